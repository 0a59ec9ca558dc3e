"""derive.monomials builds products and sums exactly as sympy's Mul and Add do (same
arguments, same order, same class), on random atoms: temporaries, input elements, plain
and dummy symbols, their negations and squares, rationals and floats, repeated terms."""

from __future__ import annotations

import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.monomials import product, sum_of
from derive.statements import InputElement, Temporary

SYMBOLS = ([Temporary(f"t{i}") for i in range(6)] + [InputElement(f"P[{i}]") for i in range(4)]
           + list(sympy.symbols("x y")) + [sympy.Dummy("d")])
atoms = st.one_of(
    st.sampled_from(SYMBOLS),
    st.sampled_from(SYMBOLS).map(lambda s: -s),
    st.sampled_from(SYMBOLS).map(lambda s: s ** 2),
    st.tuples(st.integers(-5, 5), st.integers(1, 4)).map(lambda t: sympy.Rational(*t)),
    st.sampled_from([sympy.Float(0.25), sympy.Float(-1.5)]),
    st.tuples(st.sampled_from(SYMBOLS), st.sampled_from(SYMBOLS)).map(lambda t: t[0] - t[1]))


def _same(got: sympy.Expr, expected: sympy.Expr) -> bool:
    return sympy.srepr(got) == sympy.srepr(expected) and type(got) is type(expected)


@settings(max_examples=500, deadline=None)
@given(atoms, atoms)
def test_product_is_sympys(a, b):
    assert _same(product(a, b), a * b)


@settings(max_examples=500, deadline=None)
@given(st.lists(st.tuples(atoms, atoms), max_size=12), st.booleans())
def test_sum_of_products_is_sympys(pairs, repeat):
    terms = [product(a, b) for a, b in pairs]
    if repeat and terms:
        terms.append(terms[0])
    assert _same(sum_of(terms), sympy.Add(*terms))
