"""The UD (Bierman-Thornton) filter: its NumPy reference (derive.reference.ud) against the
covariance KF, its staged programs (derive.filters.udkf) against the reference, and its
robustness in float32 on the poorly conditioned model of test_long_runs.

The programs are evaluated with derive.emit.python_printer.python_function, the printer
the templates use, so no unit registration is needed."""

import ctypes
import subprocess

import numpy as np
import pytest
import sympy
from _random_models import stable_models
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_long_runs import measurements
from test_long_runs import model as long_run_model

from derive import LinearModel, catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import relative_error
from derive.emit.c_printer import function_parts
from derive.emit.python_printer import python_function
from derive.errors import NumericalError, PatternError
from derive.filters import derive_unit
from derive.filters.udkf import PIVOT_FLOOR, udkf_programs
from derive.flops import count
from derive.lowering import lower_program
from derive.options import SharedOptions
from derive.reference import ud

TOLERANCE = 1e-12
"""The issue's bar: normwise relative per step (derive.apps.verify.relative_error)."""
LINEAR = [name for name in catalog.names() if catalog.load(name).kind == "linear"]


def series(num, steps, seed):
    return simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs


def spd(n, seed):
    A = np.random.default_rng(seed).normal(size=(n, n))
    return A @ A.T / n + 0.5 * np.eye(n)


def with_gaps(zs, seed, fraction=0.3):
    """zs with about ``fraction`` of its entries NaN (absent measurements)."""
    zs = np.array(zs, dtype=float)
    zs[np.random.default_rng(seed).random(zs.shape) < fraction] = np.nan
    return zs


# -- the reference ------------------------------------------------------------------------


@pytest.mark.parametrize("name", LINEAR)
@pytest.mark.parametrize("start", ["catalog", "spd"])
def test_reference_matches_the_covariance_kf_on_the_catalog(name, start):
    """From the catalog's P0 (mostly 0: zero pivots, exact here) and from a dense P0."""
    num = catalog.load(name).numeric()
    P0 = num.P0 if start == "catalog" else spd(len(num.x0), 3)
    zs = series(num, 500, 1)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs)
    xs, Ps = ud.ud_kf(num, zs, P0=P0)
    assert relative_error(xs, xr) <= TOLERANCE
    assert relative_error(Ps, Pr) <= TOLERANCE


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stable_models(), st.integers(0, 1000), st.booleans())
def test_reference_matches_the_covariance_kf_on_random_models(model, seed, gaps):
    """Dense Q and correlated R (Q and R whitened), with and without absent measurements."""
    num = model.numeric()
    zs = series(num, 200, seed)
    if gaps:
        zs = with_gaps(zs, seed)
    P0 = spd(model.n, seed)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs)
    xs, Ps = ud.ud_kf(num, zs, P0=P0)
    assert relative_error(xs, xr) <= TOLERANCE
    assert relative_error(Ps, Pr) <= TOLERANCE


def test_ud_factor_round_trips_and_refuses_an_indefinite_matrix():
    P = spd(5, 7)
    U, D = ud.ud_factor(P)
    assert np.array_equal(U, np.triu(U)) and np.all(np.diag(U) == 1) and np.all(D > 0)
    np.testing.assert_allclose(ud.ud_compose(U, D), P, rtol=1e-14, atol=1e-14)
    U, D = ud.ud_factor(np.zeros((3, 3)))
    assert np.array_equal(U, np.eye(3)) and np.array_equal(D, np.zeros(3))
    with pytest.raises(NumericalError, match="pivot 1"):
        ud.ud_factor(np.diag([1.0, -1.0, 1.0]))


# -- the programs -------------------------------------------------------------------------


class Programs:
    """The three programs of a model as Python functions on flat arrays."""

    def __init__(self, model, **options):
        self.n, self.programs = model.n, udkf_programs(model, SharedOptions(**options))
        self.functions = {k: python_function(p) for k, p in self.programs.items()}

    def enter(self, P):
        _, U, D = self.functions["enter"](np.zeros(self.n), np.ravel(P))
        return np.reshape(U, (self.n, self.n)), np.asarray(D)

    def store(self, U, D):
        return np.reshape(self.functions["store"](np.zeros(self.n), np.ravel(U), D),
                          (self.n, self.n))

    def run(self, zs, x0, P0):
        """(xs, Us, Ds, Ps) over the series, P0 entered and every P stored."""
        x, (U, D) = np.asarray(x0, dtype=float), self.enter(P0)
        xs, Us, Ds, Ps = [], [], [], []
        for z in zs:
            x, U, D = (np.asarray(v) for v in self.functions["step"](x, np.ravel(U), D, z))
            U = U.reshape(self.n, self.n)
            xs.append(x), Us.append(U), Ds.append(D), Ps.append(self.store(U, D))
        return tuple(np.array(v) for v in (xs, Us, Ds, Ps))


def check_against_references(model, zs, P0, **options):
    num = model.numeric()
    xs, Us, Ds, Ps = Programs(model, **options).run(zs, num.x0, P0)
    xu, Uu, Du = ud.ud_kf_factors(num, zs, P0=P0)
    assert relative_error(xs, xu) <= TOLERANCE
    assert relative_error(Us, Uu) <= TOLERANCE
    assert relative_error(Ds, Du) <= TOLERANCE
    assert np.array_equal(Us, np.triu(Us)) and np.all(np.diagonal(Us, axis1=1, axis2=2) == 1)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs)
    assert relative_error(xs, xr) <= TOLERANCE
    assert relative_error(Ps, Pr) <= TOLERANCE


@pytest.mark.parametrize("name", LINEAR)
@pytest.mark.parametrize("start", ["catalog", "identity"])
def test_programs_match_the_references_on_the_catalog(name, start):
    """From the catalog's P0 (mostly 0: zero pivots at the first steps) and from I."""
    model = catalog.load(name)
    num = model.numeric()
    P0 = num.P0 if start == "catalog" else np.eye(model.n)
    check_against_references(model, series(num, 100, 2), P0)


@pytest.mark.parametrize("name", ["mpt3d_a", "gsm2d_a"])
def test_programs_skip_absent_measurements(name):
    model = catalog.load(name)
    zs = with_gaps(series(model.numeric(), 100, 4), 4, fraction=0.4)
    zs[5] = np.nan  # a step with no measurement at all
    check_against_references(model, zs, np.eye(model.n), missing=True)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stable_models(), st.integers(0, 1000), st.booleans())
def test_programs_match_the_references_on_random_models(model, seed, missing):
    zs = series(model.numeric(), 40, seed)
    if missing:
        zs = with_gaps(zs, seed)
    check_against_references(model, zs, spd(model.n, seed), P0_pattern="dense",
                             missing=missing)


def test_programs_with_free_parameters_take_p():
    q, r = sympy.symbols("q r", positive=True)
    model = LinearModel("axis", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]], [[q]], [[r]],
                        G=[[sympy.Rational(1, 2)], [1]], parameters=[q, r])
    step = udkf_programs(model)["step"]
    assert [p.name for p in step.inputs] == ["x", "U", "D", "z", "p"]
    f = python_function(step)
    fixed = LinearModel("axis", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]], [[0.3]],
                        [[0.2]], G=[[0.5], [1]])
    num = fixed.numeric()
    U, D = ud.ud_factor(spd(2, 1))
    x, Un, Dn = f([1.0, 2.0], U.ravel(), D, [0.7], [0.3, 0.2])
    xu, Uu, Du = ud.ud_kf_factors(num, [[0.7]], x0=[1.0, 2.0], P0=ud.ud_compose(U, D))
    np.testing.assert_allclose(x, xu[0], rtol=1e-14)
    np.testing.assert_allclose(np.reshape(Un, (2, 2)), Uu[0], rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(Dn, Du[0], rtol=1e-14)


def test_no_square_root_and_every_divisor_checked():
    programs = udkf_programs(catalog.load("mpt3d_a"))
    for name, program in programs.items():
        assert count(program).sqrt == 0, name
    step = programs["step"].listing()
    assert "pivot 0 of the time update" in step and "innovation variance" in step


def test_zero_pivots_give_zero_columns_and_negative_ones_are_refused():
    """P0 = 0 (the catalog's) enters as U = I, D = 0, and P(1/0) = G Q Gᵀ of mpt3d_b (one
    noise input, two states) is singular: the zero pivots divide as 0 / 1 = 0 (the
    reference's zero column); a negative pivot (P not positive semidefinite) is refused."""
    programs = Programs(catalog.load("mpt3d_b"))
    U, D = programs.enter(np.zeros((2, 2)))
    assert np.array_equal(U, np.eye(2)) and np.array_equal(D, np.zeros(2))
    x, U, D = programs.functions["step"]([0.0, 0.0], [1.0, 0.0, 0.0, 1.0], [0.0, 0.0], [1.0])
    assert np.all(np.isfinite(U)) and np.all(np.isfinite(D)) and min(D) == 0
    with pytest.raises(NumericalError, match="pivot 1 of its UD factorisation is negative"):
        programs.enter(np.diag([1.0, -1.0]))
    with pytest.raises(NumericalError, match=r"P\(k\+1/k\) is not positive semidefinite: "
                                             "pivot 1"):
        programs.functions["step"]([0.0, 0.0], [1.0, 0.0, 0.0, 1.0], [1.0, -1.0], [1.0])


def test_the_pivot_floor_changes_no_quotient_of_a_normal_pivot():
    """d + DBL_MIN == d for d >= 2^-968, so the pivot check d + DBL_MIN > 0 is that of d
    itself there (and lets d = 0 through)."""
    floor = float(PIVOT_FLOOR)
    assert floor == np.finfo(float).tiny
    d = np.geomspace(2.0**-968, 1e300, 10000)
    assert np.array_equal(d + floor, d)
    assert 0.0 + floor > 0


def test_entries_outside_the_pattern_are_refused():
    """mpt3d_a's axes are independent: U keeps their block structure, and a U or P with a
    coupling entry is refused rather than filtered wrongly."""
    programs = Programs(catalog.load("mpt3d_a"))
    U, D = np.eye(6), np.ones(6)
    outside = next((i, j) for i in range(6) for j in range(i + 1, 6)
                   if f"U[{i * 6 + j}] == 0" in programs.programs["step"].listing())
    U[outside] = 0.5
    with pytest.raises(PatternError, match=f"U\\[{outside[0]}\\]\\[{outside[1]}\\]"):
        programs.functions["step"](np.zeros(6), U.ravel(), D, np.zeros(3))
    P = np.eye(6)
    P[outside] = P[outside[::-1]] = 0.1
    with pytest.raises(PatternError, match=f"P0\\[{outside[0]}\\]\\[{outside[1]}\\]"):
        programs.enter(P)


@pytest.mark.parametrize("name", ["mpt3d_a", "mpt3d_b"])
def test_counts_against_the_covariance_kf(name):
    """The step's flops are printed next to the covariance KF's (the report's numbers)."""
    model = catalog.load(name)
    ud_step = count(udkf_programs(model)["step"])
    kf_step = count(derive_unit(model, "kf").programs["step"])
    print(f"{name}: udkf step {ud_step.summary()}; kf step {kf_step.summary()}")
    assert ud_step.sqrt == 0 and ud_step.flops > 0


# -- float32 on the poorly conditioned model ----------------------------------------------

FLOAT32_STEPS = 5000
EPS32 = float(np.finfo(np.float32).eps)


def test_float32_ud_keeps_p_positive_definite_where_the_covariance_kf_loses_it():
    """illcond (test_long_runs: R = 1e-8, Q = 1e4, P0 = 0), 5000 steps in NumPy float32.

    From step 2 on the true P(k/k) is positive definite (step 1's is singular: P0 = 0 and
    G Q Gᵀ has rank 3).  The covariance KF in float32, in the standard form (as
    reference.kf) and in Joseph's, loses positive definiteness: its P has a negative
    eigenvalue at every step, and is far from the float64 P (error over 100 times the
    UD's: the standard form's is about 1e5, all accuracy lost).  The UD filter
    keeps every D > 0, so its P = U D Uᵀ is positive definite by construction, and stays
    within eps32 sqrt(kappa) (normwise relative) of the float64 KF, kappa the condition
    number of the steady P(k+1/k): the factored forms' accuracy goes as the square root
    of the condition number.  Its x stays within 64 eps32 (normwise relative)."""
    num = long_run_model("illcond").numeric()
    zs = measurements("illcond", FLOAT32_STEPS)
    x64, P64 = ud.covariance_kf(num, zs)
    predicted = num.F @ P64[-1] @ num.F.T + num.GQGt
    eig = np.linalg.eigvalsh(predicted)
    kappa = eig.max() / eig.min()
    p_tolerance = EPS32 * np.sqrt(kappa)

    def normwise(Ps):
        return (np.linalg.norm(Ps[1:] - P64[1:], axis=(1, 2))
                / np.linalg.norm(P64[1:], axis=(1, 2)))

    covariance = {}
    for joseph in (False, True):
        _, P32 = ud.covariance_kf(num, zs, dtype=np.float32, joseph=joseph)
        spectrum = np.linalg.eigvalsh(P32[1:].astype(float))
        ratio = spectrum.min(axis=1) / np.abs(spectrum).max(axis=1)
        covariance["Joseph" if joseph else "standard"] = (
            int(np.count_nonzero(ratio < 0)), ratio.min(), normwise(P32.astype(float)).max(),
            P32[-1].astype(float))

    xu, Us, Ds = ud.ud_kf_factors(num, zs, dtype=np.float32)
    Us, Ds = Us.astype(float), Ds.astype(float)
    Pu = (Us * Ds[:, None, :]) @ Us.transpose(0, 2, 1)
    p_error = normwise(Pu)
    x_error = np.linalg.norm(xu - x64, axis=1) / np.linalg.norm(x64, axis=1)
    for form, (lost, ratio, error, _) in covariance.items():
        print(f"covariance KF ({form}) float32: P indefinite at {lost} of "
              f"{FLOAT32_STEPS - 1} steps, worst lambda_min/|lambda|_max {ratio:.3g}, "
              f"worst P error {error:.3g}")
    print(f"UD float32 (kappa {kappa:.3g}): min D {Ds[1:].min():.3g}, worst P error "
          f"{p_error.max():.3g} (tolerance {p_tolerance:.3g}), worst x error "
          f"{x_error.max():.3g} (tolerance {64 * EPS32:.3g})")
    for form, (lost, _, error, last) in covariance.items():
        assert lost == FLOAT32_STEPS - 1, form
        with pytest.raises(np.linalg.LinAlgError):
            np.linalg.cholesky(last)
        assert error > 100 * p_error.max(), form
    assert Ds[1:].min() > 0
    np.linalg.cholesky(Pu[1:])
    assert p_error.max() <= p_tolerance
    assert x_error.max() <= 64 * EPS32


# -- the programs printed as C ------------------------------------------------------------

C_FLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared", "-fPIC"]


def c_library(programs, directory):
    """The programs printed by derive.emit.c_printer (with fma), compiled with the
    project's flags into a shared library."""
    lines = ["#include <math.h>", "#define DERIVE_FMA(a, b, c) fma(a, b, c)",
             "#define DERIVE_FNMA(a, b, c) fma(a, -(b), c)"]
    for program in programs.values():
        parts = function_parts(lower_program(program, use_fma=True), "ud")
        lines += [parts["signature"] + ";", parts["signature"] + " {"]
        lines += [f"    {line}" for line in parts["body"]] + ["}"]
    source = directory / "ud.c"
    source.write_text("\n".join(lines) + "\n")
    library = directory / "ud.so"
    subprocess.run(["gcc", *C_FLAGS, "-o", str(library), str(source), "-lm"], check=True,
                   capture_output=True, text=True, timeout=120)
    return ctypes.CDLL(str(library))


def c_call(function, *arrays):
    """Call a C function on float64 arrays (the outputs among them are written in place)."""
    pointer = ctypes.POINTER(ctypes.c_double)
    return function(*(a.ctypes.data_as(pointer) for a in arrays))


def test_programs_print_as_c_that_compiles_and_matches_python(tmp_path):
    """mpt3d_a from its P0 = 0 (zero pivots) with missing measurements (selects): C (with
    fma) within 1e-12 of the printed Python over 100 steps, and a non-zero status where
    Python raises."""
    model = catalog.load("mpt3d_a")
    programs = Programs(model, missing=True)
    library = c_library(programs.programs, tmp_path)
    num = model.numeric()
    zs = with_gaps(series(num, 100, 6), 6)
    xs, Us, Ds, _ = programs.run(zs, num.x0, num.P0)
    U, D = np.zeros(36), np.zeros(6)
    assert c_call(library.ud_enter, np.zeros(6), np.array(num.P0, dtype=float).ravel(),
                  np.zeros(6), U, D) == 0
    x = np.array(num.x0, dtype=float)
    for k, z in enumerate(zs):
        x_new, U_new, D_new = np.zeros(6), np.zeros(36), np.zeros(6)
        assert c_call(library.ud_step, x, U, D, np.ascontiguousarray(z), x_new, U_new,
                      D_new) == 0
        x, U, D = x_new, U_new, D_new
        assert relative_error(x[None], xs[k][None]) <= TOLERANCE
        assert relative_error(U[None], Us[k].ravel()[None]) <= TOLERANCE
        assert relative_error(D[None], Ds[k][None]) <= TOLERANCE
    P = np.zeros(36)
    assert c_call(library.ud_store, x, U, D, P) == 0
    np.testing.assert_allclose(P.reshape(6, 6), programs.store(U.reshape(6, 6), D),
                               rtol=1e-12, atol=1e-15)
    assert c_call(library.ud_enter, x, -np.eye(6).ravel(), np.zeros(6), U, D) != 0
    assert c_call(library.ud_step, x, np.eye(6).ravel(), -np.ones(6), np.zeros(3),
                  np.zeros(6), np.zeros(36), np.zeros(6)) != 0


def test_a_measurement_variance_given_at_runtime_is_checked():
    """R is checked positive when the model is built; a free R is checked when run."""
    r = sympy.Symbol("r")
    model = LinearModel("free_r", ["s"], ["z"], [[1]], [[1]], [[1]], [[r]], parameters=[r])
    step = python_function(udkf_programs(model)["step"])
    x, U, D = step([0.0], [1.0], [1.0], [2.0], [0.5])
    assert x[0] == pytest.approx(2 * 2 / 2.5) and D[0] == pytest.approx(2 * 0.5 / 2.5)
    with pytest.raises(NumericalError, match="measurement noise variance"):
        step([0.0], [1.0], [1.0], [2.0], [0.0])


def test_missing_measurements_cost_no_flop_with_a_diagonal_r():
    """Each scalar update is kept or not by selects (comparisons, counted as cmp)."""
    model = catalog.load("mpt3d_a")
    plain = count(udkf_programs(model)["step"])
    skipping = count(udkf_programs(model, SharedOptions(missing=True))["step"])
    assert skipping.flops == plain.flops and skipping.cmp > plain.cmp
