"""Time-varying linear filters written straight from the papers' equations: KF, LF, JKLF and the two
algebraic forms of the MDKF (information form, covariance form; u = 0).

Indexing for every function: zs[k-1] = z(k) for k = 1..steps, and the outputs are
xs[k-1] = x(k/k), Ps[k-1] = P(k/k); x(0/0) = x0 and P(0/0) = P0 are not repeated.
"""

from __future__ import annotations

import numpy as np

from derive.errors import NumericalError
from derive.reference._inputs import measurement_series, square, state_vector
from derive.reference.likelihood import gaussian_loglik, loglik_scale
from derive.riccati import lf_constants
from derive.system_checks import system_arrays


def _setup(F, G, H, Q, R, x0, P0, zs, allow_nan=False):
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    n, m = F.shape[0], H.shape[0]
    x = state_vector("x0", x0, n)
    P = square("P0", P0, n)
    Z = measurement_series(zs, m, allow_nan=allow_nan)
    return F, G, H, Q, R, x, P, Z


def _input_terms(B, D, us, n: int, m: int, steps: int):
    """B u(k) (steps, n) and D u(k) (steps, m) for the rows of ``us`` (zero without)."""
    if us is None:
        return np.zeros((steps, n)), np.zeros((steps, m))
    U = np.asarray(us, dtype=float)
    B, D = np.asarray(B, dtype=float), np.asarray(D, dtype=float)
    if U.ndim != 2 or U.shape[0] != steps or B.shape != (n, U.shape[1]) \
            or D.shape != (m, U.shape[1]):
        raise ValueError(f"us must be (steps={steps}, n_u) with B (n, n_u) and D (m, n_u); "
                         f"got us {U.shape}, B {B.shape}, D {D.shape}")
    return U @ B.T, U @ D.T


def kf(F, G, H, Q, R, x0, P0, zs, skip_nan: bool = True, B=None, D=None, us=None,
       lls: np.ndarray | None = None, ll_scales: np.ndarray | None = None):
    """Kalman filter. Returns (xs (steps, n), Ps (steps, n, n)).

    ``lls`` (steps,): filled with each step's log-likelihood of the innovation,
    log N(nu; 0, S) = -1/2 (m log 2 pi + log det S + nu' S^-1 nu) over the m present
    measurements (0 at a step with none); ``ll_scales`` (steps,) with the scale of each
    (derive.reference.likelihood.loglik_scale).

    skip_nan=True: a NaN in z(k) marks that component as absent; the update uses only the
    present rows of H and R (all absent: prediction only). skip_nan=False refuses NaN.
    ``us`` (steps, n_u) with ``B`` (n, n_u), ``D`` (m, n_u): known inputs, row k with
    zs[k]: x(k+1/k) = F x(k/k) + B us[k], and z(k+1) is predicted as H x(k+1/k) + D us[k]."""
    F, G, H, Q, R, x, P, Z = _setup(F, G, H, Q, R, x0, P0, zs, allow_nan=skip_nan)
    n = F.shape[0]
    Bu, Du = _input_terms(B, D, us, n, H.shape[0], len(Z))
    GQG = G @ Q @ G.T
    xs, Ps = np.empty((len(Z), n)), np.empty((len(Z), n, n))
    for k, z in enumerate(Z):
        x = F @ x + Bu[k]                           # x(k+1/k)
        P = GQG + F @ P @ F.T                       # P(k+1/k)
        present = ~np.isnan(z)
        if present.any():
            Hk, Rk = H[present], R[np.ix_(present, present)]
            PHt = P @ Hk.T
            S = Hk @ PHt + Rk
            K = np.linalg.solve(S.T, PHt.T).T   # P Hᵀ [H P Hᵀ + R]⁻¹
            nu = (z - Du[k])[present] - Hk @ x
            if lls is not None:
                lls[k] = gaussian_loglik(nu, S)
            if ll_scales is not None:
                ll_scales[k] = loglik_scale(z[present], nu, S)
            IKH = np.eye(n) - K @ Hk
            x = IKH @ x + K @ (z - Du[k])[present]
            P = IKH @ P
        else:
            for out in (lls, ll_scales):
                if out is not None:
                    out[k] = 0.0
        xs[k], Ps[k] = x, P
    return xs, Ps


def predictions(F, G, Q, x0, P0, xs, Ps):
    """The one-step predictions of a Kalman filter run whose filtered estimates are (xs,
    Ps): row k is x(k+1/k) = F x(k/k), P(k+1/k) = F P(k/k) F^T + G Q G^T from row k - 1
    (x0, P0 for row 0), as the step that made row k of xs predicted it."""
    F, G, Q = (np.asarray(a, dtype=float) for a in (F, G, Q))
    before = np.concatenate([np.asarray(x0, dtype=float)[None], xs[:-1]])
    P_before = np.concatenate([np.asarray(P0, dtype=float)[None], Ps[:-1]])
    return before @ F.T, F @ P_before @ F.T + G @ Q @ G.T


def lf(F, G, H, Q, R, x0, P0, zs):
    """Lainiotis filter (the papers' constants and per-step equations). Returns (xs, Ps)."""
    F, G, H, Q, R, x, P, Z = _setup(F, G, H, Q, R, x0, P0, zs)
    c = lf_constants(F, G, H, Q, R)
    n = F.shape[0]
    xs, Ps = np.empty((len(Z), n)), np.empty((len(Z), n, n))
    for k, z in enumerate(Z):
        M = np.linalg.inv(np.eye(n) + P @ c.On)
        x = c.Kn @ z + c.Fn @ M @ (P @ c.Km @ z + x)
        P = c.Pn + c.Fn @ M @ P @ c.Fn.T
        xs[k], Ps[k] = x, P
    return xs, Ps


def update_first(run, H, R, x0, P0, zs, skip_nan: bool = True, D=None, us=None, **first):
    """A run from x0, P0 whose step 0 updates them with z(0) without a prediction
    (update-first, pykalman's convention): x(0/0), P(0/0) by :func:`kf` on that step with
    F = I and no process noise (``D``, ``us``: the measurement's input offset D u(0);
    ``first``: more of kf's arguments for that step, ``lls``, ``ll_scales``), then
    ``run(x(0/0), P(0/0), zs[1:], us[1:])`` (a filter started there). Returns (xs, Ps) of
    all the steps."""
    x0 = np.asarray(x0, dtype=float)
    n = x0.shape[0]
    inputs = {} if us is None else {"B": np.zeros((n, np.shape(us)[1])), "D": D,
                                     "us": np.asarray(us, dtype=float)[:1]}
    first_x, first_P = kf(np.eye(n), np.zeros((n, 1)), H, np.zeros((1, 1)), R, x0, P0,
                          np.asarray(zs, dtype=float)[:1], skip_nan=skip_nan, **inputs,
                          **first)
    if len(zs) == 1:
        return first_x, first_P
    xs, Ps = run(first_x[0], first_P[0], np.asarray(zs, dtype=float)[1:],
                 None if us is None else np.asarray(us, dtype=float)[1:])
    return np.concatenate([first_x, xs]), np.concatenate([first_P, Ps])


def jklf(F, G, H, Q, R, x0, P0, zs):
    """Join Kalman-Lainiotis filter: KF and LF run independently, outputs averaged."""
    x_kf, P_kf = kf(F, G, H, Q, R, x0, P0, zs, skip_nan=False)
    x_lf, P_lf = lf(F, G, H, Q, R, x0, P0, zs)
    return (x_kf + x_lf) / 2, (P_kf + P_lf) / 2


def ikf(F, G, H, Q, R, x0, P0, zs):
    """MDKF information form (case m >= n), u = 0, with A = F, Ψ = G Q Gᵀ, V = R:
    R(v)⁻¹ = [A R(v−1) Aᵀ + Ψ]⁻¹ + Hᵀ V⁻¹ H, K(v) = R(v) Hᵀ V⁻¹,
    λ(v) = A λ(v−1) + K(v)[ξ(v) − H A λ(v−1)]. Returns (xs, Ps).
    Needs A R Aᵀ + Ψ invertible at every step (raises NumericalError otherwise)."""
    F, G, H, Q, R, x, P, Z = _setup(F, G, H, Q, R, x0, P0, zs)
    n = F.shape[0]
    Psi = G @ Q @ G.T
    HtVinv = H.T @ np.linalg.inv(R)
    xs, Ps = np.empty((len(Z), n)), np.empty((len(Z), n, n))
    for k, z in enumerate(Z):
        prior = F @ P @ F.T + Psi
        try:
            P = np.linalg.inv(np.linalg.inv(prior) + HtVinv @ H)
        except np.linalg.LinAlgError as exc:
            raise NumericalError(
                f"information-form MDKF, step {k + 1}: A R Aᵀ + Ψ is singular and cannot be "
                "inverted; use the covariance form (mdkf_covariance)") from exc
        K = P @ HtVinv
        x_pred = F @ x
        x = x_pred + K @ (z - H @ x_pred)
        xs[k], Ps[k] = x, P
    return xs, Ps


def mdkf_covariance(F, G, H, Q, R, x0, P0, zs):
    """MDKF covariance form (case m < n), u = 0, with A = F, Ψ = G Q Gᵀ, V = R:
    R~(v) = A R(v−1) Aᵀ + Ψ, K(v) = R~ Hᵀ [H R~ Hᵀ + V]⁻¹,
    λ(v) = A λ(v−1) + K(v)[ξ(v) − H A λ(v−1)], R(v) = [I − K(v) H] R~(v)."""
    F, G, H, Q, R, x, P, Z = _setup(F, G, H, Q, R, x0, P0, zs)
    n = F.shape[0]
    Psi = G @ Q @ G.T
    xs, Ps = np.empty((len(Z), n)), np.empty((len(Z), n, n))
    for k, z in enumerate(Z):
        prior = F @ P @ F.T + Psi
        K = prior @ H.T @ np.linalg.inv(H @ prior @ H.T + R)
        x_pred = F @ x
        x = x_pred + K @ (z - H @ x_pred)
        P = (np.eye(n) - K @ H) @ prior
        xs[k], Ps[k] = x, P
    return xs, Ps
