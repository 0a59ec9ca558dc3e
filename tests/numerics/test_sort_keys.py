"""derive.sort_keys.SortKeys is sympy's default_sort_key of the renamed expression, on
random products, powers, sums and calls of temporaries, input elements and plain and
dummy symbols, renamed onto each other (two factors merging into one power included),
with calls (``exp`` is a power of E to sympy) and symbolic exponents."""

from __future__ import annotations

import sympy
from hypothesis import given, settings
from hypothesis import strategies as st
from sympy import default_sort_key

from derive.sort_keys import SortKeys
from derive.statements import InputElement, Temporary

SYMBOLS = ([Temporary(f"t{i}") for i in range(5)] + [InputElement(f"P[{i}]") for i in range(3)]
           + list(sympy.symbols("x0 x1")) + [sympy.Dummy("d")])
COEFFS = [sympy.Integer(1), sympy.Integer(-1), sympy.Integer(2), sympy.Rational(1, 3),
          sympy.Float(0.5)]

atoms = st.sampled_from(SYMBOLS)
expressions = st.recursive(
    atoms | st.integers(-3, 3).map(sympy.Integer),
    lambda inner: st.one_of(
        st.tuples(st.lists(inner, min_size=1, max_size=4), st.sampled_from(COEFFS)).map(
            lambda t: t[1] * sympy.Mul(*t[0])),
        st.tuples(inner, st.sampled_from([2, -1, -2, 3, sympy.Rational(1, 2)])).map(
            lambda t: t[0] ** t[1]),
        st.lists(inner, min_size=1, max_size=3).map(lambda terms: sympy.Add(*terms)),
        inner.map(sympy.sin), inner.map(sympy.exp),
        st.tuples(inner, inner).map(lambda t: sympy.atan2(*t)),
        st.tuples(inner, inner).map(lambda t: t[0] ** t[1])),
    max_leaves=8)
renamings = st.dictionaries(st.sampled_from(SYMBOLS[:5]), st.sampled_from(SYMBOLS), max_size=3)


@settings(max_examples=400, deadline=None)
@given(st.lists(expressions, min_size=1, max_size=4), renamings)
def test_the_key_is_sympys_of_the_renamed_expression(exprs, names):
    keys = SortKeys(names)
    for e in exprs + exprs:                      # the second time from the memo
        assert keys(e) == default_sort_key(e.xreplace(names))


polynomial_terms = st.tuples(
    st.sampled_from(COEFFS + [sympy.Integer(-2), sympy.Float(-0.25), sympy.Integer(3)]),
    st.lists(st.tuples(atoms, st.sampled_from([1, 1, 2, -1, 3])), max_size=3)).map(
        lambda t: t[0] * sympy.Mul(*(s ** k for s, k in t[1])))


@settings(max_examples=1000, deadline=None)
@given(st.lists(polynomial_terms, min_size=2, max_size=6))
def test_the_key_of_a_polynomial_sum_is_sympys(terms):
    """Sums of monomials (a number and one negated monomial included, which sympy orders
    number first) take their order from their monomials' exponents, not from sympy."""
    e = sympy.Add(*terms)
    assert SortKeys()(e) == default_sort_key(e)
