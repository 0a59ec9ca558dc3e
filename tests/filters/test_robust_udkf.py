"""The UD filter on scaled models (robustness item "udkf pivot underflow"): a model whose
covariances are all scaled by s is the same filter (x the same, P times s), so the
generated UD filter must match the covariance KF there as at s = 1, down to P ~ 1e-300 in
double and 1e-35 in float, or refuse.  Before: Bierman's D_j before / alpha multiplied two
variances first (D_j before underflows from P ~ 1e-154), and each pivot divided as
d + DBL_MIN, which is not d below 4e-292; both gave wrong P with status 0."""

from __future__ import annotations

import numpy as np
import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import reference
from derive.apps.simulate import simulate_linear
from derive.errors import MatrixPropertyError
from derive.model import LinearModel
from derive.pipeline import load_generated
from derive.reference.ud import ud_kf

TOLERANCE = 1e-12       # generated double vs reference, relative to the array's scale
FLOAT_TOLERANCE = 1e-5  # float32 code vs the double KF (errors seen ~2e-7, u = 6e-8)
STEPS = 40


def scaled_model() -> LinearModel:
    """Three states, two correlated measurements, Q = q diag(1, 2, 3) / 10,
    R = r [[1, 0.3], [0.3, 2]]: q and r are the scale, free parameters of one build."""
    q, r = sympy.symbols("q r", positive=True)
    F = [[1, 1, sympy.Rational(1, 2)], [0, 1, 1], [0, 0, sympy.Rational(9, 10)]]
    H = [[1, 0, 0], [0, 0, 1]]
    Q = sympy.diag(q / 10, 2 * q / 10, 3 * q / 10)
    R = sympy.Matrix([[r, 3 * r / 10], [3 * r / 10, 2 * r]])
    return LinearModel("scaled", ["a", "b", "c"], ["y", "w"], F, H, Q, R,
                       G=sympy.eye(3).tolist(), P0_pattern="dense", parameters=[q, r])


MODEL = scaled_model()


def scaled_error(a, b) -> float:
    """max |a - b| / max |b|: relative to the array's own scale (derive verify's
    relative_error floored the scale at 1 when this was written, which hid everything
    at P ~ 1e-160; its floor is now min(1, the typical step's size))."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def problem(scale: float, seed: int = 3):
    """(numeric model, zs, x0, P0, p) at ``scale``: the same filter as at scale 1, with
    P and Q, R times ``scale`` and x, z times sqrt(scale)."""
    p = [scale, scale]
    num = MODEL.numeric({"q": scale, "r": scale})
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, np.zeros(3), STEPS, seed).zs
    A = np.random.default_rng(seed).normal(size=(3, 3))
    P0 = scale * (A @ A.T + np.eye(3))
    return num, zs, np.zeros(3), P0, p


@pytest.fixture(scope="module")
def double_modules():
    loaded = load_generated(MODEL, "udkf", {"P0_pattern": "dense"}, lang="all")
    return loaded.python, loaded.c


@pytest.fixture(scope="module")
def float_module():
    return load_generated(MODEL, "udkf", {"P0_pattern": "dense", "precision": "float"},
                          lang="c").c


def test_a_model_with_tiny_covariances_is_accepted():
    """R = 1e-200 [[1, 0.3], [0.3, 2]] is as definite as at scale 1 (the check was an
    absolute 1e-12), and a Q with an eigenvalue -1e-14 at scale 1e-15 is as indefinite."""
    for scale in (1e-13, 1e-200):
        num = LinearModel("tiny", ["s"], ["z", "w"], [[1]], [[1], [1]], [[scale]],
                          (scale * np.array([[1, 0.3], [0.3, 2]])).tolist()).numeric()
        assert num.R[1][1] == 2 * scale
    with pytest.raises(MatrixPropertyError, match="Q must be positive semidefinite"):
        LinearModel("indefinite", ["s", "v"], ["z"], [[1, 0], [0, 1]], [[1, 0]],
                    [[1e-15, 0], [0, -1e-14]], [[1]])


@settings(max_examples=25, deadline=None)
@given(st.integers(-305, 0), st.integers(0, 1000))
def test_generated_udkf_matches_the_kf_at_every_scale(double_modules, exponent, seed):
    """Python and C double, P from 1e-305 to 1: x and P within 1e-12 of the KF and of the
    NumPy UD reference, relative to their own scale."""
    scale = 10.0 ** exponent
    num, zs, x0, P0, p = problem(scale, seed)
    xk, Pk = reference.kf(num.F, num.G, num.H, num.Q, num.R, x0, P0, zs)
    xu, Pu = ud_kf(num, zs, x0, P0)
    assert scaled_error(xu, xk) <= TOLERANCE and scaled_error(Pu, Pk) <= TOLERANCE
    for module in double_modules:
        xs, Ps = module.run(zs, x0, P0, p)
        assert scaled_error(xs, xk) <= TOLERANCE, exponent
        assert scaled_error(np.reshape(Ps, Pk.shape), Pk) <= TOLERANCE, exponent
        assert scaled_error(xs, xu) <= TOLERANCE, exponent


@settings(max_examples=15, deadline=None)
@given(st.integers(-35, 0), st.integers(0, 1000))
def test_float_udkf_matches_the_kf_at_every_scale(float_module, exponent, seed):
    """C float (--precision float), P from 1e-35 to 1: within 1e-5 of the double KF, as
    the float32 NumPy UD reference is."""
    scale = 10.0 ** exponent
    num, zs, x0, P0, p = problem(scale, seed)
    xk, Pk = reference.kf(num.F, num.G, num.H, num.Q, num.R, x0, P0, zs)
    x32, P32 = ud_kf(num, zs, x0, P0, dtype=np.float32)
    assert scaled_error(x32, xk) <= FLOAT_TOLERANCE and scaled_error(P32, Pk) <= FLOAT_TOLERANCE
    f32 = np.float32
    xs, Ps = float_module.run(zs.astype(f32), x0.astype(f32), P0.astype(f32),
                              np.asarray(p, dtype=f32))
    assert scaled_error(xs, xk) <= FLOAT_TOLERANCE, exponent
    assert scaled_error(np.reshape(Ps, Pk.shape), Pk) <= FLOAT_TOLERANCE, exponent
