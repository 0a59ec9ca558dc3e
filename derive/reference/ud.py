"""The UD (Bierman-Thornton) Kalman filter in NumPy, in any floating dtype.

P = U D Uᵀ is carried as a unit upper-triangular U and a diagonal D (a vector); no
square root is taken anywhere.  One step, x(k/k), U(k/k), D(k/k) -> x(k+1/k+1), ...:

- time update, Thornton's modified weighted Gram-Schmidt (MWGS): the rows of
  W = [F U | G Lq] are orthogonalised, last row first, in the weights diag(D, Dq), where
  Q = Lq Dq Lqᵀ (Lq = I, Dq = Q when Q is diagonal); then F U D Uᵀ Fᵀ + G Q Gᵀ = W diag(D, Dq) Wᵀ
  = U' D' U'ᵀ;
- measurement update, Bierman's scalar updates, one measurement component at a time.
  They need uncorrelated measurement noise: when R is not diagonal the measurement is
  whitened with R = L Dr Lᵀ (L unit lower triangular): z' = L⁻¹ z, H' = L⁻¹ H, R' = Dr.
  A NaN in z(k)[i] marks component i absent; the whitening is then that of the present
  components' block of R (absent components are dropped, as in reference.kf).

A zero pivot (a singular P(k+1/k), e.g. P0 = 0 with a rank-deficient G Q Gᵀ) is exact
here: its column of U is set to zero (any column gives the same P); a negative pivot
raises NumericalError.  The generated programs (derive.filters.udkf) divide by d itself,
or by 1 where d <= 0, which gives the same zero column.  Bierman's new D_j is
D_j (alpha_(j-1) / alpha_j), the ratio first: D_j alpha_(j-1), a product of two variances,
underflows for P ~ 1e-154 (in float32 for P ~ 1e-19).

Indexing as in derive.reference.linear: zs[k-1] = z(k); outputs [k-1] are at step k.
"""

from __future__ import annotations

import numpy as np

from derive.errors import NumericalError
from derive.reference._inputs import measurement_series, square, state_vector


def ud_factor(P, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """``P = U diag(D) Uᵀ`` of a symmetric positive-semidefinite P (upper triangle read),
    U unit upper triangular; a zero pivot gives a zero column of U above the diagonal."""
    P = np.asarray(P, dtype=dtype)
    n = P.shape[0]
    U, D = np.eye(n, dtype=dtype), np.zeros(n, dtype=dtype)
    for j in reversed(range(n)):
        E = U[:, j + 1:] * D[j + 1:]          # E[i, k] = U[i, k] D[k]
        D[j] = P[j, j] - E[j] @ U[j, j + 1:]
        if D[j] < 0 or not np.isfinite(D[j]):
            raise NumericalError(f"ud_factor: P is not positive semidefinite (pivot {j} "
                                 f"is {D[j]!r})")
        if D[j] > 0:
            U[:j, j] = (P[:j, j] - E[:j] @ U[j, j + 1:]) / D[j]
    return U, D


def ud_compose(U, D) -> np.ndarray:
    """``U diag(D) Uᵀ``."""
    return (U * D) @ U.T


def ldl_lower(R, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """``R = L diag(Dr) Lᵀ``, L unit lower triangular, R symmetric positive definite."""
    R = np.asarray(R, dtype=dtype)
    m = R.shape[0]
    L, Dr = np.eye(m, dtype=dtype), np.zeros(m, dtype=dtype)
    for j in range(m):
        E = L[:, :j] * Dr[:j]
        Dr[j] = R[j, j] - E[j] @ L[j, :j]
        if not Dr[j] > 0:
            raise NumericalError(f"ldl_lower: the matrix is not positive definite "
                                 f"(pivot {j} is {Dr[j]!r})")
        L[j + 1:, j] = (R[j + 1:, j] - E[j + 1:] @ L[j, :j]) / Dr[j]
    return L, Dr


def mwgs(W, weights) -> tuple[np.ndarray, np.ndarray]:
    """Thornton's modified weighted Gram-Schmidt: U, D with ``U diag(D) Uᵀ = W diag(weights) Wᵀ``
    (W is n x N, weights >= 0); rows are orthogonalised from the last to the first."""
    W = np.array(W)
    n = W.shape[0]
    U, D = np.eye(n, dtype=W.dtype), np.zeros(n, dtype=W.dtype)
    for j in reversed(range(n)):
        c = weights * W[j]
        D[j] = W[j] @ c
        if D[j] < 0 or not np.isfinite(D[j]):
            raise NumericalError(f"mwgs: pivot {j} is {D[j]!r}")
        if D[j] == 0:
            continue                           # row j is zero in the weights: U[:j, j] = 0
        for i in range(j):
            U[i, j] = (W[i] @ c) / D[j]
            W[i] -= U[i, j] * W[j]
    return U, D


def bierman(x, U, D, z, h, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bierman's update of (x, U, D) with the scalar measurement z = h x + v, var(v) = r."""
    x, U, D = x.copy(), U.copy(), D.copy()
    n = len(x)
    f = U.T @ h
    v = D * f
    b = np.zeros_like(x)
    alpha = r
    for j in range(n):
        before = alpha
        alpha = before + f[j] * v[j]
        if not alpha > 0:
            raise NumericalError(f"bierman: innovation variance {j} is {alpha!r}")
        D[j] = D[j] * (before / alpha)   # D[j] * before underflows for P ~ 1e-154
        gain = -f[j] / before
        for i in range(j):
            old = U[i, j]
            U[i, j] = old + b[i] * gain
            b[i] = b[i] + old * v[j]
        b[j] = v[j]
    x = x + b * ((z - h @ x) / alpha)
    return x, U, D


def time_update(F, G_weighted, Dq, x, U, D):
    """x(k+1/k) = F x and the MWGS factors of F U D Uᵀ Fᵀ + G_weighted diag(Dq) G_weightedᵀ."""
    W = np.hstack([F @ U, G_weighted])
    U, D = mwgs(W, np.concatenate([D, Dq]))
    return F @ x, U, D


def measurement_update(H, R, x, U, D, z):
    """Bierman's scalar updates with the present components of z, whitened when R is not
    diagonal (R's present block = L diag(Dr) Lᵀ: z' = L⁻¹ z, H' = L⁻¹ H)."""
    present = ~np.isnan(z)
    Hp, Rp, zp = H[present], R[np.ix_(present, present)], z[present]
    if np.count_nonzero(Rp - np.diag(np.diag(Rp))):
        L, r = ldl_lower(Rp, dtype=Rp.dtype)
        Hp, zp = np.linalg.solve(L, Hp).astype(Rp.dtype), np.linalg.solve(L, zp).astype(Rp.dtype)
    else:
        r = np.diag(Rp)
    for i in range(len(zp)):
        x, U, D = bierman(x, U, D, zp[i], Hp[i], r[i])
    return x, U, D


def process_noise_factors(G, Q, dtype) -> tuple[np.ndarray, np.ndarray]:
    """``G Lq`` and ``Dq`` with Q = Lq diag(Dq) Lqᵀ (Q diagonal: G and its diagonal)."""
    Q = np.asarray(Q, dtype=dtype)
    if not np.count_nonzero(Q - np.diag(np.diag(Q))):
        return np.asarray(G, dtype=dtype), np.diag(Q).copy()
    Lq, Dq = ldl_lower(Q, dtype=dtype)
    return (np.asarray(G, dtype=dtype) @ Lq).astype(dtype), Dq


def ud_kf_factors(num, zs, x0=None, P0=None, dtype=np.float64):
    """The UD filter on the numeric linear model ``num`` (F, G, H, Q, R, x0, P0).

    Returns (xs (steps, n), Us (steps, n, n), Ds (steps, n)), all of ``dtype``."""
    F, H, R = (np.asarray(a, dtype=dtype) for a in (num.F, num.H, num.R))
    n, m = F.shape[0], H.shape[0]
    x = state_vector("x0", num.x0 if x0 is None else x0, n).astype(dtype)
    P = square("P0", num.P0 if P0 is None else P0, n)
    Z = measurement_series(zs, m).astype(dtype)
    Gw, Dq = process_noise_factors(num.G, num.Q, dtype)
    U, D = ud_factor(P, dtype=dtype)
    xs = np.empty((len(Z), n), dtype=dtype)
    Us, Ds = np.empty((len(Z), n, n), dtype=dtype), np.empty((len(Z), n), dtype=dtype)
    for k, z in enumerate(Z):
        x, U, D = time_update(F, Gw, Dq, x, U, D)
        x, U, D = measurement_update(H, R, x, U, D, z)
        xs[k], Us[k], Ds[k] = x, U, D
    return xs, Us, Ds


def ud_kf(num, zs, x0=None, P0=None, dtype=np.float64):
    """The UD filter; returns (xs (steps, n), Ps (steps, n, n)) with P = U D Uᵀ."""
    xs, Us, Ds = ud_kf_factors(num, zs, x0, P0, dtype)
    return xs, (Us * Ds[:, None, :]) @ Us.transpose(0, 2, 1)


def covariance_kf(num, zs, x0=None, P0=None, dtype=np.float64, joseph: bool = False):
    """The covariance KF of reference.kf (same operations) in ``dtype``; ``joseph``: the
    Joseph-form update (I - K H) P (I - K H)ᵀ + K R Kᵀ.  No missing measurements."""
    F, G, H, Q, R = (np.asarray(a, dtype=dtype) for a in (num.F, num.G, num.H, num.Q, num.R))
    n, m = F.shape[0], H.shape[0]
    x = state_vector("x0", num.x0 if x0 is None else x0, n).astype(dtype)
    P = square("P0", num.P0 if P0 is None else P0, n).astype(dtype)
    Z = measurement_series(zs, m, allow_nan=False).astype(dtype)
    GQG, eye = G @ Q @ G.T, np.eye(n, dtype=dtype)
    xs, Ps = np.empty((len(Z), n), dtype=dtype), np.empty((len(Z), n, n), dtype=dtype)
    for k, z in enumerate(Z):
        x = F @ x
        P = GQG + F @ P @ F.T
        PHt = P @ H.T
        K = np.linalg.solve((H @ PHt + R).T, PHt.T).T
        IKH = eye - K @ H
        x = IKH @ x + K @ z
        P = IKH @ P @ IKH.T + K @ R @ K.T if joseph else IKH @ P
        xs[k], Ps[k] = x, P
    return xs, Ps
