"""A sum whose only term left beside its fma products is a negative constant (the INS
model's 2 q3² − 1) is lowered with a signed constant, as printed (``-1.0``): the static
count has no negation the C text does not have."""

from __future__ import annotations

import sympy

from derive.expression_lowering import lower
from derive.flops import count_c_text
from derive.trees import Const, Op, count_tree


def test_negative_constant_beside_fma_products_is_not_a_negation():
    q = sympy.Symbol("q", real=True)
    tree = lower(2 * q ** 2 - 1, use_fma=True)
    assert isinstance(tree, Op) and tree.kind == "fma"
    assert tree.args[2] == Const(-1.0)
    counted = count_tree(tree)
    assert counted.neg == 0
    assert counted == count_c_text("DERIVE_FMA(2.0, q*q, -1.0)")


def test_a_negated_variable_is_still_a_negation():
    a, b = sympy.symbols("a b", real=True)
    assert count_tree(lower(-a - 2 * b, use_fma=True)).neg == 1
