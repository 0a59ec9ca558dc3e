"""Reference filters: agreement between equivalent filters, with FilterPy, and exact identities."""

import numpy as np
import pytest
import scipy.linalg as sl
from filterpy.kalman import (
    ExtendedKalmanFilter,
    KalmanFilter,
    MerweScaledSigmaPoints,
    UnscentedKalmanFilter,
)

from derive.apps.simulate import gnss_scenario, pseudorange, pseudorange_jacobian, simulate_linear
from derive.errors import ModelError, NumericalError, ShapeError
from derive.reference import (
    ekf,
    fir,
    ikf,
    jklf,
    jssklf,
    kf,
    lf,
    mdkf_covariance,
    pred,
    sskf,
    sslf,
    ukf,
)
from derive.riccati import kf_steady

TOL = 1e-10
STEPS = 500


def axis(dt=1.0, sq2=0.01, sr2=0.1):
    """One MPT3D/GSM2D axis (SPEC §2): F, G, H, Q, R."""
    return (np.array([[1.0, dt], [0.0, 1.0]]), np.array([[dt / 2], [1.0]]),
            np.array([[1.0, dt]]), np.array([[sq2]]), np.array([[sr2]]))


def axes(count):
    """Model A: `count` axes on a block diagonal."""
    return tuple(sl.block_diag(*[M] * count) for M in axis())


def cv(dt=1.0, sq=0.01, sr2=0.1):
    Qd = sq * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    return np.array([[1.0, dt], [0.0, 1.0]]), np.eye(2), np.array([[1.0, 0.0]]), Qd, [[sr2]]


def ca(dt=1.0, sq=0.01, sr2=0.1):
    Qd = sq * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                        [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                        [dt ** 3 / 6, dt ** 2 / 2, dt]])
    F = np.array([[1.0, dt, dt ** 2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    return F, np.eye(3), np.array([[1.0, 0.0, 0.0]]), Qd, [[sr2]]


def measurements(model, seed=7, steps=STEPS):
    n = model[0].shape[0]
    return simulate_linear(*model, np.zeros(n), steps, seed).zs


def zero_start(n):
    return np.zeros(n), np.zeros((n, n))


@pytest.mark.parametrize("count", [3, 2], ids=["mpt3d_a", "gsm2d_a"])
def test_kf_lf_jklf_agree(count):
    model = axes(count)
    zs = measurements(model)
    x0, P0 = zero_start(2 * count)
    runs = [kf(*model, x0, P0, zs), lf(*model, x0, P0, zs), jklf(*model, x0, P0, zs)]
    for xs, Ps in runs[1:]:
        assert np.abs(xs - runs[0][0]).max() <= TOL
        assert np.abs(Ps - runs[0][1]).max() <= TOL


@pytest.mark.parametrize("filt", [kf, lf, jklf])
def test_model_a_equals_three_model_b_axes(filt):
    model_a, model_b = axes(3), axes(1)
    zs = measurements(model_a)
    xs_a, Ps_a = filt(*model_a, *zero_start(6), zs)
    for i in range(3):
        xs_b, Ps_b = filt(*model_b, *zero_start(2), zs[:, i:i + 1])
        block = slice(2 * i, 2 * i + 2)
        assert np.abs(xs_a[:, block] - xs_b).max() <= TOL
        assert np.abs(Ps_a[:, block, block] - Ps_b).max() <= TOL
    off = Ps_a.copy()
    for i in range(3):
        off[:, 2 * i:2 * i + 2, 2 * i:2 * i + 2] = 0
    assert np.abs(off).max() == 0.0


@pytest.mark.parametrize("filt", [sskf, sslf, jssklf])
def test_steady_state_model_a_equals_axes_and_filters_agree(filt):
    model_a, model_b = axes(3), axes(1)
    zs = measurements(model_a)
    xs_a = filt(*model_a, np.zeros(6), zs)
    assert np.abs(xs_a - sskf(*model_a, np.zeros(6), zs)).max() <= TOL
    for i in range(3):
        xs_b = filt(*model_b, np.zeros(2), zs[:, i:i + 1])
        assert np.abs(xs_a[:, 2 * i:2 * i + 2] - xs_b).max() <= TOL


def test_kf_tends_to_sskf():
    model = axes(2)
    zs = measurements(model)
    xs, Ps = kf(*model, *zero_start(4), zs)
    ss = kf_steady(*model)
    assert np.abs(Ps[-1] - ss.Pe).max() <= 1e-12
    # after convergence the KF obeys the steady-state recursion
    assert np.abs(xs[-1] - (ss.A @ xs[-2] + ss.B @ zs[-1])).max() <= 1e-10


def gps_static():
    """MDKF: F = H = G = I3, Q = diag(upsilon, tau, zeta), R = diag(sx², sy², sz²)."""
    return np.eye(3), np.eye(3), np.eye(3), np.diag([1e-4, 2e-4, 5e-4]), np.diag([9.0, 16.0, 25.0])


def test_information_form_equals_covariance_form():
    model = gps_static()
    rng = np.random.default_rng(3)
    truth = np.array([4215471.1, 2340233.7, 4161450.1])
    zs = truth + rng.standard_normal((STEPS, 3)) * np.sqrt(np.diag(model[4]))
    x0, P0 = zs[0] * 0 + truth + 50.0, np.eye(3) * 100.0
    xi, Pi = ikf(*model, x0, P0, zs)
    xc, Pc = mdkf_covariance(*model, x0, P0, zs)
    xk, Pk = kf(*model, x0, P0, zs)
    assert np.abs(Pi - Pc).max() <= TOL
    assert np.abs(xi - xc).max() <= 1e-10 * np.abs(truth).max()   # relative at ECEF scale
    assert np.abs(xc - xk).max() <= 1e-10 * np.abs(truth).max()
    assert np.abs(Pc - Pk).max() <= TOL


def test_information_form_needs_invertible_prior():
    F, G, H, _, R = gps_static()
    with pytest.raises(NumericalError, match="covariance form"):
        ikf(F, G, H, np.zeros((3, 3)), R, np.zeros(3), np.zeros((3, 3)), np.ones((2, 3)))


@pytest.mark.parametrize("make", [cv, ca], ids=["cv", "ca"])
@pytest.mark.parametrize("N", [1, 2, 3, 4, 5])
def test_prediction_equals_f_power_times_sskf(make, N):
    model = make()
    F = model[0]
    n = F.shape[0]
    x0 = np.arange(1.0, n + 1)
    zs = measurements(model, steps=300)
    predicted = pred(*model, x0, zs, N)
    expected = sskf(*model, x0, zs) @ np.linalg.matrix_power(F, N).T
    assert np.abs(predicted - expected).max() <= TOL * max(1.0, np.abs(expected).max())


def test_fir_zero_padding_and_truncation_identity():
    model = axes(2)
    zs = measurements(model)
    ss = kf_steady(*model)
    N = 12
    x_fir = fir(*model, zs, N=N)
    x_ss = sskf(*model, np.zeros(4), zs)
    assert np.abs(x_fir[:N] - x_ss[:N]).max() <= 1e-12
    # x_SSKF(k) − x_FIR(k) = A^N x_SSKF(k−N) exactly
    gap = x_ss[N:] - x_fir[N:]
    assert np.abs(gap - x_ss[:-N] @ np.linalg.matrix_power(ss.A, N).T).max() <= TOL


def test_fir_from_epsilon_uses_minimal_order():
    model = axes(1)
    zs = measurements(model, steps=100)
    ss = kf_steady(*model)
    x_eps = fir(*model, zs, eps=1e-4)
    N = next(i for i in range(1, 1000)
             if np.linalg.norm(np.linalg.matrix_power(ss.A, i), 2) < 1e-4)
    assert np.array_equal(x_eps, fir(*model, zs, N=N))
    with pytest.raises(ModelError, match="exactly one"):
        fir(*model, zs)


def run_filterpy_kf(F, G, H, Q, R, x0, P0, zs):
    f = KalmanFilter(dim_x=F.shape[0], dim_z=H.shape[0])
    f.F, f.H, f.Q, f.R = F, H, G @ Q @ G.T, R
    f.x, f.P = x0.reshape(-1, 1).copy(), P0.copy()
    xs, Ps = [], []
    for z in zs:           # filterpy: predict to k, then update with z(k) -> x(k/k)
        f.predict()
        f.update(z.reshape(-1, 1))
        xs.append(f.x.ravel().copy())
        Ps.append(f.P.copy())
    return np.array(xs), np.array(Ps)


def test_kf_matches_filterpy():
    model = axes(3)
    zs = measurements(model)
    x0, P0 = np.ones(6), np.eye(6)
    xs, Ps = kf(*model, x0, P0, zs)
    xf, Pf = run_filterpy_kf(*model, x0, P0, zs)
    assert np.abs(xs - xf).max() <= 1e-9
    assert np.abs(Ps - Pf).max() <= 1e-9


def test_kf_skips_absent_components():
    model_a, model_b = axes(3), axes(1)
    zs = measurements(model_a).copy()
    zs[10:20, 0] = np.nan                 # x-axis measurement lost for ten steps
    zs[30, :] = np.nan                    # everything lost once
    xs_a, Ps_a = kf(*model_a, *zero_start(6), zs)
    for i in range(3):
        xs_b, Ps_b = kf(*model_b, *zero_start(2), zs[:, i:i + 1])
        assert np.abs(xs_a[:, 2 * i:2 * i + 2] - xs_b).max() <= TOL
        assert np.abs(Ps_a[:, 2 * i:2 * i + 2, 2 * i:2 * i + 2] - Ps_b).max() <= TOL
    F, G, _, Q, _ = model_a
    assert np.allclose(xs_a[30], F @ xs_a[29], atol=1e-15)
    assert np.allclose(Ps_a[30], F @ Ps_a[29] @ F.T + G @ Q @ G.T, atol=1e-15)
    with pytest.raises(ModelError, match="NaN"):
        kf(*model_a, *zero_start(6), zs, skip_nan=False)


def test_shapes_are_checked():
    model = axes(1)
    with pytest.raises(ShapeError, match="zs must have shape"):
        kf(*model, *zero_start(2), np.zeros((5, 2)))
    with pytest.raises(ShapeError, match="x0 must have 2 entries"):
        lf(*model, np.zeros(3), np.zeros((2, 2)), np.zeros(5))
    with pytest.raises(ShapeError, match="P0 must have shape"):
        kf(*model, np.zeros(2), np.zeros((3, 3)), np.zeros(5))


# ---------------------------------------------------------------- nonlinear (GNSS)
@pytest.fixture(scope="module")
def gnss():
    return gnss_scenario(steps=300, seed=11)


def h_gnss(x, sats):
    return pseudorange(x, sats)


def hjac_gnss(x, sats):
    return pseudorange_jacobian(x, sats)


def test_ekf_matches_filterpy(gnss):
    res = ekf(None, None, h_gnss, hjac_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0,
              gnss.pseudoranges, inputs=gnss.satellites)
    f = ExtendedKalmanFilter(dim_x=4, dim_z=4)
    f.x, f.P, f.Q, f.R, f.F = gnss.x0.copy(), gnss.P0.copy(), gnss.Q, gnss.R, np.eye(4)
    for k, (z, sats) in enumerate(zip(gnss.pseudoranges, gnss.satellites)):
        f.predict()
        f.update(z, hjac_gnss, h_gnss, args=(sats,), hx_args=(sats,))
        assert np.abs(res.xs[k] - f.x).max() <= 1e-6
        assert np.abs(res.Ps[k] - f.P).max() <= 1e-9
        assert np.abs(res.innovations[k] - f.y).max() <= 1e-6
        assert np.allclose(res.normalized_innovations[k], f.y / np.sqrt(np.diag(f.S)),
                           atol=1e-8)


def run_filterpy_ukf(gnss, alpha, beta, kappa, fx=None):
    points = MerweScaledSigmaPoints(4, alpha=alpha, beta=beta, kappa=kappa)
    f = UnscentedKalmanFilter(dim_x=4, dim_z=4, dt=1.0, hx=h_gnss,
                              fx=fx or (lambda x, dt: x), points=points)
    f.x, f.P, f.Q, f.R = gnss.x0.copy(), gnss.P0.copy(), gnss.Q, gnss.R
    xs, Ps = [], []
    for z, sats in zip(gnss.pseudoranges, gnss.satellites):
        f.predict()                 # P⁻ = P + Q (identity f), sigma points redrawn from P⁻
        f.update(z, sats=sats)
        xs.append(f.x.copy())
        Ps.append(f.P.copy())
    return np.array(xs), np.array(Ps)


# Small alpha gives weights of size 1/alpha²; with pseudoranges of 2e7 m both filters then
# lose ~|Wm0|·2e7·eps metres to cancellation, so alpha stays >= 0.3 for the 1e-6 m bar.
@pytest.mark.parametrize("params", [(None, None, None), (1.0, 0.0, -1.0), (0.5, 2.0, 0.0),
                                    (0.3, 2.0, 1.0)],
                         ids=["paper-default", "paper-explicit", "scaled", "scaled-kappa"])
def test_ukf_matches_filterpy(gnss, params):
    alpha, beta, kappa = params
    res = ukf(None, lambda x, sats: pseudorange(x, sats), gnss.Q, gnss.R, gnss.x0, gnss.P0,
              gnss.pseudoranges, alpha=alpha, beta=beta, kappa=kappa, inputs=gnss.satellites)
    fp = (1.0, 0.0, -1.0) if alpha is None else params
    xf, Pf = run_filterpy_ukf(gnss, *fp)
    assert np.abs(res.xs - xf).max() <= 1e-6
    assert np.abs(res.Ps - Pf).max() <= 1e-6


def test_ukf_with_identity_f_equals_paper_form(gnss):
    args = (h_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0, gnss.pseudoranges)
    paper = ukf(None, *args, inputs=gnss.satellites)
    general = ukf(lambda x: x, *args, inputs=gnss.satellites)
    assert np.abs(paper.xs - general.xs).max() <= 1e-6
    assert np.abs(paper.Ps - general.Ps).max() <= 1e-6


def pendulum(x, dt=0.05):
    return np.array([x[0] + dt * x[1], x[1] - dt * 9.81 * np.sin(x[0])])


def pendulum_jac(x, dt=0.05):
    return np.array([[1.0, dt], [-dt * 9.81 * np.cos(x[0]), 1.0]])


def pendulum_case():
    rng = np.random.default_rng(5)
    truth = [np.array([1.0, 0.0])]
    for _ in range(200):
        truth.append(pendulum(truth[-1]))
    truth = np.array(truth[1:])
    zs = np.sin(truth[:, :1]) + 0.05 * rng.standard_normal((200, 1))
    return zs, np.diag([1e-5, 1e-4]), np.array([[0.05 ** 2]]), np.array([0.8, 0.1]), np.eye(2) * 0.1


def test_nonlinear_dynamics_match_filterpy():
    zs, Q, R, x0, P0 = pendulum_case()
    h = lambda x: np.sin(x[:1])
    hjac = lambda x: np.array([[np.cos(x[0]), 0.0]])
    res = ekf(pendulum, pendulum_jac, h, hjac, Q, R, x0, P0, zs)
    f = ExtendedKalmanFilter(dim_x=2, dim_z=1)
    f.x, f.P, f.Q, f.R = x0.copy(), P0.copy(), Q, R
    for k, z in enumerate(zs):
        f.F = pendulum_jac(f.x)
        f.x = pendulum(f.x)            # FilterPy's EKF predicts linearly: set x⁻ by hand
        f.P = f.F @ f.P @ f.F.T + f.Q
        f.update(z, hjac, h)
        assert np.abs(res.xs[k] - f.x).max() <= 1e-9
    res_u = ukf(pendulum, h, Q, R, x0, P0, zs, alpha=0.3, beta=2.0, kappa=0.0)
    points = MerweScaledSigmaPoints(2, alpha=0.3, beta=2.0, kappa=0.0)
    u = UnscentedKalmanFilter(dim_x=2, dim_z=1, dt=0.05, hx=h,
                              fx=lambda x, dt: pendulum(x), points=points)
    u.x, u.P, u.Q, u.R = x0.copy(), P0.copy(), Q, R
    xu, _ = u.batch_filter(zs)
    assert np.abs(res_u.xs - xu).max() <= 1e-9


def test_ukf_refuses_indefinite_covariance(gnss):
    P0 = np.diag([100.0, 100.0, 100.0, -50.0])
    with pytest.raises(NumericalError, match="Cholesky"):
        ukf(None, h_gnss, gnss.Q, gnss.R, gnss.x0, P0, gnss.pseudoranges,
            inputs=gnss.satellites)


def test_normalised_innovations_are_unit_scale(gnss):
    for res in (ekf(None, None, h_gnss, hjac_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0,
                    gnss.pseudoranges, inputs=gnss.satellites),
                ukf(None, h_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0, gnss.pseudoranges,
                    inputs=gnss.satellites)):
        nu = res.normalized_innovations
        assert nu.shape == (300, 4)
        # 300 samples of a unit normal per satellite: std within ±20 % (≈ 5 standard errors)
        assert np.all(np.abs(nu.std(axis=0) - 1.0) < 0.2)
        assert np.all(np.abs(nu.mean(axis=0)) < 5 / np.sqrt(300))


def test_nonlinear_filters_skip_absent_satellites(gnss):
    zs = gnss.pseudoranges.copy()
    zs[5:8, 2] = np.nan
    res = ekf(None, None, h_gnss, hjac_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0, zs,
              inputs=gnss.satellites)
    three = [0, 1, 3]
    sub = ekf(None, None, lambda x, s: pseudorange(x, s[three]),
              lambda x, s: pseudorange_jacobian(x, s[three]), gnss.Q, gnss.R[np.ix_(three, three)],
              res.xs[4], res.Ps[4], zs[5:8, three], inputs=gnss.satellites[5:8])
    assert np.abs(res.xs[5:8] - sub.xs).max() <= 1e-9
    assert np.isnan(res.normalized_innovations[5:8, 2]).all()
    assert np.all(np.isfinite(ukf(None, h_gnss, gnss.Q, gnss.R, gnss.x0, gnss.P0, zs,
                                  inputs=gnss.satellites).xs))
