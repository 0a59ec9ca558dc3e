"""Generation time of the INS/GNSS EKF: polynomial Jacobian entries are kept as derived.

Differentiating ins_gnss's polynomial f leaves the products f is written with, which the
program shares with f's own evaluation; sympy.simplify of those entries only factored or
flipped signs, cost most of the generation time and gave the predict more flops.
"""

from __future__ import annotations

import sympy

from derive import catalog
from derive.filters import nonlinear
from derive.flops import count
from derive.generation import command_unit


def _model():
    return catalog.load("ins_gnss")


def test_polynomial_jacobian_entries_are_kept_as_derived():
    model = _model()
    f = model.subs(model.f)
    wrt = model.state_symbols + model.f_inputs
    entries = [sympy.diff(fi, w) for fi in f for w in wrt]
    assert all(e.is_polynomial() for e in entries)
    simplifier = nonlinear._Simplifier()
    changed = [e for e in entries if simplifier(e) is not e]
    assert changed == []
    assert simplifier.spent == 0


def test_an_entry_with_a_function_is_still_simplified():
    x = sympy.Symbol("x", real=True)
    entry = sympy.sin(x) ** 2 + sympy.cos(x) ** 2 + x
    assert nonlinear._Simplifier()(entry) == x + 1


def _predict_flops() -> int:
    unit = command_unit(_model(), "ekf")
    return count(unit.programs["predict"], "c").flops


def test_predict_has_fewer_flops_than_with_simplified_polynomial_entries(monkeypatch):
    kept = _predict_flops()

    def simplify_every_entry(self, expr):  # the bounded simplify, polynomials included
        if expr.is_Atom or sympy.count_ops(expr) > nonlinear.MAX_SIMPLIFY_OPERATIONS:
            return expr
        candidate = sympy.simplify(expr)
        return candidate if sympy.count_ops(candidate) < sympy.count_ops(expr) else expr

    monkeypatch.setattr(nonlinear._Simplifier, "__call__", simplify_every_entry)
    assert kept < _predict_flops()
