"""Nonlinear reference filters from the GNSS paper's equations: EKF and UKF with additive noise.

Model: x(k) = f(x(k-1)) + w(k), w ~ N(0, Q);  z(k) = h(x(k), u_k) + v(k), v ~ N(0, R).
f=None means identity dynamics (the GNSS paper's stationary user). h and H_jac are called
as h(x) when inputs is None, else h(x, inputs[k-1]) (e.g. satellite positions at step k).
The EKF also takes inputs in f, x(k) = f(x(k-1), u_k) + w(k), with noise Qu on u_k mapped
through ∂f/∂u (see :func:`ekf`).
Indexing: zs[k-1] = z(k); results hold x(k/k) at row k-1. A NaN in z marks an absent
component (skip_nan=True): only the present components are used in that update.

Q and R may be callables ``(x, u)``: Q is evaluated at x(k-1/k-1), R at x(k/k-1), both
with u_k. ``angles`` (one flag per measurement) marks the components that are angles: their
innovations, and in the UKF the sigma points' deviations, are wrapped to (-pi, pi]
(:func:`wrap`).
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


def wrap(y):
    """``y`` wrapped to (-pi, pi] (an angle's residual): pi stays pi, -pi becomes pi."""
    return np.pi - np.mod(np.pi - np.asarray(y, dtype=float), 2 * np.pi)


def _wrapped(y, angles):
    """``y`` with the components flagged in ``angles`` wrapped (:func:`wrap`)."""
    if angles is None or not np.any(angles):
        return y
    y = np.array(y, dtype=float)
    y[..., angles] = wrap(y[..., angles])
    return y


class _Noise:
    """A noise covariance, constant or a callable ``(x, u)`` (checked square at each
    call)."""

    def __init__(self, name: str, value, size: int | None):
        self.name, self.fn = name, value if callable(value) else None
        self.value = None if self.fn else square(name, value, size or _size(value))

    def at(self, x, u, size: int):
        if self.fn is None:
            return self.value
        return square(self.name, self.fn(x, () if u is None else u), size)


def _size(value) -> int:
    arr = np.asarray(value, dtype=float)
    return 1 if arr.ndim == 0 else arr.shape[0]


def _setup(Q, R, x0, P0, zs, inputs, skip_nan, m=None):
    x = state_vector("x0", x0, np.size(x0))
    n = x.shape[0]
    P = square("P0", P0, n)
    Q = _Noise("Q", Q, n)
    if m is None:
        m = _size(R(x, ()) if callable(R) else R)
    R = _Noise("R", R, m)
    Z = measurement_series(zs, m, allow_nan=skip_nan)
    return x, P, Q, R, Z, inputs_series(inputs, len(Z))


def ekf(f, F_jac, h, H_jac, Q, R, x0, P0, zs, inputs=None, skip_nan: bool = True,
        Fu_jac=None, Qu=None, angles=None, iterations: int = 0, m: int | None = None):
    """Extended Kalman filter: x⁻ = f(x), P⁻ = F P Fᵀ + Q with F = F_jac(x(k-1/k-1))
    (f=None, F_jac=None: identity); H = H_jac(x⁻); K = P⁻Hᵀ[H P⁻ Hᵀ + R]⁻¹;
    x = x⁻ + K[z − h(x⁻)]; P = P⁻ − K H P⁻. Returns a NonlinearResult.

    Inputs in f: with ``Fu_jac`` (∂f/∂u) and ``Qu`` (n_u x n_u, the noise on u) given,
    f, F_jac and Fu_jac are called as fn(x, inputs[k-1]) (the row that goes with zs[k-1])
    and P⁻ = F P Fᵀ + Fu Qu Fuᵀ + Q.

    ``iterations`` = N: the iterated update (Bell and Cathey 1993), x_0 = x⁻ and N times
    x_(i+1) = x⁻ + K_i[z − h(x_i) − H_i (x⁻ − x_i)] with H_i, K_i at x_i (R at x⁻); the
    estimate is the last, P = P⁻ − K_N H_N P⁻."""
    x, P, Q, R, Z, U = _setup(Q, R, x0, P0, zs, inputs, skip_nan, m)
    n = x.shape[0]
    m = Z.shape[1]
    in_f = Fu_jac is not None
    if in_f:
        Qu = np.asarray(Qu, dtype=float)
        if Qu.ndim != 2 or Qu.shape[0] != Qu.shape[1]:
            raise ModelError(f"Qu must be a square matrix, got shape {Qu.shape}")
    out = _Recorder(len(Z), n, m)
    flags = None if angles is None else np.asarray(angles, dtype=bool)
    for k, (z, u) in enumerate(zip(Z, U)):
        Qx = Q.at(x, u, n)
        if in_f:
            Fk = np.asarray(F_jac(x, u), dtype=float)
            Fu = np.asarray(Fu_jac(x, u), dtype=float).reshape(n, Qu.shape[0])
            Qk = Fu @ Qu @ Fu.T + Qx
            x = np.asarray(f(x, u), dtype=float)
        else:
            Fk = np.eye(n) if F_jac is None else np.asarray(F_jac(x), dtype=float)
            x = x.copy() if f is None else np.asarray(f(x), dtype=float)
            Qk = Qx
        P = Fk @ P @ Fk.T + Qk
        present = ~np.isnan(z)
        if not present.any():
            out.save(k, x, P, present)
            continue
        Rk = R.at(x, u, m)[np.ix_(present, present)]
        seen = None if flags is None else flags[present]
        prior, at = x, x
        for _ in range(iterations + 1):
            Hk = _call(H_jac, at, u).reshape(m, n)[present]
            S = Hk @ P @ Hk.T + Rk
            K = np.linalg.solve(S.T, (P @ Hk.T).T).T
            nu = _wrapped(z[present] - _call(h, at, u).reshape(m)[present], seen) \
                - Hk @ (prior - at)
            at = prior + K @ nu
        x = at
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


def _angle_mean(Y, Wm, angles):
    """Σ Wm Y_i, the angle components through the deviations from the first point,
    wrapped: Y_0 + Σ Wm wrap(Y_i − Y_0)."""
    if angles is None or not np.any(angles):
        return Wm @ Y
    mean = Wm @ Y
    deviations = wrap(Y[:, angles] - Y[0, angles])
    mean[angles] = Y[0, angles] + Wm @ deviations
    return mean


def ukf(f, h, Q, R, x0, P0, zs, alpha=None, beta=None, kappa=None, inputs=None,
        skip_nan: bool = True, angles=None, f_inputs: bool = False, m: int | None = None):
    """Unscented Kalman filter with additive noise. Defaults (None): alpha = 1, beta = 0,
    kappa = 3 − n, the paper's plain UKF with n + kappa = 3.

    f=None (identity dynamics): sigma points are drawn once per step from
    (x, P + Q), x⁻ = x and P⁻ = P + Q. Otherwise sigma points from (x, P) pass through f,
    x⁻ and P⁻ = Σ Wc (·)(·)ᵀ + Q are formed and sigma points are redrawn from (x⁻, P⁻)
    (as FilterPy does); for an identity f the two coincide. Update: Ŷ = Σ Wm h(X_i),
    Pyy, Pxy from the points, Pvv = Pyy + R, K = Pxy Pvv⁻¹, x = x⁻ + K(z − Ŷ),
    P = P⁻ − K Pvv Kᵀ. A failed Cholesky raises NumericalError.

    ``f_inputs``: f is called as f(x, inputs[k-1]) (the row that goes with zs[k-1]).
    Angle components (``angles``): Ŷ's through the deviations from the first sigma point,
    Ŷ = Y_0 + Σ Wm wrap(Y_i − Y_0), the spreads wrap(Y_i − Ŷ) and ν = wrap(z − Ŷ)."""
    x, P, Q, R, Z, U = _setup(Q, R, x0, P0, zs, inputs, skip_nan, m)
    n = x.shape[0]
    m = Z.shape[1]
    c, Wm, Wc = sigma_weights(n, 1.0 if alpha is None else alpha,
                              0.0 if beta is None else beta,
                              3.0 - n if kappa is None else kappa)
    out = _Recorder(len(Z), n, m)
    flags = None if angles is None else np.asarray(angles, dtype=bool)
    for k, (z, u) in enumerate(zip(Z, U)):
        Qx = Q.at(x, u, n)
        if f is None:
            P = P + Qx
            X = sigma_points(x, P, c, k + 1)
        else:
            Xf = np.array([np.asarray(f(s, u) if f_inputs else f(s), dtype=float)
                           for s in sigma_points(x, P, c, k + 1)])
            x = Wm @ Xf
            D = Xf - x
            P = D.T @ (Wc[:, None] * D) + Qx
            X = sigma_points(x, P, c, k + 1)
        present = ~np.isnan(z)
        if not present.any():
            out.save(k, x, P, present)
            continue
        seen = None if flags is None else flags[present]
        Y = np.array([_call(h, s, u).reshape(m)[present] for s in X])
        y_hat = _angle_mean(Y, Wm, seen)
        DY, DX = _wrapped(Y - y_hat, seen), X - x
        Pvv = DY.T @ (Wc[:, None] * DY) + R.at(x, u, m)[np.ix_(present, present)]
        Pxy = DX.T @ (Wc[:, None] * DY)
        K = np.linalg.solve(Pvv.T, Pxy.T).T
        nu = _wrapped(z[present] - y_hat, seen)
        x = x + K @ nu
        P = P - K @ Pvv @ K.T
        out.save(k, x, P, present, nu, Pvv)
    return out.result()
