"""Generation time of the INS/GNSS EKF: polynomial Jacobian entries are kept as derived.

Differentiating ins_gnss's polynomial f leaves the products f is written with, which the
program shares with f's own evaluation; sympy.simplify of those entries only factored or
flipped signs, cost most of the generation time and gave the predict more flops.
"""

from __future__ import annotations

import numpy as np
import sympy

from derive import catalog, staging
from derive.emit.python_printer import python_function
from derive.filters import nonlinear
from derive.filters.sensors import kalman_update
from derive.flops import count
from derive.generation import command_unit
from derive.lowering import lower_program
from derive.program import Port, Program
from derive.trees import Const, Op, Var


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


# -- the Kalman update without the back substitution --------------------------------------

N_STATES, SELECTED = 7, (4, 1, 6)  # H picks states 4, 1, 6 (a GNSS-like selector)


def _update_program(gain) -> Program:
    """``gain(prog, x, P, PHt, S, innovation_of)`` for H a selector and R diagonal."""
    n, m = N_STATES, len(SELECTED)
    prog = Program("update", [Port("x", (n,)), Port("P", (n, n), symmetric=True),
                              Port("z", (m,))],
                   [Port("x_new", (n,)), Port("P_new", (n, n), symmetric=True)])
    x, P, z = prog.matrix("x"), prog.matrix("P"), prog.matrix("z")
    PHt = P.extract(list(range(n)), list(SELECTED))
    R = sympy.diag(*[sympy.Rational(k + 1, 4) for k in range(m)])
    S = staging.add(prog, PHt.extract(list(SELECTED), list(range(m))), R,
                    symmetric_result=True)
    x_new, P_new, _ = gain(prog, x, P, PHt, S,
                           lambda: staging.sub(prog, z, x.extract(list(SELECTED), [0])))
    prog.set_output("x_new", x_new)
    prog.set_output("P_new", P_new)
    return prog.optimize()


def _textbook(prog, x, P, PHt, S, innovation_of):
    """K = P H^T S^-1 by a full LDL^T solve (back substitution included)."""
    K = staging.transpose(staging.spd_solve(prog, S, staging.transpose(PHt), name="S"))
    x_new = staging.add(prog, x, staging.matmul(prog, K, innovation_of()))
    KPHt = staging.matmul(prog, K, staging.transpose(PHt), symmetric_result=True)
    return x_new, staging.sub(prog, P, KPHt, symmetric_result=True), ()


def test_update_without_back_substitution_agrees_and_costs_fewer_flops():
    ours, textbook = _update_program(kalman_update), _update_program(_textbook)
    rng = np.random.default_rng(13)
    A = rng.standard_normal((N_STATES, N_STATES))
    P = A @ A.T + N_STATES * np.eye(N_STATES)
    x, z = rng.standard_normal(N_STATES), rng.standard_normal(len(SELECTED))
    got = python_function(ours)(x, P.ravel(), z)
    want = python_function(textbook)(x, P.ravel(), z)
    for g, w in zip(got, want):
        np.testing.assert_allclose(np.ravel(g), np.ravel(w), rtol=1e-12, atol=1e-14)
    H = np.eye(N_STATES)[list(SELECTED)]
    S = H @ P @ H.T + np.diag([(k + 1) / 4 for k in range(len(SELECTED))])
    K = P @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(np.ravel(got[1]), np.ravel(P - K @ H @ P), rtol=1e-12)
    # the back substitution's n (m - 1) m / 2 products are gone; the innovation's forward
    # substitution, m (m - 1) / 2, is new: fewer flops and fewer instructions
    assert count(ours, "c").flops < count(textbook, "c").flops
    assert count(ours, "c").instructions < count(textbook, "c").instructions


# -- no multiplication by 0 or ±1 and no addition of 0 survives ----------------------------


def _trivial_operations(tree) -> int:
    """Operations of ``tree`` that multiply by 0 or ±1 or add or subtract 0."""
    if not isinstance(tree, Op):
        return 0
    trivial = {"mul": {0.0, 1.0, -1.0}, "fma": {0.0, 1.0, -1.0}, "add": {0.0},
               "sub": {0.0}}.get(tree.kind, set())
    factors = tree.args[:2]
    found = sum(1 for a in factors if isinstance(a, Const) and a.value in trivial)
    if tree.kind == "fma" and isinstance(tree.args[2], Const) and tree.args[2].value == 0.0:
        found += 1
    return found + sum(_trivial_operations(a) for a in tree.args)


def _wasted(lowered) -> int:
    """Trivial operations of a lowered program: every one of a scalar statement; in a
    vector chunk (derive.rows), only a step trivial in all its lanes (a lane that adds a
    zero of Q beside lanes that add non-zeros is the price of the vector, not a waste)."""
    lanes = {t for chunk in lowered.rows for t in chunk.targets}
    total = sum(_trivial_operations(s.tree) for s in lowered.body
                if getattr(s, "target", None) not in lanes)
    trees = {s.target: s.tree for s in lowered.body if hasattr(s, "target")}
    for chunk in lowered.rows:
        total += min(_trivial_operations(trees[t]) for t in chunk.targets)
    return total


def test_ins_gnss_programs_have_no_multiplication_by_zero_or_one():
    unit = command_unit(_model(), "ekf")
    names = ("predict", "update_gnss", "update_baro")
    lowered = {name: lower_program(unit.programs[name], use_fma=True) for name in names}
    assert all(lowered[name].body for name in names)
    assert {name: _wasted(lowered[name]) for name in names} == dict.fromkeys(names, 0)
    assert lowered["predict"].rows and lowered["update_gnss"].rows  # the catalog's vector rows


def test_trivial_operations_are_found():
    a = Var("a")
    assert _trivial_operations(Op("fma", (Const(1.0), a, Const(0.0)))) == 2
    assert _trivial_operations(Op("add", (a, Op("mul", (Const(-1.0), a))))) == 1
