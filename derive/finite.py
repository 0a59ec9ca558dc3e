"""Model entries must be finite doubles at the given values: checked with bounded effort.

An entry whose symbols all have values is evaluated bottom-up with ``DIGITS``-digit floats
(never exactly, so ``dt**1000000`` at ``dt = 1e200`` costs a few multiplications). An
intermediate beyond ``2**MAX_EXPONENT_BITS`` in magnitude stops the evaluation: no double
result can come from it in generated code, and going on (``exp(exp(exp(dt)))``) could
take unbounded time. The exact substitution the model does afterwards is bounded too: an
entry whose exact value could need more than ``MAX_EXACT_BITS`` bits is refused.
"""

from __future__ import annotations

from collections.abc import Mapping

import sympy

from .errors import NotFiniteError
from .symbols import DOUBLE_MAX, decimal

DIGITS = 30
"""Decimal digits of the floating-point evaluation."""
MAX_EXPONENT_BITS = 10_000
"""Largest binary exponent of an intermediate value (2**10000, about 1e3010)."""
MAX_EXACT_BITS = 1_000_000
"""Bound on the estimated bits of an entry's exact value at the given values."""

_LIMIT = sympy.Float(2, DIGITS) ** MAX_EXPONENT_BITS


class _Beyond(Exception):
    """An intermediate value left the range evaluation is bounded to."""


def _floating(expr: sympy.Expr, at: Mapping[sympy.Symbol, sympy.Expr]) -> sympy.Expr:
    """``expr`` at ``at`` in DIGITS-digit floats; _Beyond if an intermediate is too large."""
    memo: dict[sympy.Basic, sympy.Expr] = {}

    def go(e: sympy.Basic) -> sympy.Expr:
        if e in memo:
            return memo[e]
        try:
            if e.is_Symbol:
                out = sympy.Float(at[e], DIGITS)
            elif e.is_Number:
                out = sympy.Float(e, DIGITS)
            elif not e.args:
                out = e.evalf(DIGITS)
            elif e.is_Pow and e.exp.is_Rational:
                out = sympy.Pow(go(e.base), e.exp)
            else:
                out = e.func(*[go(a) for a in e.args])
            if not out.is_Float:
                out = out.evalf(DIGITS)
        except OverflowError:
            raise _Beyond from None
        if not isinstance(out, sympy.Expr):  # a condition inside a Piecewise
            memo[e] = out
            return out
        if out.has(sympy.nan, sympy.zoo, sympy.oo, -sympy.oo):
            memo[e] = out
            return out
        if abs(out) > _LIMIT:
            raise _Beyond
        memo[e] = out
        return out

    return go(expr)


def _exact_bits(expr: sympy.Expr, at: Mapping[sympy.Symbol, sympy.Expr]) -> int:
    """An upper estimate of the bits of ``expr``'s exact value at ``at``."""
    if expr.is_Symbol:
        value = at.get(expr, sympy.Integer(1))
        return _exact_bits(value, {}) if value.is_Rational else 0
    if expr.is_Rational:
        if abs(expr.p) == 1 and expr.q == 1:  # powers of 1 and -1 cost nothing
            return 0
        return int(expr.p).bit_length() + int(expr.q).bit_length()
    if expr.is_Pow and expr.exp.is_Integer:
        return abs(int(expr.exp)) * _exact_bits(expr.base, at)
    return sum(_exact_bits(a, at) for a in expr.args)


def _problem(value: sympy.Expr) -> str | None:
    """Why a float value is not a finite double, or None."""
    if value.has(sympy.nan):
        return "nan"
    if value.has(sympy.zoo, sympy.oo, -sympy.oo):
        return "inf"
    real, imag = value.as_real_imag()
    if imag != 0:
        return f"{value} (not a real number)"
    if abs(real) > DOUBLE_MAX:
        return f"{decimal(real)} (beyond the range of a double)"
    return None



#: A number longer than this is shown in scientific notation in messages (1e400 in a model
#: file is an integer of 401 digits).
SHOWN_DIGITS = 30


def _shown(entry) -> str:
    """``entry`` as a message shows it: a number of more than :data:`SHOWN_DIGITS`
    characters to six significant digits (``1.00000e+400``), anything else as sympy prints
    it."""
    text = str(entry)
    if entry.is_number and len(text) > SHOWN_DIGITS:
        return str(sympy.N(entry, 6))
    return text

def check_entries(matrices: Mapping[str, sympy.MatrixBase],
                  at: Mapping[sympy.Symbol, sympy.Expr]) -> None:
    """Refuse an entry whose symbols all have values in ``at`` but that is not a finite
    double there; name the matrix, the entry, its expression and the values."""
    for name, mat in matrices.items():
        for (i, j), entry in sorted(mat.todok().items()):  # a zero entry is always finite
            if entry.is_Rational and abs(entry) <= DOUBLE_MAX:
                continue
            symbols = entry.free_symbols
            if any(s not in at for s in symbols):
                continue
            where = f"{name}[{i}]" if mat.cols == 1 and name in ("f", "h", "x0") \
                else f"{name}[{i}][{j}]"
            values = ", ".join(f"{s.name} = {decimal(at[s])}"
                               for s in sorted(symbols, key=lambda s: s.name))
            at_text = f" at {values}" if values else ""
            try:
                problem = _problem(_floating(entry, at))
            except TypeError:  # a construct floats cannot evaluate: left to sympy
                continue
            except _Beyond:
                problem = (f"inf (an intermediate value exceeds 2**{MAX_EXPONENT_BITS}, "
                           "far beyond the range of a double)")
            if problem is None:
                bits = _exact_bits(entry, at)
                if bits > MAX_EXACT_BITS:
                    raise NotFiniteError(
                        f"{where} = {entry}{at_text} needs an exact number of about "
                        f"{bits} bits, more than the limit of {MAX_EXACT_BITS}")
                continue
            raise NotFiniteError(f"{where} = {_shown(entry)} is not a finite double"
                                 f"{at_text}: it evaluates to {problem}")
