"""The float32 C of every catalog filter against the float64 NumPy reference, within the
tolerance derived for it (derive.apps.float_tolerance), and the UD filter against the
standard KF in float32 on an ill-conditioned model.

The tolerance is tol = c * u32 * L * G * kappa, u32 = 2^-24, computed for each filter
(nothing typed): L the roundings on the longest chain of its generated step (+ 2 for the
inputs and constants rounded to float), G = sum_j ||A^j||_inf for the closed loop
A = (I - K H) F of the model, kappa the largest over the run of the product of what the
filter's step factorises, solves or cancels (its spec's conditioning: a KF's S, scaled to
a unit diagonal, and its update's ratio ||P(k/k-1)|| / ||P(k/k)||; an information form's
P(k/k)^-1; a sigma-point filter whose h has a node without a difference rule: also its
spreads' cancellation squared), c = 2 (the state's and the
covariance's error, each at most the first-order gamma_L = L u of Higham's Lemma 3.1).
docs/generated-code.md states it and the measured ratios.

The float kernels are compiled once, all in one extension, with the strict flags and
-Wdouble-promotion -Wfloat-conversion -Wconversion (so this is also the float half of
test_emb_float_code's compile test).
"""

from __future__ import annotations

import shutil

import pytest

from derive import LinearModel, catalog
from derive.apps.float_tolerance import (
    FloatTolerance,
    error_growth,
    float_tolerance,
    growth_of,
    in_double,
    rounding_depth,
    run_roundings,
)
from derive.apps.verify import (
    LINEAR_TOLERANCE,
    conditioning_run,
    generated_run,
    linear_run,
    reference_run,
    relative_error,
    verify_modules,
)
from derive.build import CONVERSION_CFLAGS
from derive.cli import main
from derive.filters import available
from derive.generation import command_unit
from derive.lowering import lower_program
from derive.pipeline import load_units
from derive.precision import FLOAT
from derive.riccati import kf_steady
from derive.runs.kinds import two_step_map

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

FLOAT_OPTIONS = {"precision": "float"}
STEPS = 1000


@pytest.fixture(scope="module")
def catalog_results():
    """Every catalog model with every filter that applies, float32 C verified."""
    units, models = [], []
    for name in catalog.names():
        model = catalog.load(name)
        for filter_name in available(model):
            units.append(command_unit(model, filter_name, FLOAT_OPTIONS, name))
            models.append(model)
    loaded = load_units(units, "c", extra_cflags=CONVERSION_CFLAGS)
    return [verify_modules(model, g.unit.filter, {"c": g.c}, STEPS, 7, FLOAT_OPTIONS,
                           g.unit)[0]
            for model, g in zip(models, loaded)]


def test_every_catalog_filter_in_float32_agrees_within_its_derived_tolerance(catalog_results):
    failed = [r.line() for r in catalog_results if not r.passed]
    assert not failed, "\n".join(failed)
    for r in catalog_results:
        assert r.tolerance == r.bound.value
        # the error is that of float32, not of double: above the same bound in double,
        # so the test is of float code indeed
        assert r.error > in_double(r.bound).value, r.line()


def test_every_catalog_bound_is_meaningful(catalog_results):
    """No catalog filter is beyond float32 by its bound: the INS/GNSS EKF, once refused for
    cond P(1/0) ~ 2e6, which the EKF never inverts (tests/numerics/test_float_bound.py); the
    24-state flight-controller filters, whose weakly observed states (the earth field, the
    magnetic bias, the wind) the sensors units' first-order bound carries by the filter's
    own maps, not by norms of their products; and the GNSS UKF, whose pseudoranges of 2e7 m
    have float32 spacing 2 m, now that it forms its sigma-point spreads of metres in
    difference form (derive.filters.difference; tests/numerics/test_float_ukf.py)."""
    refused = [r.line() for r in catalog_results if not r.bound.meaningful]
    assert not refused, "\n".join(refused)
    # the CTRV turn's omega-Jacobian cancels u / (omega dt)^2 of itself in float32: the
    # model expands the turn below |omega dt| = 0.03 (4e-2 of P when it did at 1e-4)
    ctrv = [r for r in catalog_results if r.model == "ctrv_radar"]
    assert ctrv and all(r.error < 1e-3 for r in ctrv), [r.line() for r in ctrv]
    ukf = next(r for r in catalog_results if (r.model, r.filter) == ("gnss_pseudorange", "ukf"))
    assert ukf.passed and ukf.error < FLOAT.unit_roundoff**0.5, ukf.line()


@pytest.mark.parametrize("name", ["kf", "udkf"])
def test_the_python_of_a_float_unit_stays_double(name):
    """The Python twin computes in double and meets the double bar (the UD filter's, with
    the float pivot floor FLT_MIN, from cv's P0 = 0: zero pivots at the start)."""
    model = catalog.load("cv")
    unit = command_unit(model, name, FLOAT_OPTIONS, "cv")
    generated = load_units([unit], "all", extra_cflags=CONVERSION_CFLAGS)[0]
    python, c = verify_modules(model, name, {"python": generated.python, "c": generated.c},
                               300, 7, FLOAT_OPTIONS, unit)
    assert python.bound is None and python.tolerance == LINEAR_TOLERANCE and python.passed
    assert c.bound is not None and c.passed and c.error > 1e3 * python.error


def ill_conditioned_model(P0_scale: float = 1e6, r: float = 1e-2, q: float = 1e-6
                          ) -> LinearModel:
    """A constant-velocity track whose P0 is 10^8 times R and whose Q is 10^-4 of R: the
    standard KF's update P - K S K^T cancels ~1e6 against ~1e6 to leave ~1e-2, so in
    float32 (spacing 0.06 at 1e6) its P is dominated by rounding."""
    return LinearModel("illcond", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]],
                       [[q, 0], [0, q]], [[r]], x0=[0, 0],
                       P0=[[P0_scale, 0], [0, P0_scale]], P0_pattern="dense")


def test_the_ud_filter_in_float32_beats_the_kf_on_an_ill_conditioned_model():
    model = ill_conditioned_model()
    steps = 300
    units = [command_unit(model, name, FLOAT_OPTIONS, "illcond") for name in ("kf", "udkf")]
    kf, udkf = load_units(units, "c", extra_cflags=CONVERSION_CFLAGS)
    zs = linear_run(model, steps, 7)
    xs_ref, Ps_ref = reference_run(model, "kf", zs, {})  # float64: the reference of both
    ud_xs, ud_Ps = reference_run(model, "udkf", zs, {})
    # the float64 KF is itself ill-conditioned here (its P cancels too, at 2^-53): it and
    # the float64 UD filter agree to ~1e-10, below one float32 rounding, so at float32's
    # resolution either is the reference
    assert max(relative_error(ud_xs, xs_ref), relative_error(ud_Ps, Ps_ref)) < \
        FLOAT.unit_roundoff

    def error(generated):
        xs, Ps = generated_run(generated.c, generated.unit.filter, zs, model, "c")
        return max(relative_error(xs, xs_ref), relative_error(Ps, Ps_ref))

    kf_error, ud_error = error(kf), error(udkf)
    run = conditioning_run(model, zs, None, xs_ref, Ps_ref)
    # what the conditioning-free part of the bound allows (kappa = 1): the error a float32
    # step makes on a well-conditioned model of the same shape
    plain = {g.unit.filter: FloatTolerance(run_roundings(g.unit),
                                           error_growth(model, g.unit.filter, steps, run),
                                           1.0).value for g in (kf, udkf)}
    # the UD filter keeps that accuracy on this model; the KF loses it by orders of
    # magnitude (measured: UD ~2e-7, KF ~0.3, the KF's P wrong in its first digit)
    assert ud_error <= plain["udkf"]
    assert kf_error > 1e3 * plain["kf"]
    assert kf_error > 1e5 * ud_error
    # and the full bound says so: float32 is not safe for the KF here (kappa: its
    # update's cancellation ||P(k/k-1)|| / ||P(k/k)||, ~1e6 at the first step), and is for
    # the UD filter (it never inverts or cancels P: kappa, S's scaled condition, is 1)
    full = {g.unit.filter: verify_modules(model, unit.filter, {"c": g.c}, steps, 7,
                                          FLOAT_OPTIONS, unit)[0]
            for unit, g in zip(units, (kf, udkf))}
    assert not full["kf"].bound.meaningful and not full["kf"].passed
    assert full["udkf"].bound.condition == 1.0 and full["udkf"].passed


def test_derive_verify_precision_float_prints_the_tolerance_it_used(capsys):
    status = main(["verify", "cv", "--filter", "sskf", "--precision", "float",
                   "--steps", "200", "--no-progress"])
    out = capsys.readouterr().out
    assert status == 0
    c_line = next(line for line in out.splitlines() if " c f32 " in line)
    assert c_line.startswith("ok   cv                 sskf")
    assert "(c u32 L G kappa = 2 * 2^-24 * " in c_line
    python_line = next(line for line in out.splitlines() if " python " in line)
    assert f"<= {LINEAR_TOLERANCE:.1e}" in python_line
    assert out.splitlines()[-1] == "derive verify: 2 passed, 0 failed (1 model)"


def test_the_derived_terms_are_those_of_the_generated_step():
    """L from the lowered C (the steady-state filter's two-step map is its deepest chain),
    G from the model's closed loop, kappa 1 for a filter with offline constants."""
    model = catalog.load("cv")
    unit = command_unit(model, "sskf", FLOAT_OPTIONS, "cv")
    zs = linear_run(model, 100, 7)
    xs, Ps = reference_run(model, "kf", zs, {})
    bound = float_tolerance(model, unit, 100, conditioning_run(model, zs, None, xs, Ps))
    step = lower_program(unit.programs["step"], use_fma=True, state_ports=("x",))
    two = two_step_map(unit, use_fma=True)
    assert bound.roundings == max(rounding_depth(step), rounding_depth(two)) + 2
    num = model.numeric()
    A = kf_steady(num.F, num.G, num.H, num.Q, num.R).A
    assert bound.growth == growth_of(A, 100) and bound.growth > 1.0
    assert bound.condition == 1.0
    assert bound.value == 2.0 * 2.0**-24 * bound.roundings * bound.growth
