"""The papers' burden formulas (MPT3D Tables 2-3, SSPRED Table 2): what they *claim*.

Burden = scalar additions, subtractions, multiplications and divisions per
iteration of the on-line part. The printed formulas are typed once, as text
(:data:`PRINTED`), and parsed like any formula a user audits (:func:`parse_formula`:
a polynomial in n, m with exact rational coefficients); :func:`kf`, :func:`lf`, ...
are their values. Each filter formula is also given as the list of matrix
operations it charges (:func:`kf_operations`, :func:`lf_operations`), each costed
with the papers' per-operation rules (:data:`OPERATION_COSTS`); their sums are the
printed formulas. derive's counts come from generated code (:mod:`derive.flops`),
and the formulas they obey are derived from those counts
(:mod:`derive.apps.burden_formula`), never from here.
"""

from __future__ import annotations

import math
from fractions import Fraction
from functools import cache

import sympy

from ..errors import ExpressionError, ModelError
from ..expressions import parse_expression


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

#: The variables a burden formula may use: sizes n, m, the FIR order N, the number k of
#: independent copies of a block.
VARIABLES = {name: sympy.Symbol(name) for name in ("N", "n", "m", "k")}

#: Highest total degree a formula may have (burden formulas are cubic).
MAX_DEGREE = 12

#: The papers' formulas as they print them, typed once as text: the claims the audit sets
#: against the formulas derived from generated code (derive.apps.burden_formula). JKLF and
#: JSSKLF are printed as sums of named parts, KF + LF (or SSKF + SSLF) and their join.
#: The FIR's is not printed (GSM2D's Table 5 was lost in extraction): the count of its N
#: taps C_i = A^i B, a dot product each.
PRINTED = {
    "kf": "4*n**3 + 3.5*n**2 - 1.5*n + 4*n**2*m + n*m + 3*n*m**2 + (16*m**3 - 3*m**2 - m)/6",
    "lf": "4*n*m + (58*n**3 + 9*n**2 - 7*n)/6",
    "jklf": "KF + LF + n**2 + 3*n",
    "sskf": "2*n**2 + 2*n*m - n",
    "sslf": "2*n**2 + 2*n*m - n",
    "jssklf": "SSKF + SSLF + 2*n",
    "pred": "2*n**2 + 2*n*m - n",
    "fir": "2*N*n*m - n",
}

#: Where each claim is printed.
CITATIONS = {
    "kf": "MPT3D Table 2", "lf": "MPT3D Table 2", "jklf": "MPT3D Table 2 (join: n^2 + 3n)",
    "sskf": "MPT3D Table 2, SSPRED Table 2", "sslf": "MPT3D Table 2",
    "jssklf": "MPT3D Table 2 (join: 2n)", "pred": "SSPRED Table 2",
    "fir": "not printed (GSM2D Table 5 was lost in extraction): 2Nnm - n, N dot products",
}

#: The joins: filter -> (the two filters it runs, the text of its join part).
JOINS = {"jklf": (("kf", "lf"), "n**2 + 3*n"), "jssklf": (("sskf", "sslf"), "2*n")}


def _degree(expr: sympy.Expr, symbols: frozenset) -> int:
    """The total degree of a polynomial expression (unexpanded: nothing is multiplied out),
    or ExpressionError naming what makes it no polynomial with rational coefficients."""
    if expr.is_Rational:
        return 0
    if expr in symbols:
        return 1
    if expr.is_Add:
        return max(_degree(arg, symbols) for arg in expr.args)
    if expr.is_Mul:
        return sum(_degree(arg, symbols) for arg in expr.args)
    if expr.is_Pow and expr.exp.is_Integer and expr.exp >= 0:
        return _degree(expr.base, symbols) * int(expr.exp)
    if expr.is_Pow and expr.exp.is_Integer:
        raise ExpressionError(f"a division by {expr.base}")
    raise ExpressionError(f"{expr} is not a polynomial term with rational coefficients")


def parse_formula(text: str, variables=("n", "m"), parts=None) -> sympy.Expr:
    """A burden formula's text as an expanded polynomial in ``variables`` with rational
    coefficients (``3.5`` is 7/2). Parsed by derive.expressions, like model files: an
    allow-list over Python's ast, nothing executed; ``parts`` names expressions the text may
    use (the parts of a join). Raises ExpressionError on anything else, in one line."""
    names = {v: VARIABLES[v] for v in variables}
    listed = ", ".join(variables)
    expr = parse_expression(text, {**names, **(parts or {})}, where="formula")
    try:
        degree = _degree(expr, frozenset(names.values()))
    except ExpressionError as error:
        raise ExpressionError(f"formula {text[:60]!r} is not a polynomial in {listed}: "
                              f"{error}") from None
    if degree > MAX_DEGREE:
        raise ExpressionError(f"formula {text[:60]!r} has total degree {degree}, more than "
                              f"the limit of {MAX_DEGREE}")
    return sympy.expand(expr)


def _claim_parts(name: str) -> dict[str, sympy.Expr]:
    if name not in JOINS:
        return {}
    return {part.upper(): claim(part) for part in JOINS[name][0]}


@cache
def claim(name: str) -> sympy.Expr:
    """The papers' formula of filter ``name`` as a polynomial (parsed from PRINTED)."""
    try:
        text = PRINTED[name]
    except KeyError:
        raise ModelError(f"no burden formula for filter {name!r}; formulas: "
                         f"{', '.join(PRINTED)}") from None
    return parse_formula(text, ("N", "n", "m") if name == "fir" else ("n", "m"),
                         _claim_parts(name))


@cache
def join_claim(name: str) -> sympy.Expr:
    """The join part the papers add to the two filters of ``name`` (jklf, jssklf)."""
    return parse_formula(JOINS[name][1])


def value(expr: sympy.Expr, **sizes: int) -> int:
    """An integer formula's value at positive integer sizes."""
    for key, size in sizes.items():
        _size(key, size)
    result = sympy.Rational(expr.subs({VARIABLES[k]: v for k, v in sizes.items()}))
    return _exact(Fraction(int(result.p), int(result.q)),
                  f"{expr} at {', '.join(f'{k} = {v}' for k, v in sizes.items())}")


def kf(n: int, m: int) -> int:
    """KF: 4n³ + 3.5n² - 1.5n + 4n²m + nm + 3nm² + (16m³ - 3m² - m)/6."""
    return value(claim("kf"), n=n, m=m)


def lf(n: int, m: int) -> int:
    """LF: 4nm + (58n³ + 9n² - 7n)/6."""
    return value(claim("lf"), n=n, m=m)


def jklf_join(n: int) -> int:
    """The JKLF join: state sum and halving (2n), P sum and halving ((n²+n)/2 each)."""
    return value(join_claim("jklf"), n=n)


def jklf(n: int, m: int) -> int:
    """JKLF: KF + LF + n² + 3n."""
    return value(claim("jklf"), n=n, m=m)


def sskf(n: int, m: int) -> int:
    """SSKF (also SSLF and the steady-state prediction): 2n² + 2nm - n."""
    return value(claim("sskf"), n=n, m=m)


def sslf(n: int, m: int) -> int:
    """SSLF: 2n² + 2nm - n."""
    return value(claim("sslf"), n=n, m=m)


def sspred(n: int, m: int) -> int:
    """The steady-state N-step prediction: 2n² + 2nm - n, whatever N."""
    return value(claim("pred"), n=n, m=m)


def jssklf_join(n: int) -> int:
    """The JSSKLF join: state sum and halving, 2n."""
    return value(join_claim("jssklf"), n=n)


def jssklf(n: int, m: int) -> int:
    """JSSKLF: SSKF + SSLF + 2n."""
    return value(claim("jssklf"), n=n, m=m)


def fir(N: int, n: int, m: int) -> int:
    """FIR of order N (derived, not printed): N taps C_i = A^i B, 2Nnm - n per output."""
    return value(claim("fir"), N=N, n=n, m=m)


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
