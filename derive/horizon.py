"""Constants of the filters with a horizon N: the FIR's order and taps, the N-step predictor.

NumPy arrays (SSPRED), from a stable steady-state transition A and gain B (or K); the
constants written into generated code (the taps, A_N and B_N) are products and solves of
derive.ieee_linalg, the same bits on every CPU. A bad FIR epsilon, norm or order, an
unstable A, or a singular F where the prediction needs F^-(N-1) raises
derive.errors.SteadyStateError.
"""

from __future__ import annotations

from numbers import Real
from typing import NamedTuple

import numpy as np

from derive.errors import SteadyStateError
from derive.ieee_linalg import matmul as mm
from derive.ieee_linalg import power, solve
from derive.system_checks import check_stable, numeric_matrix

MAX_ORDER = 100_000
"""Largest FIR order fir_order tries by default."""
MAX_FIR_WINDOW = 256
"""Bound on N m, the measurements in the generated FIR's window: each output is a sum of
up to N m products, which the code printers nest about two calls deep per term, so 256
keeps them well inside Python's default recursion limit of 1000."""
MAX_FIR_TAPS = 2048
"""Bound on N n m, the tap constants A^i B baked into the generated FIR: deriving and
rendering them takes about a second, and gcc -O2 about four seconds to compile them."""
MAX_HORIZON = 4096
"""Bound on the prediction horizon N: F^N and F^-(N-1) carry a relative rounding of about
N 2^-53, which stays below 2^-41 (5e-13), inside the 1e-12 that derive verify holds the
generated code to."""
MAX_SQUARINGS = 64
"""fir_order estimates an order beyond its search by repeated squaring, up to A^(2^64)."""
_NORMS = {2: 2, "2": 2, "fro": "fro", "inf": np.inf, np.inf: np.inf}
"""fir_order's norm names -> numpy.linalg.norm's ord."""


class FirOrderError(SteadyStateError):
    """||A^N|| < eps needs an order N above the bound searched (``needed``: the order found
    by repeated squaring and bisection, None when even A^(2^64) is not below eps)."""

    def __init__(self, message: str, needed: int | None, bound: int):
        super().__init__(message)
        self.needed = needed
        self.bound = bound


def max_fir_order(n: int, m: int) -> int:
    """The largest FIR order generated for n states and m measurements (at least 1)."""
    return max(1, min(MAX_FIR_WINDOW // m, MAX_FIR_TAPS // (n * m)))


def fir_order(A, eps: float, norm=2, max_order: int = MAX_ORDER) -> int:
    """Smallest N <= max_order with ||A^N|| < eps, eps in (0, 1). norm: 2 (spectral,
    default), 'fro' or 'inf' (max row sum). A must be asymptotically stable.

    When no N <= max_order will do, raises :class:`FirOrderError` naming the order that
    would be needed, found without building it: A^(2^j) by repeated squaring until its
    norm falls below eps, then bisection between the last two powers (O(log^2 N) matrix
    products)."""
    if not (isinstance(eps, Real) and 0.0 < eps < 1.0):
        raise SteadyStateError(f"FIR epsilon must lie in (0, 1), got {eps!r}")
    if norm not in _NORMS:
        raise SteadyStateError(f"unknown FIR norm {norm!r}; expected 2, 'fro' or 'inf'")
    A = numeric_matrix("A", A, None, None)
    check_stable(A, "the FIR transition A")
    ord_ = _NORMS[norm]
    power = np.eye(A.shape[0])
    for order in range(1, max_order + 1):
        power = power @ A
        if np.linalg.norm(power, ord_) < eps:
            return order
    needed = _order_beyond(A, eps, ord_, max_order)
    what = (f"N = {needed}" if needed is not None else f"N > 2^{MAX_SQUARINGS}")
    raise FirOrderError(f"||A^N|| < {eps!r} needs {what}, more than the bound {max_order}",
                        needed, max_order)


def _order_beyond(A: np.ndarray, eps: float, ord_, known_above: int) -> int | None:
    """An N > known_above with ||A^N|| < eps <= ||A^(N-1)||, or None beyond 2^64."""
    squares = [A]                           # squares[j] = A^(2^j)
    while (np.linalg.norm(squares[-1], ord_) >= eps
           or 2 ** (len(squares) - 1) <= known_above):
        if len(squares) > MAX_SQUARINGS:
            return None
        squares.append(squares[-1] @ squares[-1])

    def power(N: int) -> np.ndarray:
        out = np.eye(A.shape[0])
        for j, square in enumerate(squares):
            if N >> j & 1:
                out = out @ square
        return out

    low, high = max(known_above, 2 ** (len(squares) - 2)), 2 ** (len(squares) - 1)
    while high - low > 1:                   # ||A^low|| >= eps > ||A^high||
        mid = (low + high) // 2
        if np.linalg.norm(power(mid), ord_) < eps:
            high = mid
        else:
            low = mid
    return high


def fir_taps(A, B, N: int) -> np.ndarray:
    """FIR coefficients C_i = A^i B, i = 0..N-1, as an array of shape (N, n, m)."""
    if int(N) != N or N < 1:
        raise SteadyStateError(f"FIR order must be a positive integer, got {N!r}")
    A = numeric_matrix("A", A, None, None)
    B = numeric_matrix("B", B, A.shape[0], None)
    taps = np.empty((int(N), *B.shape))
    taps[0] = B
    for i in range(1, int(N)):
        taps[i] = mm(A, taps[i - 1])
    return taps


class PredictionConstants(NamedTuple):
    """Steady-state N-step prediction: x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k)."""

    A_N: np.ndarray
    B_N: np.ndarray


def pred_constants(F, K, H, N: int) -> PredictionConstants:
    """A_N = F^N (I − KH) F^-(N-1), B_N = F^N K (SSPRED). N >= 2 needs F invertible."""
    if int(N) != N or N < 1:
        raise SteadyStateError(f"prediction horizon N must be a positive integer, got {N!r}")
    N = int(N)
    F = numeric_matrix("F", F, None, None)
    K = numeric_matrix("K", K, F.shape[0], None)
    H = numeric_matrix("H", H, K.shape[1], F.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        FN = power(F, N)
        back = power(F, N - 1)
    if not np.isfinite(FN).all():
        raise SteadyStateError(f"N-step prediction with N = {N} needs F^{N}, which overflows "
                               f"a double (spectral radius of F: "
                               f"{np.abs(np.linalg.eigvals(F)).max():.6g})")
    with np.errstate(over="ignore", invalid="ignore"):
        left, gain = mm(FN, np.eye(F.shape[0]) - mm(K, H)), mm(FN, K)
    if not (np.isfinite(left).all() and np.isfinite(gain).all()):
        raise SteadyStateError(f"N-step prediction with N = {N}: F^{N} (I - K H) or F^{N} K "
                               "overflows a double")
    if N == 1:
        return PredictionConstants(left, gain)
    if np.linalg.cond(back) > 1e12:
        raise SteadyStateError(
            f"N-step prediction with N = {N} needs F^-(N-1), but F is singular or "
            f"ill-conditioned (cond(F^{N - 1}) = {np.linalg.cond(back):.3g})")
    return PredictionConstants(solve(back.T, left.T).T, gain)


__all__ = ["MAX_FIR_TAPS", "MAX_FIR_WINDOW", "MAX_HORIZON", "MAX_ORDER", "FirOrderError",
           "PredictionConstants", "fir_order", "fir_taps", "max_fir_order", "pred_constants"]
