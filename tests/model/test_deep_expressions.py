"""Expressions deeper than a printer or a pass can recurse over (a sum of hundreds of
terms): the lowering cuts them into temporaries of at most MAX_DEPTH operations, in the
same order, so the code is generated, its results are bitwise those of the uncut
expression and its counts do not change."""

import operator

import numpy as np
import sympy

from derive import NonlinearModel
from derive.apps.verify import verify_filter
from derive.emit.python_printer import python_function
from derive.expression_lowering import lower
from derive.flops import count_lowered
from derive.generation import command_unit
from derive.lowering import MAX_DEPTH, LoweredAssign, lower_program
from derive.program import Port, Program
from derive.trees import Op

TERMS = 3000
OPERATIONS = {"add": operator.add, "sub": operator.sub, "mul": operator.mul,
              "neg": operator.neg}


def _depth(tree) -> int:
    deepest, stack = 0, [(tree, 0)]
    while stack:
        node, above = stack.pop()
        if isinstance(node, Op):
            stack.extend((a, above + 1) for a in node.args)
        deepest = max(deepest, above)
    return deepest


def _evaluate(tree, values: dict) -> float:
    """A tree's value in Python floats, operation by operation (iterative)."""
    done: dict[int, float] = {}
    stack = [(tree, False)]
    while stack:
        node, expanded = stack.pop()
        if not isinstance(node, Op):
            done[id(node)] = values[node.name] if hasattr(node, "name") else node.value
        elif not expanded:
            stack.append((node, True))
            stack.extend((a, False) for a in node.args)
        else:
            done[id(node)] = OPERATIONS[node.kind](*(done[id(x)] for x in node.args))
    return done[id(tree)]


def _long_sum() -> tuple[Program, sympy.Expr]:
    """A program y = sum_k c_k a_k of TERMS terms, and that sum."""
    prog = Program("f", [Port("a", (TERMS,))], [Port("y", (1,))])
    a = prog.matrix("a")
    total = sympy.Add(*(a[k] * (k % 7 + 2) for k in range(TERMS)))
    prog.set_output("y", [total])
    return prog, total


def test_every_lowered_tree_is_at_most_max_depth_deep_and_the_count_is_unchanged():
    prog, total = _long_sum()
    for use_fma in (False, True):
        lowered = lower_program(prog, use_fma=use_fma)
        trees = [s.tree for s in lowered.body] + [t for _, ts in lowered.results for t in ts]
        assert max(_depth(t) for t in trees) <= MAX_DEPTH
        assert len(lowered.body) >= TERMS // MAX_DEPTH     # it was cut
        whole = lower(total, use_fma=use_fma)
        assert _depth(whole) >= TERMS - 1
        counted = count_lowered(lowered)
        # the uncut chain: TERMS products and TERMS - 1 additions (fma: one product stays)
        assert (counted.mul, counted.add, counted.fma) == (
            (1, 0, TERMS - 1) if use_fma else (TERMS, TERMS - 1, 0))


def test_the_cut_program_computes_bitwise_what_the_uncut_tree_computes():
    prog, total = _long_sum()
    values = np.random.default_rng(3).normal(size=TERMS)
    got = python_function(prog)(values)
    whole = lower(total)
    expected = _evaluate(whole, {f"a[{k}]": float(v) for k, v in enumerate(values)})
    assert float(np.asarray(got).ravel()[0]) == expected


def test_a_model_with_a_long_sum_generates_and_verifies_in_python_and_c():
    x, v = sympy.symbols("x v")
    terms = 150                       # a chain of 150 > MAX_DEPTH operations
    h = sum((x - sympy.Rational(k, terms)) ** 2 / terms for k in range(terms))
    model = NonlinearModel("deep", ["x", "v"], ["y"], f=[x + v / 10, sympy.Rational(9, 10) * v],
                           h=[h], Q=[[1e-3, 0], [0, 1e-3]], R=[[0.1]])
    unit = command_unit(model, "ekf")
    lowered = lower_program(unit.programs["step"], use_fma=True)
    assert any(isinstance(s, LoweredAssign) for s in lowered.body)
    assert max(_depth(s.tree) for s in lowered.body) <= MAX_DEPTH
    for result in verify_filter(model, "ekf", steps=50):
        assert result.error <= result.tolerance, result
