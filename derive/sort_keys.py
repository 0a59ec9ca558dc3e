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
            return self._sympy(e)
        coeff, expr = e.as_coeff_Mul()
        factors = sympy.Mul.make_args(expr)
        bases = [f.base if f.is_Pow else f for f in factors]
        renamed = {self.names.get(b, b) for b in bases}
        if not all(b.is_Symbol and not b.is_Dummy for b in (*bases, *renamed)) or \
                any(f.is_Pow and not f.exp.is_Number for f in factors):
            return self._sympy(e)
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
