"""Riccati equations of the KF (REKF) and LF (RELF), solved per step and by doubling.

NumPy arrays, their products and solves by derive.ieee_linalg (the same bits on every
CPU, so the constants written into generated code are too): the LF's off-line
constants, the per-step recursions, structure-preserving doubling, and the steady-state
gains of the SSKF and SSLF (the equations of MPT3D and SSPRED).
Every solver first checks the model (derive.system_checks: detectable and stabilisable);
a failed check or a failed convergence raises derive.errors.SteadyStateError.

The system checks live in derive.system_checks, the FIR and N-step prediction constants
in derive.horizon: import them from there.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from derive.errors import ModelError, SteadyStateError
from derive.ieee_linalg import inverse, solve
from derive.ieee_linalg import matmul as mm
from derive.system_checks import check_stable, check_steady_state, system_arrays

DEFAULT_TOL = 1e-13
"""Relative change of P between iterations at which an iteration is converged."""
MAX_STEPS = 100_000
"""Iteration cap of the per-step recursions (doubling uses MAX_DOUBLINGS)."""
MAX_DOUBLINGS = 100


# ---------------------------------------------------------------- LF constants
class LainiotisConstants(NamedTuple):
    """Off-line constants of the Lainiotis filter (MPT3D)."""

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
    GQG = mm(G, Q, G.T)
    A = inverse(mm(H, GQG, H.T) + R)
    Kn = mm(GQG, H.T, A)
    Km = mm(F.T, H.T, A)
    Pn = GQG - mm(Kn, H, GQG)
    Fn = F - mm(Kn, H, F)
    On = mm(F.T, H.T, A, H, F)
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
    GQG = mm(G, Q, G.T)

    def step(P):
        FP = mm(F, P)
        S = mm(H, P, H.T) + R
        return GQG + mm(FP, F.T) - mm(FP, H.T, solve(S, mm(H, P, F.T)))

    P0 = np.zeros_like(F) if P0 is None else np.asarray(P0, dtype=float)
    return _iterate(step, P0, tol, max_iter, "REKF iteration")


def relf_iterate(F, G, H, Q, R, P0=None, tol: float = DEFAULT_TOL,
                 max_iter: int = MAX_STEPS) -> np.ndarray:
    """Pe by iterating P(k+1/k+1) = Pn + Fn [I + P On]⁻¹ P Fnᵀ from P0 (default 0)."""
    check_steady_state(F, G, H, Q, R)
    c = lf_constants(F, G, H, Q, R)
    eye = np.eye(c.Fn.shape[0])

    def step(P):
        return c.Pn + mm(c.Fn, solve(eye + mm(P, c.On), P), c.Fn.T)

    P0 = np.zeros_like(c.Fn) if P0 is None else np.asarray(P0, dtype=float)
    return _iterate(step, P0, tol, max_iter, "RELF iteration")


def doubling(A, Gd, Hd, tol: float = DEFAULT_TOL, max_iter: int = MAX_DOUBLINGS) -> np.ndarray:
    """Structure-preserving doubling (Chu, Fan, Lin 2005) for X = Aᵀ X (I + Gd X)⁻¹ A + Hd,
    Gd and Hd symmetric positive semidefinite. Converges quadratically to the stabilising X."""
    A, Gd, Hd = (np.asarray(M, dtype=float) for M in (A, Gd, Hd))
    eye = np.eye(A.shape[0])
    for _ in range(max_iter):
        W = eye + mm(Gd, Hd)
        try:
            WA = solve(W, A)
            WG = solve(W, Gd)
        except np.linalg.LinAlgError as exc:
            raise SteadyStateError(f"doubling failed: I + G H singular ({exc})") from exc
        H_next = Hd + mm(A.T, Hd, WA)
        G_next = Gd + mm(A, WG, A.T)
        A = mm(A, WA)
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
    return doubling(F.T, mm(H.T, solve(R, H)), mm(G, Q, G.T), tol)


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


def kf_steady(F, G, H, Q, R, method: str = "doubling") -> KalmanSteadyState:
    """Steady-state KF: Pp from the REKF, K = Pp Hᵀ[H Pp Hᵀ + R]⁻¹, Pe = (I − KH)Pp."""
    _check_method(method)
    riccati = rekf_doubling if method == "doubling" else rekf_iterate
    Pp = riccati(F, G, H, Q, R)
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    K = solve(mm(H, Pp, H.T) + R, mm(H, Pp)).T
    IKH = np.eye(F.shape[0]) - mm(K, H)
    A = mm(IKH, F)
    check_stable(A, "A_KF = (I - K H) F")
    Pe = mm(IKH, Pp)
    return KalmanSteadyState(Pp, (Pe + Pe.T) / 2, K, A, K)


def lf_steady(F, G, H, Q, R, method: str = "doubling") -> LainiotisSteadyState:
    """Steady-state LF: Pe from the RELF, A_LF = Fn[I + Pe On]⁻¹, B_LF = Kn + A_LF Pe Km."""
    _check_method(method)
    riccati = relf_doubling if method == "doubling" else relf_iterate
    Pe = riccati(F, G, H, Q, R)
    c = lf_constants(F, G, H, Q, R)
    A = solve((np.eye(c.Fn.shape[0]) + mm(Pe, c.On)).T, c.Fn.T).T
    check_stable(A, "A_LF = Fn [I + Pe On]^-1")
    return LainiotisSteadyState(A, c.Kn + mm(A, Pe, c.Km), Pe)


__all__ = [
    "DEFAULT_TOL", "MAX_DOUBLINGS", "MAX_STEPS", "KalmanSteadyState", "LainiotisConstants",
    "LainiotisSteadyState", "doubling", "kf_steady", "lf_constants", "lf_steady",
    "rekf_doubling", "rekf_iterate", "relf_doubling", "relf_iterate",
]
