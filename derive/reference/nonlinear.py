"""Nonlinear reference filters from the GNSS paper's equations: EKF and UKF with additive noise.

Model: x(k) = f(x(k-1)) + w(k), w ~ N(0, Q);  z(k) = h(x(k), u_k) + v(k), v ~ N(0, R).
f=None means identity dynamics (the GNSS paper's stationary user). h and H_jac are called
as h(x) when inputs is None, else h(x, inputs[k-1]) (e.g. satellite positions at step k).
The EKF also takes inputs in f, x(k) = f(x(k-1), u_k) + w(k), with noise Qu on u_k mapped
through ∂f/∂u (see :func:`ekf`).
Indexing: zs[k-1] = z(k); results hold x(k/k) at row k-1. A NaN in z marks an absent
component (skip_nan=True): only the present components are used in that update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.errors import ModelError, NumericalError
from derive.reference._inputs import inputs_series, measurement_series, square, state_vector


@dataclass(frozen=True)
class NonlinearResult:
    """Filter output over time. innovations[k-1] = z(k) − ẑ(k/k−1); normalized_innovations
    divides each component by sqrt of the innovation covariance diagonal S_ii (NaN where a
    component was absent)."""

    xs: np.ndarray
    Ps: np.ndarray
    innovations: np.ndarray
    innovation_covariances: np.ndarray
    normalized_innovations: np.ndarray


class _Recorder:
    def __init__(self, steps: int, n: int, m: int):
        self.xs, self.Ps = np.empty((steps, n)), np.empty((steps, n, n))
        self.nu = np.full((steps, m), np.nan)
        self.S = np.full((steps, m, m), np.nan)

    def save(self, k, x, P, present, nu=None, S=None):
        self.xs[k], self.Ps[k] = x, P
        if nu is not None:
            self.nu[k, present] = nu
            self.S[k][np.ix_(present, present)] = S

    def result(self) -> NonlinearResult:
        diag = np.diagonal(self.S, axis1=1, axis2=2)
        return NonlinearResult(self.xs, self.Ps, self.nu, self.S, self.nu / np.sqrt(diag))


def _call(fn, x, u):
    return np.asarray(fn(x) if u is None else fn(x, u), dtype=float)


def _setup(Q, R, x0, P0, zs, inputs, skip_nan):
    x = state_vector("x0", x0, np.size(x0))
    n = x.shape[0]
    P = square("P0", P0, n)
    Q = square("Q", Q, n)
    R_arr = np.asarray(R, dtype=float)
    m = 1 if R_arr.ndim == 0 else R_arr.shape[0]
    R = square("R", R, m)
    Z = measurement_series(zs, m, allow_nan=skip_nan)
    return x, P, Q, R, Z, inputs_series(inputs, len(Z))


def ekf(f, F_jac, h, H_jac, Q, R, x0, P0, zs, inputs=None, skip_nan: bool = True,
        Fu_jac=None, Qu=None):
    """Extended Kalman filter: x⁻ = f(x), P⁻ = F P Fᵀ + Q with F = F_jac(x(k-1/k-1))
    (f=None, F_jac=None: identity); H = H_jac(x⁻); K = P⁻Hᵀ[H P⁻ Hᵀ + R]⁻¹;
    x = x⁻ + K[z − h(x⁻)]; P = P⁻ − K H P⁻. Returns a NonlinearResult.

    Inputs in f: with ``Fu_jac`` (∂f/∂u) and ``Qu`` (n_u x n_u, the noise on u) given,
    f, F_jac and Fu_jac are called as fn(x, inputs[k-1]) (the row that goes with zs[k-1])
    and P⁻ = F P Fᵀ + Fu Qu Fuᵀ + Q."""
    x, P, Q, R, Z, U = _setup(Q, R, x0, P0, zs, inputs, skip_nan)
    n, m = x.shape[0], R.shape[0]
    in_f = Fu_jac is not None
    if in_f:
        Qu = np.asarray(Qu, dtype=float)
        if Qu.ndim != 2 or Qu.shape[0] != Qu.shape[1]:
            raise ModelError(f"Qu must be a square matrix, got shape {Qu.shape}")
    out = _Recorder(len(Z), n, m)
    for k, (z, u) in enumerate(zip(Z, U)):
        if in_f:
            Fk = np.asarray(F_jac(x, u), dtype=float)
            Fu = np.asarray(Fu_jac(x, u), dtype=float).reshape(n, Qu.shape[0])
            Qk = Fu @ Qu @ Fu.T + Q
            x = np.asarray(f(x, u), dtype=float)
        else:
            Fk = np.eye(n) if F_jac is None else np.asarray(F_jac(x), dtype=float)
            x = x.copy() if f is None else np.asarray(f(x), dtype=float)
            Qk = Q
        P = Fk @ P @ Fk.T + Qk
        present = ~np.isnan(z)
        if not present.any():
            out.save(k, x, P, present)
            continue
        Hk = _call(H_jac, x, u).reshape(m, n)[present]
        Rk = R[np.ix_(present, present)]
        S = Hk @ P @ Hk.T + Rk
        K = np.linalg.solve(S.T, (P @ Hk.T).T).T
        nu = z[present] - _call(h, x, u).reshape(m)[present]
        x = x + K @ nu
        P = P - K @ Hk @ P
        out.save(k, x, P, present, nu, S)
    return out.result()


def sigma_weights(n: int, alpha: float, beta: float, kappa: float):
    """Scaled unscented weights (Wan & van der Merwe): lambda = alpha²(n + kappa) − n,
    Wm0 = lambda/(n + lambda), Wc0 = Wm0 + 1 − alpha² + beta, Wi = 1/(2(n + lambda)).
    Returns (c = n + lambda, Wm, Wc). alpha=1, beta=0 gives the plain UKF (W0 = kappa/(n+kappa))."""
    c = alpha ** 2 * (n + kappa)
    if not c > 0:
        raise ModelError(f"UKF needs alpha²(n + kappa) > 0, got {c:g} (n={n}, "
                         f"alpha={alpha:g}, kappa={kappa:g})")
    lam = c - n
    Wm = np.full(2 * n + 1, 1.0 / (2 * c))
    Wm[0] = lam / c
    Wc = Wm.copy()
    Wc[0] += 1.0 - alpha ** 2 + beta
    return c, Wm, Wc


def sigma_points(x: np.ndarray, P: np.ndarray, c: float, step: int) -> np.ndarray:
    """Rows x, x + L_i, x − L_i with L the lower Cholesky factor of c·P (L_i its columns)."""
    try:
        L = np.linalg.cholesky(c * P)
    except np.linalg.LinAlgError as exc:
        eig = np.linalg.eigvalsh((P + P.T) / 2).min()
        raise NumericalError(
            f"UKF step {step}: Cholesky of the sigma-point covariance failed, it is not "
            f"positive definite (smallest eigenvalue {eig:.3g}); a negative weight W0 can "
            "make P indefinite") from exc
    return np.vstack([x, x + L.T, x - L.T])


def ukf(f, h, Q, R, x0, P0, zs, alpha=None, beta=None, kappa=None, inputs=None,
        skip_nan: bool = True):
    """Unscented Kalman filter with additive noise. Defaults (None): alpha = 1, beta = 0,
    kappa = 3 − n, the paper's plain UKF with n + kappa = 3.

    f=None (identity dynamics): sigma points are drawn once per step from
    (x, P + Q), x⁻ = x and P⁻ = P + Q. Otherwise sigma points from (x, P) pass through f,
    x⁻ and P⁻ = Σ Wc (·)(·)ᵀ + Q are formed and sigma points are redrawn from (x⁻, P⁻)
    (as FilterPy does); for an identity f the two coincide. Update: Ŷ = Σ Wm h(X_i),
    Pyy, Pxy from the points, Pvv = Pyy + R, K = Pxy Pvv⁻¹, x = x⁻ + K(z − Ŷ),
    P = P⁻ − K Pvv Kᵀ. A failed Cholesky raises NumericalError."""
    x, P, Q, R, Z, U = _setup(Q, R, x0, P0, zs, inputs, skip_nan)
    n, m = x.shape[0], R.shape[0]
    c, Wm, Wc = sigma_weights(n, 1.0 if alpha is None else alpha,
                              0.0 if beta is None else beta,
                              3.0 - n if kappa is None else kappa)
    out = _Recorder(len(Z), n, m)
    for k, (z, u) in enumerate(zip(Z, U)):
        if f is None:
            P = P + Q
            X = sigma_points(x, P, c, k + 1)
        else:
            Xf = np.array([np.asarray(f(s), dtype=float) for s in sigma_points(x, P, c, k + 1)])
            x = Wm @ Xf
            D = Xf - x
            P = D.T @ (Wc[:, None] * D) + Q
            X = sigma_points(x, P, c, k + 1)
        present = ~np.isnan(z)
        if not present.any():
            out.save(k, x, P, present)
            continue
        Y = np.array([_call(h, s, u).reshape(m)[present] for s in X])
        y_hat = Wm @ Y
        DY, DX = Y - y_hat, X - x
        Pvv = DY.T @ (Wc[:, None] * DY) + R[np.ix_(present, present)]
        Pxy = DX.T @ (Wc[:, None] * DY)
        K = np.linalg.solve(Pvv.T, Pxy.T).T
        nu = z[present] - y_hat
        x = x + K @ nu
        P = P - K @ Pvv @ K.T
        out.save(k, x, P, present, nu, Pvv)
    return out.result()
