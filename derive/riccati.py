"""Riccati equations of the KF (REKF) and LF (RELF), solved per step and by doubling.

Plain NumPy on numeric arrays (SPEC.md §3-4). Before any steady state is computed the
model is checked with PBH tests: (F, H) detectable and (F, G Q^1/2) stabilisable, i.e. every
eigenvalue with |lambda| >= 1 is observable / controllable. A failed check, a failed
convergence or a bad FIR epsilon raises derive.errors.SteadyStateError.
"""

from __future__ import annotations

from numbers import Real
from typing import NamedTuple

import numpy as np

from derive.errors import MatrixPropertyError, ModelError, ShapeError, SteadyStateError

DEFAULT_TOL = 1e-13
"""Relative change of P between iterations at which an iteration is converged."""
MAX_STEPS = 100_000
"""Iteration cap of the per-step recursions (doubling uses MAX_DOUBLINGS)."""
MAX_DOUBLINGS = 100
UNIT_CIRCLE_MARGIN = 1e-9
"""Eigenvalues with |lambda| >= 1 - margin are treated as not asymptotically stable."""
PBH_RANK_TOL = 1e-8
"""PBH tests call a mode unobservable/uncontrollable when sigma_min < tol * scale."""


# ---------------------------------------------------------------- input arrays
def _matrix(name: str, value, rows: int | None, cols: int | None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name} must be a numeric matrix: {exc}") from exc
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    elif arr.ndim == 1:
        arr = arr.reshape(1, -1) if name == "H" else arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise ShapeError(f"{name} must be 2-D, got shape {arr.shape}")
    want = (arr.shape[0] if rows is None else rows, arr.shape[1] if cols is None else cols)
    if arr.shape != want:
        raise ShapeError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains NaN or inf")
    return arr


def _covariance(name: str, value, size: int, definite: bool) -> np.ndarray:
    arr = _matrix(name, value, size, size)
    if not np.allclose(arr, arr.T, rtol=1e-12, atol=1e-14 * max(1.0, np.abs(arr).max())):
        raise MatrixPropertyError(f"{name} must be symmetric")
    low = np.linalg.eigvalsh((arr + arr.T) / 2).min()
    floor = -1e-12 * max(1.0, np.abs(arr).max())
    if low <= (0.0 if definite else floor):
        kind = "positive definite" if definite else "positive semidefinite"
        raise MatrixPropertyError(f"{name} must be {kind}; smallest eigenvalue {low:.3g}")
    return arr


def system_arrays(F, G, H, Q, R):
    """Validate and return (F, G, H, Q, R) as float 2-D arrays (shapes n×n, n×p, m×n, p×p,
    m×m). A 1-D H is a row, a 1-D G a column, a scalar a 1×1 matrix. R must be positive
    definite and Q positive semidefinite; failures raise ModelError subclasses."""
    F = _matrix("F", F, None, None)
    n = F.shape[0]
    if F.shape[1] != n:
        raise ShapeError(f"F must be square, got {F.shape}")
    G = _matrix("G", G, n, None)
    H = _matrix("H", H, None, n)
    Q = _covariance("Q", Q, G.shape[1], definite=False)
    R = _covariance("R", R, H.shape[0], definite=True)
    return F, G, H, Q, R


def psd_sqrt(M: np.ndarray) -> np.ndarray:
    """Symmetric square root of a positive semidefinite matrix (negative rounding clipped)."""
    w, V = np.linalg.eigh((M + M.T) / 2)
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


# ---------------------------------------------------------------- PBH tests
def _eigen_clusters(F: np.ndarray) -> list[complex]:
    """Eigenvalues of F plus the mean of each cluster of close eigenvalues: a defective
    eigenvalue is computed only to ~eps^(1/k), the cluster mean to ~eps."""
    lams = list(np.linalg.eigvals(F))
    scale = max(1.0, np.linalg.norm(F, 2))
    points = list(lams)
    remaining = sorted(lams, key=lambda z: (z.real, z.imag))
    while remaining:
        seed = remaining.pop(0)
        cluster = [seed] + [z for z in remaining if abs(z - seed) < 1e-4 * scale]
        remaining = [z for z in remaining if abs(z - seed) >= 1e-4 * scale]
        if len(cluster) > 1:
            points.append(complex(np.mean(cluster)))
    return points


def _pbh_unobservable(F: np.ndarray, C: np.ndarray) -> complex | None:
    """An eigenvalue of F with |lambda| >= 1 whose mode C cannot see, else None."""
    n = F.shape[0]
    scale = max(1.0, np.linalg.norm(F, 2), np.linalg.norm(C, 2) if C.size else 0.0)
    for lam in _eigen_clusters(F):
        if abs(lam) < 1.0 - UNIT_CIRCLE_MARGIN:
            continue
        pbh = np.vstack([lam * np.eye(n) - F, C.astype(complex)])
        if np.linalg.svd(pbh, compute_uv=False)[-1] < PBH_RANK_TOL * scale:
            return complex(lam)
    return None


def _fmt(lam: complex) -> str:
    return f"{lam.real:.6g}" if abs(lam.imag) < 1e-12 else f"{lam:.6g}"


def check_detectable(F, H) -> None:
    """Raise SteadyStateError if (F, H) is not detectable (PBH test on |lambda| >= 1)."""
    F = np.asarray(F, dtype=float)
    lam = _pbh_unobservable(F, np.atleast_2d(np.asarray(H, dtype=float)))
    if lam is not None:
        raise SteadyStateError(
            f"(F, H) is not detectable: the mode of eigenvalue {_fmt(lam)} of F "
            f"(|lambda| = {abs(lam):.6g} >= 1) is not observed by H; "
            "no steady-state filter exists")


def check_stabilizable(F, G, Q) -> None:
    """Raise SteadyStateError if (F, G Q^1/2) is not stabilisable (PBH on |lambda| >= 1)."""
    F = np.asarray(F, dtype=float)
    B = np.atleast_2d(np.asarray(G, dtype=float)) @ psd_sqrt(np.atleast_2d(Q))
    lam = _pbh_unobservable(F.T, B.T)
    if lam is not None:
        raise SteadyStateError(
            f"(F, G Q^1/2) is not stabilizable: the mode of eigenvalue {_fmt(lam)} of F "
            f"(|lambda| = {abs(lam):.6g} >= 1) is not excited by the process noise; "
            "no steady-state filter exists")


def check_steady_state(F, G, H, Q, R) -> None:
    """Validate the arrays, then check detectability and stabilisability."""
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    check_detectable(F, H)
    check_stabilizable(F, G, Q)


# ---------------------------------------------------------------- LF constants
class LainiotisConstants(NamedTuple):
    """Off-line constants of the Lainiotis filter (SPEC §3)."""

    A: np.ndarray
    Kn: np.ndarray
    Km: np.ndarray
    Pn: np.ndarray
    Fn: np.ndarray
    On: np.ndarray


def lf_constants(F, G, H, Q, R) -> LainiotisConstants:
    """A = [H GQGᵀ Hᵀ + R]⁻¹, Kn = GQGᵀHᵀA, Km = FᵀHᵀA, Pn = GQGᵀ − Kn H GQGᵀ,
    Fn = F − Kn H F, On = FᵀHᵀ A H F."""
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    GQG = G @ Q @ G.T
    A = np.linalg.inv(H @ GQG @ H.T + R)
    Kn = GQG @ H.T @ A
    Km = F.T @ H.T @ A
    Pn = GQG - Kn @ H @ GQG
    Fn = F - Kn @ H @ F
    On = F.T @ H.T @ A @ H @ F
    return LainiotisConstants(A, Kn, Km, Pn, Fn, On)


# ---------------------------------------------------------------- solvers
def _converged(new: np.ndarray, old: np.ndarray, tol: float) -> bool:
    return np.abs(new - old).max() <= tol * np.abs(new).max()


def _iterate(step, P0: np.ndarray, tol: float, max_iter: int, what: str) -> np.ndarray:
    P = P0
    for _ in range(max_iter):
        P_next = step(P)
        P_next = (P_next + P_next.T) / 2
        if not np.all(np.isfinite(P_next)):
            raise SteadyStateError(f"{what} diverged (non-finite P)")
        if _converged(P_next, P, tol):
            return P_next
        P = P_next
    raise SteadyStateError(f"{what} did not converge to relative tolerance {tol:g} "
                           f"within {max_iter} iterations")


def rekf_iterate(F, G, H, Q, R, P0=None, tol: float = DEFAULT_TOL,
                 max_iter: int = MAX_STEPS) -> np.ndarray:
    """Pp by iterating P(k+1/k) = GQGᵀ + F P Fᵀ − F P Hᵀ [H P Hᵀ + R]⁻¹ H P Fᵀ from P0 (default
    0) until the relative change is <= tol."""
    check_steady_state(F, G, H, Q, R)
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    GQG = G @ Q @ G.T

    def step(P):
        FP = F @ P
        S = H @ P @ H.T + R
        return GQG + FP @ F.T - FP @ H.T @ np.linalg.solve(S, H @ P @ F.T)

    P0 = np.zeros_like(F) if P0 is None else np.asarray(P0, dtype=float)
    return _iterate(step, P0, tol, max_iter, "REKF iteration")


def relf_iterate(F, G, H, Q, R, P0=None, tol: float = DEFAULT_TOL,
                 max_iter: int = MAX_STEPS) -> np.ndarray:
    """Pe by iterating P(k+1/k+1) = Pn + Fn [I + P On]⁻¹ P Fnᵀ from P0 (default 0)."""
    check_steady_state(F, G, H, Q, R)
    c = lf_constants(F, G, H, Q, R)
    eye = np.eye(c.Fn.shape[0])

    def step(P):
        return c.Pn + c.Fn @ np.linalg.solve(eye + P @ c.On, P) @ c.Fn.T

    P0 = np.zeros_like(c.Fn) if P0 is None else np.asarray(P0, dtype=float)
    return _iterate(step, P0, tol, max_iter, "RELF iteration")


def doubling(A, Gd, Hd, tol: float = DEFAULT_TOL, max_iter: int = MAX_DOUBLINGS) -> np.ndarray:
    """Structure-preserving doubling (Chu, Fan, Lin 2005) for X = Aᵀ X (I + Gd X)⁻¹ A + Hd,
    Gd and Hd symmetric positive semidefinite. Converges quadratically to the stabilising X."""
    A, Gd, Hd = (np.asarray(M, dtype=float) for M in (A, Gd, Hd))
    eye = np.eye(A.shape[0])
    for _ in range(max_iter):
        W = eye + Gd @ Hd
        try:
            WA = np.linalg.solve(W, A)
            WG = np.linalg.solve(W, Gd)
        except np.linalg.LinAlgError as exc:
            raise SteadyStateError(f"doubling failed: I + G H singular ({exc})") from exc
        H_next = Hd + A.T @ Hd @ WA
        G_next = Gd + A @ WG @ A.T
        A = A @ WA
        H_next, Gd = (H_next + H_next.T) / 2, (G_next + G_next.T) / 2
        if not np.all(np.isfinite(H_next)):
            raise SteadyStateError("doubling diverged (non-finite X)")
        if _converged(H_next, Hd, tol):
            return H_next
        Hd = H_next
    raise SteadyStateError(f"doubling did not converge to relative tolerance {tol:g} "
                           f"within {max_iter} doublings")


def rekf_doubling(F, G, H, Q, R, tol: float = DEFAULT_TOL) -> np.ndarray:
    """Pp of the REKF by doubling: A = Fᵀ, Gd = Hᵀ R⁻¹ H, Hd = GQGᵀ."""
    check_steady_state(F, G, H, Q, R)
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    return doubling(F.T, H.T @ np.linalg.solve(R, H), G @ Q @ G.T, tol)


def relf_doubling(F, G, H, Q, R, tol: float = DEFAULT_TOL) -> np.ndarray:
    """Pe of the RELF by doubling: Pe = Fn Pe (I + On Pe)⁻¹ Fnᵀ + Pn, so A = Fnᵀ, Gd = On,
    Hd = Pn."""
    check_steady_state(F, G, H, Q, R)
    c = lf_constants(F, G, H, Q, R)
    return doubling(c.Fn.T, c.On, c.Pn, tol)


# ---------------------------------------------------------------- steady-state gains
class KalmanSteadyState(NamedTuple):
    """SSKF: x(k+1/k+1) = A x(k/k) + B z(k+1), with A = (I − KH)F, B = K."""

    Pp: np.ndarray
    Pe: np.ndarray
    K: np.ndarray
    A: np.ndarray
    B: np.ndarray


class LainiotisSteadyState(NamedTuple):
    """SSLF: x(k+1/k+1) = A x(k/k) + B z(k+1), A = Fn[I + Pe On]⁻¹, B = Kn + A Pe Km."""

    A: np.ndarray
    B: np.ndarray
    Pe: np.ndarray


_METHODS = ("doubling", "iteration")


def _check_method(method: str) -> None:
    if method not in _METHODS:
        raise ModelError(f"unknown Riccati method {method!r}; expected one of {_METHODS}")


def _check_stable(A: np.ndarray, what: str) -> None:
    rho = np.abs(np.linalg.eigvals(A)).max()
    if rho >= 1.0:
        raise SteadyStateError(f"{what} is not stable (spectral radius {rho:.6g} >= 1)")


def kf_steady(F, G, H, Q, R, method: str = "doubling") -> KalmanSteadyState:
    """Steady-state KF: Pp from the REKF, K = Pp Hᵀ[H Pp Hᵀ + R]⁻¹, Pe = (I − KH)Pp."""
    _check_method(method)
    solve = rekf_doubling if method == "doubling" else rekf_iterate
    Pp = solve(F, G, H, Q, R)
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    K = np.linalg.solve(H @ Pp @ H.T + R, H @ Pp).T
    IKH = np.eye(F.shape[0]) - K @ H
    A = IKH @ F
    _check_stable(A, "A_KF = (I - K H) F")
    Pe = IKH @ Pp
    return KalmanSteadyState(Pp, (Pe + Pe.T) / 2, K, A, K)


def lf_steady(F, G, H, Q, R, method: str = "doubling") -> LainiotisSteadyState:
    """Steady-state LF: Pe from the RELF, A_LF = Fn[I + Pe On]⁻¹, B_LF = Kn + A_LF Pe Km."""
    _check_method(method)
    solve = relf_doubling if method == "doubling" else relf_iterate
    Pe = solve(F, G, H, Q, R)
    c = lf_constants(F, G, H, Q, R)
    A = np.linalg.solve((np.eye(c.Fn.shape[0]) + Pe @ c.On).T, c.Fn.T).T
    _check_stable(A, "A_LF = Fn [I + Pe On]^-1")
    return LainiotisSteadyState(A, c.Kn + A @ Pe @ c.Km, Pe)


# ---------------------------------------------------------------- FIR and prediction
_NORMS = {2: 2, "2": 2, "fro": "fro", "inf": np.inf, np.inf: np.inf}


def fir_order(A, eps: float, norm=2, max_order: int = MAX_STEPS) -> int:
    """Smallest N with ||A^N|| < eps, eps in (0, 1). norm: 2 (spectral, default), 'fro' or
    'inf' (max row sum). A must be asymptotically stable."""
    if not (isinstance(eps, Real) and 0.0 < eps < 1.0):
        raise SteadyStateError(f"FIR epsilon must lie in (0, 1), got {eps!r}")
    if norm not in _NORMS:
        raise SteadyStateError(f"unknown FIR norm {norm!r}; expected 2, 'fro' or 'inf'")
    A = _matrix("A", A, None, None)
    _check_stable(A, "the FIR transition A")
    power = np.eye(A.shape[0])
    for order in range(1, max_order + 1):
        power = power @ A
        if np.linalg.norm(power, _NORMS[norm]) < eps:
            return order
    raise SteadyStateError(f"||A^N|| did not fall below {eps:g} for N <= {max_order}")


def fir_taps(A, B, N: int) -> np.ndarray:
    """FIR coefficients C_i = A^i B, i = 0..N-1, as an array of shape (N, n, m)."""
    if int(N) != N or N < 1:
        raise SteadyStateError(f"FIR order must be a positive integer, got {N!r}")
    A = _matrix("A", A, None, None)
    B = _matrix("B", B, A.shape[0], None)
    taps = np.empty((int(N), *B.shape))
    taps[0] = B
    for i in range(1, int(N)):
        taps[i] = A @ taps[i - 1]
    return taps


class PredictionConstants(NamedTuple):
    """Steady-state N-step prediction: x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k)."""

    A_N: np.ndarray
    B_N: np.ndarray


def pred_constants(F, K, H, N: int) -> PredictionConstants:
    """A_N = F^N (I − KH) F^-(N-1), B_N = F^N K (SPEC §4). N >= 2 needs F invertible."""
    if int(N) != N or N < 1:
        raise SteadyStateError(f"prediction horizon N must be a positive integer, got {N!r}")
    N = int(N)
    F = _matrix("F", F, None, None)
    K = _matrix("K", K, F.shape[0], None)
    H = _matrix("H", H, K.shape[1], F.shape[0])
    FN = np.linalg.matrix_power(F, N)
    left = FN @ (np.eye(F.shape[0]) - K @ H)
    if N == 1:
        return PredictionConstants(left, FN @ K)
    back = np.linalg.matrix_power(F, N - 1)
    if np.linalg.cond(back) > 1e12:
        raise SteadyStateError(
            f"N-step prediction with N = {N} needs F^-(N-1), but F is singular or "
            f"ill-conditioned (cond(F^{N - 1}) = {np.linalg.cond(back):.3g})")
    return PredictionConstants(np.linalg.solve(back.T, left.T).T, FN @ K)
