"""derive.lowering: the single lowering both the counter and the printers walk."""

import math

import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.emit import c_printer, python_printer
from derive.expression_lowering import LoweringError, lower
from derive.trees import Const, Op, Var, count_tree

a, b, c, d, x = sympy.symbols("a b c d x")
A, B, C, D, X = (Var(s) for s in "abcdx")


def mul(*args):
    return Op("mul", args)


@pytest.mark.parametrize("expr, tree", [
    (a - 2 * b, Op("sub", (A, mul(Const(2.0), B)))),
    (-x, Op("neg", (X,))),
    (-2 * x, mul(Const(-2.0), X)),
    (x**2, mul(X, X)),
    (x**3, mul(mul(X, X), X)),
    (1 / x, Op("div", (Const(1.0), X))),
    (a / b, Op("div", (A, B))),
    (3 / b, Op("div", (Const(3.0), B))),
    (-1 / b, Op("div", (Const(-1.0), B))),
    (2 * a / b, Op("div", (mul(Const(2.0), A), B))),
    (-a / b, Op("neg", (Op("div", (A, B)),))),
    (a / (b * c), Op("div", (A, mul(B, C)))),
    (sympy.sqrt(x), Op("sqrt", (X,))),
    (1 / sympy.sqrt(x), Op("div", (Const(1.0), Op("sqrt", (X,))))),
    (x ** sympy.Rational(3, 2), mul(X, Op("sqrt", (X,)))),
    (x / 3, mul(Const(1 / 3), X)),
    (sympy.sqrt(2) * x, mul(Const(math.sqrt(2)), X)),
    (-a - b, Op("sub", (Op("neg", (A,)), B))),
    (1 - a, Op("sub", (Const(1.0), A))),
    (a + b + c, Op("add", (Op("add", (A, B)), C))),
    (sympy.sin(x), Op("call:sin", (X,))),
    (sympy.Abs(x), Op("call:fabs", (X,))),
])
def test_lowering_rules(expr, tree):
    assert lower(expr) == tree


@pytest.mark.parametrize("expr, tree", [
    (a * b + c, Op("fma", (A, B, C))),
    (a - 2 * b * c, Op("fma", (Const(-2.0), mul(B, C), A))),
    (a - b * c, Op("fnma", (B, C, A))),
    (a * b + c * d, Op("fma", (C, D, mul(A, B)))),
    (1 + a * b, Op("fma", (A, B, Const(1.0)))),
])
def test_fma_rules(expr, tree):
    assert lower(expr, use_fma=True) == tree


def test_fma_puts_deeper_products_last():
    deep = (a + b) * c   # operand depth 1
    tree = lower(deep + d * x + a, use_fma=True)
    assert tree.kind == "fma" and Op("add", (A, B)) in tree.args[:2]


@pytest.mark.parametrize("expr", [sympy.Max(a, b), x ** sympy.Rational(1, 3), sympy.I * x,
                                  sympy.Function("f")(x)])
def test_unsupported_raises_clear_error(expr):
    with pytest.raises(LoweringError):
        lower(expr)


def _evaluate(tree, env):
    if isinstance(tree, Const):
        return tree.value
    if isinstance(tree, Var):
        return env[tree.name]
    v = [_evaluate(t, env) for t in tree.args]
    return {"add": lambda: v[0] + v[1], "sub": lambda: v[0] - v[1], "mul": lambda: v[0] * v[1],
            "div": lambda: v[0] / v[1], "neg": lambda: -v[0], "sqrt": lambda: math.sqrt(v[0]),
            "fma": lambda: v[0] * v[1] + v[2], "fnma": lambda: v[2] - v[0] * v[1]}[tree.kind]()


_leaves = st.sampled_from([a, b, c, d, sympy.Integer(2), sympy.Rational(-3, 4),
                           sympy.Float(0.1)])


def _combine(children):
    pair = st.tuples(children, children)
    return st.one_of(pair.map(lambda p: p[0] + p[1]), pair.map(lambda p: p[0] - p[1]),
                     pair.map(lambda p: p[0] * p[1]),
                     pair.map(lambda p: p[0] / (p[1] ** 2 + 1)),
                     children.map(lambda e: e ** 2),
                     children.map(lambda e: sympy.sqrt(e ** 2 + 1)))


@settings(max_examples=150, deadline=None)
@given(st.recursive(_leaves, _combine, max_leaves=8))
def test_lowered_value_and_fma_flops(expr):
    env = {"a": 0.7, "b": -1.3, "c": 2.1, "d": 0.4}
    want = float(expr.subs({a: 0.7, b: -1.3, c: 2.1, d: 0.4}))
    plain, fused = lower(expr), lower(expr, use_fma=True)
    for tree in (plain, fused):
        assert _evaluate(tree, env) == pytest.approx(want, rel=1e-12, abs=1e-12)
    # an fma replaces exactly one mul and one add/sub: same flops, fewer instructions
    assert count_tree(fused).flops == count_tree(plain).flops
    assert count_tree(fused).instructions <= count_tree(plain).instructions


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_constants_round_trip(value):
    for printer in (python_printer, c_printer):
        text = printer.expression(Const(value))
        assert float(text.strip("()")) == value
        assert "." in text or "e" in text or "inf" in text


def test_constants_print_as_doubles():
    assert python_printer.expression(lower(2 * x)) == "2.0*x"
    assert c_printer.expression(lower(-2 * x)) == "(-2.0)*x"
    assert c_printer.expression(lower(sympy.Rational(1, 10) * x)) == "0.1*x"


def test_parentheses_keep_evaluation_order():
    tree = Op("sub", (A, Op("sub", (B, C))))
    assert python_printer.expression(tree) == "a - (b - c)"
    assert python_printer.expression(Op("div", (A, mul(B, C)))) == "a/(b*c)"
    assert c_printer.expression(Op("neg", (Op("neg", (A,)),))) == "-(-a)"
    assert c_printer.expression(Op("fma", (A, B, C))) == "DERIVE_FMA(a, b, c)"
    assert python_printer.expression(Op("sqrt", (Op("add", (A, B)),))) == "_sqrt(a + b)"


def test_lowering_is_deterministic_in_term_order():
    e1 = sympy.Add(c * d, a * b, x, evaluate=True)
    e2 = sympy.Add(x, a * b, c * d, evaluate=True)
    assert lower(e1) == lower(e2)
