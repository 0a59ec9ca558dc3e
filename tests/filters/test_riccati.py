"""Riccati solvers, steady-state gains, PBH checks, FIR order and prediction constants."""

import numpy as np
import pytest
import scipy.linalg as sl
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.errors import MatrixPropertyError, ShapeError, SteadyStateError
from derive.horizon import fir_order, fir_taps, pred_constants
from derive.riccati import (
    doubling,
    kf_steady,
    lf_constants,
    lf_steady,
    rekf_doubling,
    rekf_iterate,
    relf_doubling,
    relf_iterate,
)
from derive.system_checks import check_steady_state

TOL = 1e-10


def axis(dt=1.0, sq2=0.01, sr2=0.1):
    """One MPT3D/GSM2D axis (SPEC §2)."""
    return (np.array([[1.0, dt], [0.0, 1.0]]), np.array([[dt / 2], [1.0]]),
            np.array([[1.0, dt]]), np.array([[sq2]]), np.array([[sr2]]))


def axes(count):
    F, G, H, Q, R = axis()
    return (sl.block_diag(*[F] * count), sl.block_diag(*[G] * count),
            sl.block_diag(*[H] * count), sl.block_diag(*[Q] * count),
            sl.block_diag(*[R] * count))


def cv(dt=1.0, sq=0.01, sr2=0.1):
    Qd = sq * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    return np.array([[1.0, dt], [0.0, 1.0]]), np.eye(2), np.array([[1.0, 0.0]]), Qd, [[sr2]]


def ca(dt=1.0, sq=0.01, sr2=0.1):
    Qd = sq * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                        [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                        [dt ** 3 / 6, dt ** 2 / 2, dt]])
    F = np.array([[1.0, dt, dt ** 2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    return F, np.eye(3), np.array([[1.0, 0.0, 0.0]]), Qd, [[sr2]]


def gps_static():
    return (np.eye(3), np.eye(3), np.eye(3), np.diag([0.02, 0.03, 0.05]),
            np.diag([4.0, 5.0, 9.0]))


MODELS = {"mpt3d_a": axes(3), "mpt3d_b": axes(1), "gsm2d_a": axes(2), "cv": cv(), "ca": ca(),
          "gps_static": gps_static()}


def scipy_pp(F, G, H, Q, R):
    """scipy's DARE is the control form: the filter DARE is its dual (Fᵀ, Hᵀ)."""
    G, Q, R = np.atleast_2d(G), np.atleast_2d(Q), np.atleast_2d(R)
    return sl.solve_discrete_are(F.T, H.T, G @ Q @ G.T, R)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_rekf_solvers_match_scipy(name):
    model = MODELS[name]
    expected = scipy_pp(*model)
    assert np.abs(rekf_iterate(*model) - expected).max() <= TOL
    assert np.abs(rekf_doubling(*model) - expected).max() <= TOL


@pytest.mark.parametrize("name", sorted(MODELS))
def test_relf_solvers_match_filtered_covariance(name):
    F, _G, H, _Q, R = model = MODELS[name]
    Pp = scipy_pp(*model)
    K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + np.atleast_2d(R))
    Pe = (np.eye(F.shape[0]) - K @ H) @ Pp
    assert np.abs(relf_iterate(*model) - Pe).max() <= TOL
    assert np.abs(relf_doubling(*model) - Pe).max() <= TOL


@pytest.mark.parametrize("method", ["doubling", "iteration"])
@pytest.mark.parametrize("name", sorted(MODELS))
def test_sskf_equals_sslf(name, method):
    kf = kf_steady(*MODELS[name], method=method)
    lf = lf_steady(*MODELS[name], method=method)
    assert np.abs(kf.A - lf.A).max() <= 1e-12
    assert np.abs(kf.B - lf.B).max() <= 1e-12
    assert np.abs(kf.Pe - lf.Pe).max() <= TOL
    F, _G, H, _Q, _R = MODELS[name]
    assert np.allclose(kf.A, (np.eye(len(F)) - kf.K @ H) @ F, rtol=0, atol=1e-15)
    assert np.abs(np.linalg.eigvals(kf.A)).max() < 1


def test_rekf_residual_is_tiny():
    F, G, H, Q, R = MODELS["ca"]
    Pp = kf_steady(F, G, H, Q, R).Pp
    R = np.atleast_2d(R)
    rhs = G @ Q @ G.T + F @ Pp @ F.T - F @ Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R) @ H @ Pp @ F.T
    assert np.abs(rhs - Pp).max() <= 1e-12 * np.abs(Pp).max()


def test_lf_constants_follow_spec():
    F, G, H, Q, R = MODELS["gsm2d_a"]
    c = lf_constants(F, G, H, Q, R)
    GQG = G @ Q @ G.T
    A = np.linalg.inv(H @ GQG @ H.T + R)
    assert np.allclose(c.A, A, atol=1e-15)
    assert np.allclose(c.Fn, F - GQG @ H.T @ A @ H @ F, atol=1e-15)
    assert np.allclose(c.On, F.T @ H.T @ A @ H @ F, atol=1e-15)
    assert np.allclose(c.Pn, GQG - GQG @ H.T @ A @ H @ GQG, atol=1e-15)


SOLVERS = [rekf_iterate, rekf_doubling, relf_iterate, relf_doubling, kf_steady, lf_steady]


@pytest.mark.parametrize("solve", SOLVERS)
def test_undetectable_model_is_refused(solve):
    F = np.diag([1.2, 0.5])
    with pytest.raises(SteadyStateError, match=r"not detectable.*eigenvalue 1\.2"):
        solve(F, np.eye(2), np.zeros((1, 2)), np.eye(2), [[1.0]])


@pytest.mark.parametrize("solve", SOLVERS)
def test_unstabilizable_model_is_refused(solve):
    F = np.diag([1.2, 0.5])
    with pytest.raises(SteadyStateError, match=r"not stabilizable.*eigenvalue 1\.2"):
        solve(F, [[0.0], [1.0]], [[1.0, 1.0]], [[1.0]], [[1.0]])


def test_marginal_modes_count_as_unstable():
    # F = I with no process noise: the unit-circle modes are not stabilisable.
    with pytest.raises(SteadyStateError, match=r"not stabilizable.*eigenvalue 1\b"):
        check_steady_state(np.eye(3), np.eye(3), np.eye(3), np.zeros((3, 3)), np.eye(3))
    # A defective (Jordan) eigenvalue 1 unseen by H: constant acceleration measuring only a.
    F, G, _, Q, R = MODELS["ca"]
    with pytest.raises(SteadyStateError, match="not detectable"):
        check_steady_state(F, G, [[0.0, 0.0, 1.0]], Q, R)
    # A stable unobserved mode is fine (detectable, not observable).
    check_steady_state(np.diag([1.0, 0.5]), np.eye(2), [[1.0, 0.0]], np.eye(2), [[1.0]])


def test_non_convergence_raises():
    with pytest.raises(SteadyStateError, match="did not converge"):
        rekf_iterate(*MODELS["cv"], max_iter=3)
    with pytest.raises(SteadyStateError, match="did not converge"):
        relf_iterate(*MODELS["cv"], max_iter=3)
    F, G, H, Q, _R = MODELS["cv"]
    with pytest.raises(SteadyStateError, match="did not converge"):
        doubling(F.T, H.T @ H / 0.1, G @ Q @ G.T, max_iter=1)


def test_bad_arrays_name_the_matrix():
    F, G, H, Q, R = MODELS["cv"]
    with pytest.raises(ShapeError, match="H must have shape"):
        kf_steady(F, G, np.ones((1, 3)), Q, R)
    with pytest.raises(MatrixPropertyError, match="R must be positive definite"):
        kf_steady(F, G, H, Q, [[0.0]])
    with pytest.raises(MatrixPropertyError, match="Q must be symmetric"):
        kf_steady(F, G, H, [[1.0, 0.5], [0.0, 1.0]], R)


@pytest.mark.parametrize("norm", [2, "fro", "inf"])
@pytest.mark.parametrize("eps", [0.5, 1e-2, 1e-3, 1e-6])
def test_fir_order_is_minimal(eps, norm):
    A = kf_steady(*MODELS["gsm2d_a"]).A
    N = fir_order(A, eps, norm)
    ord_ = {2: 2, "fro": "fro", "inf": np.inf}[norm]
    assert np.linalg.norm(np.linalg.matrix_power(A, N), ord_) < eps
    assert np.linalg.norm(np.linalg.matrix_power(A, N - 1), ord_) >= eps


@pytest.mark.parametrize("eps", [0.0, 1.0, -0.1, 1.5, float("nan"), "0.1"])
def test_fir_epsilon_outside_unit_interval_is_refused(eps):
    A = kf_steady(*MODELS["cv"]).A
    with pytest.raises(SteadyStateError, match="epsilon"):
        fir_order(A, eps)


def test_fir_order_refuses_unstable_matrix():
    with pytest.raises(SteadyStateError, match="not stable"):
        fir_order(np.eye(2), 0.1)


def test_fir_taps_are_powers_times_gain():
    ss = kf_steady(*MODELS["ca"])
    taps = fir_taps(ss.A, ss.B, 7)
    assert taps.shape == (7, 3, 1)
    for i in range(7):
        assert np.allclose(taps[i], np.linalg.matrix_power(ss.A, i) @ ss.B, atol=1e-15)


@pytest.mark.parametrize("N", [1, 2, 3, 5])
def test_pred_constants_follow_spec(N):
    F, G, H, Q, R = MODELS["ca"]
    K = kf_steady(F, G, H, Q, R).K
    A_N, B_N = pred_constants(F, K, H, N)
    FN = np.linalg.matrix_power(F, N)
    assert np.allclose(A_N @ np.linalg.matrix_power(F, N - 1), FN @ (np.eye(3) - K @ H),
                       atol=1e-12)
    assert np.allclose(B_N, FN @ K, atol=1e-15)


def test_pred_constants_need_invertible_f_beyond_one_step():
    F = np.array([[0.5, 1.0], [0.0, 0.0]])
    K, H = np.array([[0.3], [0.1]]), np.array([[1.0, 0.0]])
    pred_constants(F, K, H, 1)  # no inverse needed
    with pytest.raises(SteadyStateError, match="singular"):
        pred_constants(F, K, H, 2)


@st.composite
def random_models(draw):
    """Small models with PD Q and R and a random F scaled to spectral radius in [0.1, 1.3];
    detectability holds generically and is checked again by derive."""
    n = draw(st.integers(1, 4))
    m = draw(st.integers(1, n))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    F = rng.standard_normal((n, n))
    F *= draw(st.floats(0.1, 1.3)) / max(np.abs(np.linalg.eigvals(F)).max(), 1e-3)
    H = rng.standard_normal((m, n))
    Bq, Br = rng.standard_normal((n, n)), rng.standard_normal((m, m))
    return F, np.eye(n), H, Bq @ Bq.T + 0.1 * np.eye(n), Br @ Br.T + 0.1 * np.eye(m)


@settings(max_examples=60, deadline=None)
@given(random_models())
def test_doubling_matches_scipy_on_random_models(model):
    expected = scipy_pp(*model)
    got = rekf_doubling(*model)
    assert np.abs(got - expected).max() <= TOL * max(1.0, np.abs(expected).max())
