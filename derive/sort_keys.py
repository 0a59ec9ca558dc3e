"""sympy's :func:`~sympy.default_sort_key`, remembered per expression.

Generated code lists the terms of a sum and the factors of a product in sympy's order,
so the same program always prints the same way.  sympy computes that order's key
recursively and keeps it in its own cache, which holds about a thousand entries: a step of
thousands of statements evicts its keys long before they recur, and computing them again
was a seventh of the derivation of a 32-state filter.  :class:`SortKeys` keeps every key
it computes, and builds the key of a monomial (``c * a**k * b * ...``, the terms of nearly
every sum derive lowers) from its factors' keys exactly as :meth:`sympy.Expr.sort_key`
builds it; everything else is sympy's own key.  ``names`` renames symbols first (the key
of ``e.xreplace(names)``), so a program's temporaries can be ordered by the symbols they
copy.  ``tests/numerics/test_sort_keys.py`` compares it with sympy on random expressions.
"""

from __future__ import annotations

from collections.abc import Mapping

import sympy
from sympy import default_sort_key

_ONE = sympy.S.One
_ONE_KEY = _ONE.sort_key()


class SortKeys:
    """``keys(e) == default_sort_key(e.xreplace(names))`` for every expression ``e``."""

    def __init__(self, names: Mapping[sympy.Symbol, sympy.Symbol] | None = None) -> None:
        self.names = dict(names or {})
        self._keys: dict[sympy.Basic, tuple] = {}

    def __call__(self, e: sympy.Basic) -> tuple:
        key = self._keys.get(e)
        if key is None:
            key = self._keys[e] = self._key(e)
        return key

    def _sympy(self, e: sympy.Basic) -> tuple:
        return default_sort_key(e.xreplace(self.names) if self.names else e)

    def _key(self, e: sympy.Basic) -> tuple:
        if e.is_Symbol:
            return self.names.get(e, e).sort_key()
        if e.is_Number:
            return e.sort_key()
        if not (e.is_Mul or e.is_Pow) or not e.is_commutative:
            return self._structural(e)
        coeff, expr = e.as_coeff_Mul()
        factors = sympy.Mul.make_args(expr)
        bases = [f.base if f.is_Pow else f for f in factors]
        renamed = {self.names.get(b, b) for b in bases}
        if not all(b.is_Symbol and not b.is_Dummy for b in (*bases, *renamed)) or \
                any(f.is_Pow and not f.exp.is_Number for f in factors):
            return self._structural(e)
        if len(renamed) < len(bases):
            return self._sympy(e)     # renaming merges two factors into one power
        if expr.is_Pow:
            base, exp = expr.as_base_exp()
            renamed = self.names.get(base, base)
            return (renamed.class_key(), (1, (str(renamed),)), exp.sort_key(), coeff)
        if expr.is_Symbol:
            renamed = self.names.get(expr, expr)
            return (renamed.class_key(), (1, (str(renamed),)), _ONE.sort_key(), coeff)
        args = sorted(self(f) for f in factors)
        return (expr.class_key(), (len(args), tuple(args)), _ONE.sort_key(), coeff)

    def _structural(self, e: sympy.Basic) -> tuple:
        """:meth:`sympy.Expr.sort_key` of ``e`` from its arguments' remembered keys, where
        ``e``'s class keeps that method and no symbol of ``e`` is renamed (a call such as
        ``sin(x3 + 0.5)``, a product of calls); sympy's own key otherwise, and for a sum
        (whose terms sympy orders by its own rules)."""
        if type(e).sort_key is not sympy.Expr.sort_key or \
                self.names and not e.free_symbols.isdisjoint(self.names):
            return self._sympy(e)
        if e.is_Add:
            terms = self._polynomial_terms(e)
            if terms is None:
                return self._sympy(e)
            args = tuple(self(t) for t in terms)
            return (e.class_key(), (len(args), args), _ONE_KEY, _ONE)
        coeff, expr = e.as_coeff_Mul()
        if expr.is_Pow:
            base, exp = expr.as_base_exp()
            if base is sympy.S.Exp1:
                return self._sympy(e)
            expr = base
        else:
            exp = _ONE
        if expr.is_Dummy:
            args: tuple = (expr.sort_key(),)
        elif expr.is_Atom:
            args = (str(expr),)
        elif expr.is_Add or not all(isinstance(a, sympy.Basic) for a in expr.args):
            return self._sympy(e)
        elif expr.is_Mul:
            commuting, others = expr.args_cnc()
            args = (*sorted(self(a) for a in commuting), *(self(a) for a in others))
        else:
            args = tuple(self(a) for a in expr.args)
        return (expr.class_key(), (len(args), args), self(exp), coeff)

    def _polynomial_terms(self, e: sympy.Add) -> list[sympy.Expr] | None:
        """The terms of the sum ``e`` in :meth:`sympy.Add.as_ordered_terms`' order, where
        each term is a real number or one times a product of integer powers of symbols
        (None otherwise): the number first in ``c - k*a`` (c > 0, k < 0), else by
        monomial, lexicographic on the exponents of the symbols in their key's order,
        higher first, the number last."""
        terms = e.args
        if len(terms) == 2:
            number, other = (terms if terms[0].is_Number else terms[::-1])
            if number.is_Number and number.is_positive and other.is_Mul and \
                    len(other.args) == 2 and other.args[0].is_Number and \
                    other.args[0].is_negative:
                return [number, other]
        monomials = []
        for term in terms:
            coeff, rest = term.as_coeff_Mul()
            if not (coeff.is_Number and coeff.is_extended_real):
                return None
            powers = {}
            for factor in sympy.Mul.make_args(rest) if rest is not _ONE else ():
                base, exp = factor.as_base_exp() if factor.is_Pow else (factor, _ONE)
                if not (base.is_Symbol and base.is_commutative and exp.is_Integer):
                    return None
                powers[base] = int(exp)
            monomials.append((term, powers))
        gens = sorted({base for _, powers in monomials for base in powers}, key=self)
        where = {base: k for k, base in enumerate(gens)}

        def order(monomial: tuple) -> tuple[int, ...]:
            exponents = [0] * len(gens)
            for base, exp in monomial[1].items():
                exponents[where[base]] = -exp
            return tuple(exponents)
        return [term for term, _ in sorted(monomials, key=order)]
