"""The float32 bound's kappa is read from what each filter's step factorises, solves or
cancels (its spec's ``conditioning``, derive.apps.float_tolerance), not cond P(k/k-1)
for every filter that carries P: the KF and EKF solve S (an LDL^T solve: S's condition
scaled to a unit diagonal) and cancel in their update (||P(k/k-1)|| / ||P(k/k)||); the
information form inverts P(k/k)^-1 too. A unit of the run kind sensors (the INS/GNSS EKF)
has the first-order bound instead (each step's running error carried by the filter's
maps), and passes it on x86 and under qemu-arm. Every number below is recomputed here
from the same reference run with NumPy, none typed."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from derive import catalog
from derive.apps.float_tolerance import (
    PropagatedTolerance,
    chained_depth,
    condition_terms,
    local_errors,
    propagated_bound,
    rounding_depth,
    run_roundings,
    run_steps,
    scaled_condition,
    sensors_conditioning,
)
from derive.apps.targets.arm import run_under_qemu
from derive.apps.targets.data import verification_data
from derive.apps.targets.toolchains import TARGETS
from derive.apps.verify import (
    conditioning_run,
    linear_run,
    reference_run,
    sensors_case,
    verify_filter,
)
from derive.build import CONVERSION_CFLAGS, STRICT_CFLAGS
from derive.cli import main
from derive.filters import FILTERS, kind
from derive.filters.sensors import reference_run as sensors_reference
from derive.filters.spec import MATRICES, METHODS, Conditioned
from derive.generation import command_unit
from derive.lowering import lower_program
from derive.options import validate

FLOAT_OPTIONS = {"precision": "float"}
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
needs_qemu = pytest.mark.skipif(bool(TARGETS["arm-linux"].missing()),
                                reason="arm-linux tools missing")
MAKE = shutil.which("make")
PRINTED = re.compile(r"^\w+ (\w+): largest error (\S+) over (\d+) steps .*: (ok|FAIL)$", re.M)


def unit_diagonal_cond(M: np.ndarray) -> float:
    d = 1.0 / np.sqrt(np.diag(M))
    return float(np.linalg.cond(M * np.outer(d, d)))


def at_scale(M: np.ndarray) -> float:
    """The scale the error measure judges a covariance at: its own size, ||M||_inf
    (derive.apps.verify.relative_error divides by it or by a floor below it)."""
    return float(np.abs(M).sum(axis=1).max())


def ins_gnss_trace(steps: int):
    """The ins_gnss EKF's sensors reference run (derive verify's data) and its trace."""
    model = catalog.load("ins_gnss")
    options = validate("ekf", FLOAT_OPTIONS)
    case = sensors_case(model, "ekf", steps, 7, options, float_c=False)
    trace: list = []
    sensors_reference(model, options, case.run.zs, case.run.us, case.ps, case.run.x0,
                      case.run.P0, case.run.Rs, trace=trace)
    return model, trace


def ins_gnss_bound(model, trace) -> PropagatedTolerance:
    """The bound of the ins_gnss float32 EKF recomputed from its reference run's trace."""
    unit = command_unit(model, "ekf", validate("ekf", FLOAT_OPTIONS))
    run = sensors_conditioning(model, trace)
    x, P = propagated_bound(model, run, *local_errors(unit, run.trace), unit_roundoff=1.0)
    return PropagatedTolerance(x, P)


@needs_gcc
def test_the_ins_gnss_ekf_in_float32_passes_its_own_bound():
    """derive verify --precision float: the sensors unit's bound is the first-order one
    (each step's running error carried by the filter's maps), meaningful, and holds
    within a factor 10^3 of the error (the steps' errors partly cancel; the bound adds
    their magnitudes)."""
    model = catalog.load("ins_gnss")
    steps = 1000
    (c,) = verify_filter(model, "ekf", steps=steps, langs=("c",), options=FLOAT_OPTIONS)
    assert isinstance(c.bound, PropagatedTolerance) and c.bound.meaningful and c.passed
    assert 0.0 < c.error <= c.bound.value == c.tolerance <= 1e3 * c.error, c.line()
    _, trace = ins_gnss_trace(steps)
    assert c.bound == ins_gnss_bound(model, trace)
    assert "first order u32 * max(x " in c.line()


@needs_qemu
def test_the_ins_gnss_ekf_in_float32_under_qemu_arm_passes_the_same_bound():
    steps = 200
    (run,) = run_under_qemu("ins_gnss", ["ekf"], FLOAT_OPTIONS, steps=steps)
    model, trace = ins_gnss_trace(steps)
    assert run.precision == "float" and run.bound == ins_gnss_bound(model, trace)
    assert run.bound.meaningful
    assert run.passed and 0.0 < run.error <= run.tolerance == run.bound.value, run.line()
    assert run.printed == pytest.approx(run.error, rel=2e-3)  # the program's own measure


def test_a_kfs_kappa_is_cond_s_and_an_information_forms_includes_p():
    """On one reference run (ca, the KF's run every linear filter's bound reads), from
    P0 on: the KF's kappa is the largest over the steps of S's scaled condition times
    ||P(k/k-1)|| / ||P(k/k)||, with no condition of P; the information form's is cond R
    (scaled) times that ratio times the scaled condition of P(k/k)^-1, which it inverts."""
    model = catalog.load("ca")
    zs = linear_run(model, 300, 7)
    xs, Ps = reference_run(model, "kf", zs, {})
    run = conditioning_run(model, zs, None, xs, Ps)
    num = model.numeric()
    priors = [num.F @ P @ num.F.T + num.GQGt for P in [num.P0] + list(run.Ps[:-1])]
    ratios = [max(1.0, at_scale(Pp) / at_scale(P)) for Pp, P in zip(priors, run.Ps)]
    S = [num.H @ Pp @ num.H.T + num.R for Pp in priors]
    kf_kappa = max(unit_diagonal_cond(s) * r for s, r in zip(S, ratios))
    information = [unit_diagonal_cond(np.linalg.inv(P)) for P in run.Ps]
    ikf_kappa = max(unit_diagonal_cond(num.R) * r * i for r, i in zip(ratios, information))
    kf, kf_terms = condition_terms(model, "kf", run)
    ikf, ikf_terms = condition_terms(model, "ikf", run)
    assert kf == pytest.approx(kf_kappa, rel=1e-12)
    assert ikf == pytest.approx(ikf_kappa, rel=1e-12)
    assert [name for name, _ in kf_terms] == ["cond S", "P(k/k-1) -> P(k/k)"]
    assert [name for name, _ in ikf_terms] == ["cond R", "P(k/k-1) -> P(k/k)",
                                               "cond P(k/k)^-1"]
    # the information form's kappa is P's, over an order above the KF's on this model (the
    # KF's own cancellation, P(k/k-1) over P(k/k) at P(k/k)'s own size, is ~3.8 here)
    assert ikf >= max(information) > 10 * kf
    assert len(run_steps(model, kind("kf"), run)) == len(run.Ps)


def test_the_scaled_condition_ignores_the_units_and_the_plain_one_does_not():
    """An LDL^T solve's backward error is bounded by S's diagonal (Higham Thm 10.3), so
    its effect is measured by the condition of S scaled to a unit diagonal: the same for
    S in metres and in millimetres, while cond_2 changes with the units."""
    rng = np.random.default_rng(3)
    B = rng.normal(size=(4, 4))
    S = B @ B.T + 4 * np.eye(4)
    D = np.diag([1.0, 1e3, 1e-3, 10.0])
    assert scaled_condition(D @ S @ D) == pytest.approx(scaled_condition(S), rel=1e-9)
    assert np.linalg.cond(D @ S @ D) > 1e5 * np.linalg.cond(S)
    singular = np.diag([1.0, 0.0])   # a zero diagonal: no scaling, the plain condition
    assert scaled_condition(singular) == np.linalg.cond(singular)


def test_every_filter_declares_what_its_step_conditions_and_only_known_things():
    for name, spec in FILTERS.items():
        for entry in spec.conditioning:
            assert entry.matrix in MATRICES and entry.method in METHODS, name
        if not spec.covariance:   # constants computed offline in double
            assert spec.conditioning == (), name
    assert [e.method for e in kind("udkf").conditioning] == ["ldl"]  # never inverts P
    with pytest.raises(ValueError, match="unknown conditioning"):
        Conditioned("P", "cholesky")


def test_the_chain_through_the_ins_gnss_programs_is_composed_not_added():
    """L follows one chain through predict, update_gnss and update_baro: x_new and P_new
    of each enter the next at their own depths, so L is below the sum of the programs'
    deepest chains (predict's deepest is P's, update_baro's x's through the gain)."""
    model = catalog.load("ins_gnss")
    unit = command_unit(model, "ekf", validate("ekf", FLOAT_OPTIONS))
    names = ("predict", "update_gnss", "update_baro")
    depths = [rounding_depth(lower_program(unit.programs[name], use_fma=True,
                                           state_ports=("x", "P"))) for name in names]
    chained = chained_depth(unit, names)
    assert max(depths) < chained < sum(depths)
    assert run_roundings(unit) == chained + 2


@needs_gcc
@pytest.mark.skipif(MAKE is None, reason="no make")
def test_the_ins_gnss_float32_library_is_written_and_its_test_program_passes(tmp_path):
    """Refused while its bound was >= 1 ("float32 cannot carry this filter"): now its
    library builds with the conversion flags and its test program meets the bound."""
    out = tmp_path / "out"
    assert main(["generate", "ins_gnss", "--layout", "library", "--precision", "float",
                 "--out", str(out)]) == 0
    flags = " ".join(STRICT_CFLAGS + CONVERSION_CFLAGS)
    done = subprocess.run([MAKE, "-C", str(out / "ins_gnss"), f"CFLAGS={flags}", "check"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    ((name, error, steps, verdict),) = PRINTED.findall(done.stdout)
    data = verification_data(catalog.load("ins_gnss"), "ekf", FLOAT_OPTIONS,
                             steps=int(steps))
    assert data.bound is not None and data.bound.meaningful
    assert (name, verdict) == ("ekf", "ok")
    assert 0.0 < float(error) <= data.tolerance == data.bound.value
