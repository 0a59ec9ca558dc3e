"""The papers' burden formulas (MPT3D Tables 2-3), as exact integers in n and m.

Burden = scalar additions, subtractions, multiplications and divisions per
iteration of the on-line part. Each filter formula is also given as the list of
matrix operations it charges (:func:`kf_operations`, :func:`lf_operations`), each
costed with the papers' per-operation rules (:data:`OPERATION_COSTS`); their sums
are the printed formulas. These are what the papers *claim*; derive's counts come
from generated code (:mod:`derive.flops`), never from here.
"""

from __future__ import annotations

import math
from fractions import Fraction

from ..errors import ModelError


def _size(name: str, value) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ModelError(f"{name} must be a positive integer, got {value!r}")
    return value


def _exact(value: Fraction, what: str) -> int:
    if value.denominator != 1:  # the formulas are integers for every n, m >= 1
        raise ArithmeticError(f"{what} is not an integer: {value}")
    return int(value)


# -- the cost of one matrix operation ---------------------------------------------------


def add(n: int, m: int) -> int:
    """A + B, both (n x m): nm."""
    return n * m


def symmetric_add(n: int) -> int:
    """A + B with a symmetric (n x n) result: the upper triangle, (n² + n)/2."""
    return (n * n + n) // 2


def identity_add(n: int) -> int:
    """I + A or I - A (n x n): the diagonal only, n."""
    return n


def product(n: int, m: int, k: int) -> int:
    """(n x m)(m x k): 2nmk - nk."""
    return 2 * n * m * k - n * k


def symmetric_product(n: int, m: int) -> int:
    """(n x m)(m x n) with a symmetric result: n²m + nm - (n² + n)/2."""
    return n * n * m + n * m - (n * n + n) // 2


def inverse(n: int) -> int:
    """Inverse of an (n x n) matrix: (16n³ - 3n² - n)/6 (Doolittle LU plus n forward and
    n backward solves, each charged n²; a 1 x 1 inverse is charged 2)."""
    return _exact(Fraction(16 * n**3 - 3 * n**2 - n, 6), f"inverse({n})")


#: The operation kinds of the breakdowns and their costing rule, as the papers state them.
OPERATION_COSTS = {
    "add": "A+B (n x m): nm",
    "symmetric add": "A+B symmetric (n x n): (n²+n)/2",
    "identity add": "I±A (n x n): n",
    "product": "(n x m)(m x k): 2nmk - nk",
    "symmetric product": "(n x m)(m x n), symmetric result: n²m + nm - (n²+n)/2",
    "inverse": "(n x n)^-1: (16n³ - 3n² - n)/6",
}


def kf_operations(n: int, m: int) -> list[tuple[str, str, int]]:
    """The KF formula as its matrix operations: (operation, kind, cost) (MPT3D Tables 2-3)."""
    n, m = _size("n", n), _size("m", m)
    return [
        ("F x", "product", product(n, n, 1)),
        ("F P", "product", product(n, n, n)),
        ("(F P) F^T", "symmetric product", symmetric_product(n, n)),
        ("+ G Q G^T", "symmetric add", symmetric_add(n)),
        ("P H^T", "product", product(n, n, m)),
        ("H (P H^T)", "symmetric product", symmetric_product(m, n)),
        ("+ R", "symmetric add", symmetric_add(m)),
        ("[H P H^T + R]^-1", "inverse", inverse(m)),
        ("K = (P H^T) [.]^-1", "product", product(n, m, m)),
        ("K H", "product", product(n, m, n)),
        ("I - K H", "identity add", identity_add(n)),
        ("(I - K H) x", "product", product(n, n, 1)),
        ("K z", "product", product(n, m, 1)),
        ("(I - K H) x + K z", "add", add(n, 1)),
        ("(I - K H) P", "symmetric product", symmetric_product(n, n)),
    ]


def lf_operations(n: int, m: int) -> list[tuple[str, str, int]]:
    """The LF formula as its matrix operations (M = Fn [I + P On]^-1 shared)."""
    n, m = _size("n", n), _size("m", m)
    return [
        ("P On", "product", product(n, n, n)),
        ("I + P On", "identity add", identity_add(n)),
        ("[I + P On]^-1", "inverse", inverse(n)),
        ("M = Fn [.]^-1", "product", product(n, n, n)),
        ("M P", "product", product(n, n, n)),
        ("(M P) Fn^T", "symmetric product", symmetric_product(n, n)),
        ("+ Pn", "symmetric add", symmetric_add(n)),
        ("Km z", "product", product(n, m, 1)),
        ("P (Km z)", "product", product(n, n, 1)),
        ("+ x", "add", add(n, 1)),
        ("M (.)", "product", product(n, n, 1)),
        ("Kn z", "product", product(n, m, 1)),
        ("Kn z + M (.)", "add", add(n, 1)),
    ]


def steady_operations(n: int, m: int) -> list[tuple[str, str, int]]:
    """SSKF, SSLF and the steady-state prediction: x = A x + B z."""
    n, m = _size("n", n), _size("m", m)
    return [("A x", "product", product(n, n, 1)), ("B z", "product", product(n, m, 1)),
            ("A x + B z", "add", add(n, 1))]


# -- the printed formulas (MPT3D Table 2, SSPRED Table 2) --------------------------------


def kf(n: int, m: int) -> int:
    """KF: 4n³ + 3.5n² - 1.5n + 4n²m + nm + 3nm² + (16m³ - 3m² - m)/6."""
    n, m = _size("n", n), _size("m", m)
    value = (4 * n**3 + Fraction(7, 2) * n**2 - Fraction(3, 2) * n + 4 * n**2 * m + n * m
             + 3 * n * m**2 + Fraction(16 * m**3 - 3 * m**2 - m, 6))
    return _exact(value, f"kf({n}, {m})")


def lf(n: int, m: int) -> int:
    """LF: 4nm + (58n³ + 9n² - 7n)/6."""
    n, m = _size("n", n), _size("m", m)
    return _exact(4 * n * m + Fraction(58 * n**3 + 9 * n**2 - 7 * n, 6), f"lf({n}, {m})")


def jklf_join(n: int) -> int:
    """The JKLF join: state sum and halving (2n), P sum and halving ((n²+n)/2 each)."""
    n = _size("n", n)
    return n * n + 3 * n


def jklf(n: int, m: int) -> int:
    """JKLF: KF + LF + n² + 3n."""
    return kf(n, m) + lf(n, m) + jklf_join(n)


def sskf(n: int, m: int) -> int:
    """SSKF (also SSLF and the steady-state prediction): 2n² + 2nm - n."""
    n, m = _size("n", n), _size("m", m)
    return 2 * n * n + 2 * n * m - n


sslf = sskf
sspred = sskf


def jssklf_join(n: int) -> int:
    """The JSSKLF join: state sum and halving, 2n."""
    return 2 * _size("n", n)


def jssklf(n: int, m: int) -> int:
    """JSSKLF: SSKF + SSLF + 2n."""
    return sskf(n, m) + sslf(n, m) + jssklf_join(n)


def fir(N: int, n: int, m: int) -> int:
    """FIR of order N (derived, not printed): N taps C_i = A^i B, 2Nnm - n per output."""
    N, n, m = _size("N", N), _size("n", n), _size("m", m)
    return 2 * N * n * m - n


def break_even(fir_burden: int, per_step_burden: int) -> int:
    """Smallest integer L >= fir_burden / per_step_burden: the FIR wins when an output is
    needed only every L steps or more (GSM2D §7)."""
    _size("FIR burden", fir_burden)
    _size("per-step burden", per_step_burden)
    return math.ceil(Fraction(fir_burden, per_step_burden))


#: Per-filter formulas of the time-varying and steady-state filters, by derive's names.
FORMULAS = {"kf": kf, "lf": lf, "jklf": jklf, "sskf": sskf, "sslf": sslf, "jssklf": jssklf,
            "pred": sspred}


def burden(name: str, n: int, m: int) -> int:
    """The papers' burden of filter ``name`` (kf, lf, jklf, sskf, sslf, jssklf, pred)."""
    try:
        formula = FORMULAS[name]
    except KeyError:
        raise ModelError(f"no burden formula for filter {name!r}; formulas: "
                         f"{', '.join(FORMULAS)}") from None
    return formula(n, m)
