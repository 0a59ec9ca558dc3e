"""Constants of the filters with a horizon N: the FIR's order and taps, the N-step predictor.

Plain NumPy on numeric arrays (SPEC.md §4), from a stable steady-state transition A and
gain B (or K). A bad FIR epsilon, norm or order, an unstable A, or a singular F where the
prediction needs F^-(N-1) raises derive.errors.SteadyStateError.
"""

from __future__ import annotations

from numbers import Real
from typing import NamedTuple

import numpy as np

from derive.errors import SteadyStateError
from derive.system_checks import check_stable, numeric_matrix

MAX_ORDER = 100_000
"""Largest FIR order fir_order tries by default."""
_NORMS = {2: 2, "2": 2, "fro": "fro", "inf": np.inf, np.inf: np.inf}
"""fir_order's norm names -> numpy.linalg.norm's ord."""


def fir_order(A, eps: float, norm=2, max_order: int = MAX_ORDER) -> int:
    """Smallest N with ||A^N|| < eps, eps in (0, 1). norm: 2 (spectral, default), 'fro' or
    'inf' (max row sum). A must be asymptotically stable."""
    if not (isinstance(eps, Real) and 0.0 < eps < 1.0):
        raise SteadyStateError(f"FIR epsilon must lie in (0, 1), got {eps!r}")
    if norm not in _NORMS:
        raise SteadyStateError(f"unknown FIR norm {norm!r}; expected 2, 'fro' or 'inf'")
    A = numeric_matrix("A", A, None, None)
    check_stable(A, "the FIR transition A")
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
    A = numeric_matrix("A", A, None, None)
    B = numeric_matrix("B", B, A.shape[0], None)
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
    F = numeric_matrix("F", F, None, None)
    K = numeric_matrix("K", K, F.shape[0], None)
    H = numeric_matrix("H", H, K.shape[1], F.shape[0])
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


__all__ = ["MAX_ORDER", "PredictionConstants", "fir_order", "fir_taps", "pred_constants"]
