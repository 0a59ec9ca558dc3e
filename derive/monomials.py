"""Products and sums of monomials, built as sympy builds them, without its general flatten.

Staging a matrix product builds, per entry, the products of two entries (atoms: input
elements, temporaries, numbers, negated temporaries) and their sum; a vector chunk's lanes
(derive.rows) multiply a coefficient by an element.  sympy's ``Mul`` and
``Add`` handle every kind of argument, and for these the general path is most of the
derivation of a large filter.  A monomial here is a symbol, or a product of a nonzero
rational and powers of distinct symbols (``-3*t1*t2**2``); for them sympy's result is
known exactly:

- the product of ``c1*s1`` and ``c2*s2`` (rationals times distinct commutative symbols,
  either symbol possibly absent) is the ``Mul`` of ``c1*c2`` (left out when 1) and the
  symbols in sympy's argument order (``Basic.compare``, as flatten sorts them);
- the sum of monomials that differ in more than their coefficients is the ``Add`` of
  them as they are, in that order.

Everything else goes to sympy.  The results are the very expressions sympy returns
(``tests/numerics/test_monomials.py`` compares them on random inputs), so generated code
is byte for byte what sympy's constructors give.
"""

from __future__ import annotations

from collections.abc import Iterable

import sympy
from sympy.core.basic import _args_sortkey

_ZERO, _ONE = sympy.S.Zero, sympy.S.One


def _scaled_symbol(e: sympy.Expr):
    """(c, s) of ``e = c * s``, ``c`` rational and ``s`` a commutative symbol or None;
    None when ``e`` is neither a rational, a symbol nor a rational times a symbol."""
    if e.is_Symbol:
        return (_ONE, e) if e.is_commutative else None
    if e.is_Rational:
        return e, None
    if e.is_Mul and len(e.args) == 2:
        c, s = e.args
        if c.is_Rational and s.is_Symbol and s.is_commutative:
            return c, s
    return None


def product(a: sympy.Expr, b: sympy.Expr) -> sympy.Expr:
    """``a * b``."""
    left, right = _scaled_symbol(a), _scaled_symbol(b)
    if left is None or right is None:
        return a * b
    coeff = left[0] * right[0]
    symbols = [s for s in (left[1], right[1]) if s is not None]
    if coeff is _ZERO or not symbols:
        return a * b
    if len(symbols) == 2:
        order = symbols[0].compare(symbols[1])
        if not order:
            return a * b          # a power
        if order > 0:
            symbols.reverse()
    args = symbols if coeff is _ONE else [coeff, *symbols]
    return args[0] if len(args) == 1 else sympy.Mul._from_args(args, True)


def product_of(factors: Iterable[sympy.Expr]) -> sympy.Expr:
    """``sympy.Mul(*factors)``: built directly where no two factors combine (commutative
    factors, products among them taken apart, of distinct non-numeric bases besides
    rationals, no sum beside a rational other than 1, which ``Mul`` would distribute):
    the rationals' product first, the rest in sympy's argument order; 0 where a rational
    is 0 and no factor is known to be infinite."""
    factors = list(factors)
    coeff = _ONE
    rest = []
    bases = set()
    for f in _taken_apart(factors):
        if f.is_Rational:
            coeff *= f
            continue
        if f.is_Number or not f.is_commutative:
            return sympy.Mul(*factors)
        base = f.as_base_exp()[0]
        if base in bases or base.is_number:
            return sympy.Mul(*factors)
        bases.add(base)
        rest.append(f)
    if coeff is _ZERO:
        return _ZERO if all(f.is_finite is not False for f in rest) else sympy.Mul(*factors)
    if coeff is not _ONE and any(f.is_Add for f in rest):
        return sympy.Mul(*factors)
    if not rest:
        return coeff
    rest.sort(key=_args_sortkey)
    if coeff is not _ONE:
        rest.insert(0, coeff)
    return rest[0] if len(rest) == 1 else sympy.Mul._from_args(rest, True)


def _taken_apart(factors: list[sympy.Expr]) -> Iterable[sympy.Expr]:
    """The factors, a commutative product's own factors in its place (as Mul's flatten
    takes it apart)."""
    for f in factors:
        if f.is_Mul and f.is_commutative:
            yield from f.args
        else:
            yield f


def _monomial_key(term: sympy.Expr):
    """What sympy's ``Add`` collects ``term`` under (its factors without the coefficient),
    or None when ``term`` is not a monomial."""
    if term.is_Symbol:
        return term if term.is_commutative else None
    if not term.is_Mul or not term.is_commutative:
        return None
    args = term.args
    start = 1 if args[0].is_Rational else 0
    if start and args[0] is _ZERO:
        return None
    for factor in args[start:]:
        if not (factor.is_Symbol or factor.is_Pow and factor.base.is_Symbol and
                factor.exp.is_Integer):
            return None
    return term.as_coeff_Mul()[1]


def sum_of(terms: Iterable[sympy.Expr]) -> sympy.Expr:
    """``sympy.Add(*terms)``."""
    terms = list(terms)
    keys = set()
    for term in terms:
        key = _monomial_key(term)
        if key is None or key in keys:
            return sympy.Add(*terms)
        keys.add(key)
    if len(terms) < 2:
        return terms[0] if terms else _ZERO
    return sympy.Add._from_args(sorted(terms, key=_args_sortkey), True)
