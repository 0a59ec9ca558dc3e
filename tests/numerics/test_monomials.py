"""derive.monomials builds products and sums exactly as sympy's Mul and Add do (same
arguments, same order, same class), on random atoms: temporaries, input elements, plain
and dummy symbols, their negations and squares, rationals and floats, repeated terms; and
products of many factors (calls, powers, sums, numbers, exponentials that combine)."""

from __future__ import annotations

import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.monomials import product, product_of, sum_of
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


factors = st.one_of(
    atoms,
    st.sampled_from(SYMBOLS).map(sympy.sin),
    st.tuples(st.sampled_from(SYMBOLS), st.sampled_from(SYMBOLS)).map(
        lambda t: sympy.cos(t[0] + t[1])),
    st.sampled_from(SYMBOLS).map(lambda s: 1 / s),
    st.sampled_from(SYMBOLS).map(sympy.sqrt),
    st.sampled_from(SYMBOLS).map(sympy.exp),
    st.sampled_from(SYMBOLS).map(lambda s: 2 ** s),
    st.sampled_from([sympy.sqrt(2), sympy.sqrt(3), sympy.pi, sympy.I, sympy.S.Zero, sympy.S.One,
                     sympy.oo]))


@settings(max_examples=1000, deadline=None)
@given(st.lists(factors, max_size=6))
def test_product_of_many_factors_is_sympys(fs):
    assert _same(product_of(fs), sympy.Mul(*fs))


def test_product_of_every_pair_and_triple_of_kinds_is_sympys():
    """Every pair and triple of one factor of each kind, where hypothesis might not draw
    the two that combine (sqrt(2)*sqrt(3) is sqrt(6), 2**x*3**x is 6**x)."""
    t, u = SYMBOLS[0], SYMBOLS[7]
    kinds = [t, -t, t ** 2, 1 / t, sympy.sqrt(t), sympy.exp(t), sympy.exp(u), sympy.sin(t),
             sympy.sin(t + u), t + u, 2 ** t, 3 ** t, sympy.sqrt(2), sympy.sqrt(3), sympy.pi,
             sympy.I, sympy.oo, sympy.S.Zero, sympy.S.One, sympy.Integer(-2),
             sympy.Rational(1, 3), sympy.Rational(1, 2), sympy.Float(0.5), u, t * u,
             2 * t * u, sympy.Mul(3, t + u, evaluate=False),
             sympy.Mul(sympy.Rational(1, 3), t + u, evaluate=False), sympy.zoo, sympy.nan,
             sympy.Symbol("f", finite=True), sympy.Symbol("g", infinite=True)]
    for a in kinds:
        for b in kinds:
            assert _same(product_of([a, b]), a * b), (a, b)
            for c in kinds[::3]:
                assert _same(product_of([a, b, c]), sympy.Mul(a, b, c)), (a, b, c)
