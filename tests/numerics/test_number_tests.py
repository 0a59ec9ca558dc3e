"""derive.statements' shortcuts through sympy, on random expressions: ``is_number`` (each
composite's answer remembered) is sympy's ``Expr.is_number``, and ``with_arguments`` is
the call sympy builds with ``evaluate=False`` (its admissible argument counts included)."""

from __future__ import annotations

import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.statements import InputElement, Temporary, is_number, with_arguments

SYMBOLS = [Temporary("t0"), Temporary("t1"), InputElement("P[0]"), sympy.Symbol("dt")]
NUMBERS = [sympy.Integer(0), sympy.Integer(-2), sympy.Rational(1, 3), sympy.Float(0.25),
           sympy.pi, sympy.E]
CALLS = [sympy.sin, sympy.cos, sympy.exp, sympy.sqrt, sympy.atan,
         lambda a: sympy.atan2(a, sympy.Integer(2))]

leaves = st.sampled_from(SYMBOLS + NUMBERS)
expressions = st.recursive(
    leaves,
    lambda inner: st.one_of(
        st.lists(inner, min_size=2, max_size=3).map(lambda a: sympy.Add(*a)),
        st.lists(inner, min_size=2, max_size=3).map(lambda a: sympy.Mul(*a)),
        st.tuples(inner, st.sampled_from([2, -1, sympy.Rational(1, 2)])).map(
            lambda t: t[0] ** t[1]),
        st.tuples(st.sampled_from(CALLS), inner).map(lambda t: t[0](t[1])),
        inner.map(lambda a: sympy.Function("g")(a))),
    max_leaves=8)


@settings(max_examples=500, deadline=None)
@given(expressions)
def test_is_number_is_sympys(expr):
    for node in sympy.preorder_traversal(expr):
        assert is_number(node) == bool(node.is_number), node
    assert is_number(expr) == bool(expr.is_number)      # again, from the memo


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(CALLS[:5]), st.lists(expressions, min_size=1, max_size=1))
def test_with_arguments_is_the_unevaluated_call(call, args):
    original = call(Temporary("t9") + 1)
    if not isinstance(original, sympy.Function):
        return                      # sqrt is a power, not a call
    built = with_arguments(original, args)
    expected = original.func(*args, evaluate=False)
    assert built == expected and built.args == expected.args
    assert built.nargs == expected.nargs and type(built) is type(expected)
    assert hash(built) == hash(expected)
