"""derive.apps.latency: the latency bound of a run loop's carried chain (maximum cycle mean),
on hand-built programs whose cycles are known, and on catalog filters."""

import pytest

from derive import catalog
from derive.apps.latency import carried_bound
from derive.generation import derive_unit
from derive.lowering import LoweredAssign, LoweredProgram, lower_program
from derive.program import Port
from derive.trees import Const, Op, Var

LAT = {"add": 1.0, "mul": 4.0, "fma": 4.0, "div": 14.0, "sqrt": 18.0}


def _program(body, x_new, n=2):
    return LoweredProgram(
        "step", "", (Port("x", (n,)), Port("z", (1,))), (Port("x_new", (n,)),),
        tuple(LoweredAssign(t, tree) for t, tree in body), (("x_new", tuple(x_new)),), True)


def test_a_self_loop_costs_its_chain():
    # x0' = (x0 + z) * x1, x1' = x0: the cycle x0 -> x0 runs through add and mul
    body = [("t0", Op("add", (Var("x[0]"), Var("z[0]")))),
            ("t1", Op("mul", (Var("t0"), Var("x[1]"))))]
    bound = carried_bound(_program(body, [Var("t1"), Var("x[0]")]), LAT)
    assert bound.per_step == LAT["add"] + LAT["mul"]
    assert dict(bound.operations) == {"add": 1, "mul": 1} and bound.span == 1


def test_a_two_step_cycle_is_averaged_over_its_steps():
    # x0' = x1 * c, x1' = x0 / c: no self loop; x0 -> x1 -> x0 spans two steps
    c = Const(3.0)
    body = [("t0", Op("mul", (Var("x[1]"), c))), ("t1", Op("div", (Var("x[0]"), c)))]
    bound = carried_bound(_program(body, [Var("t0"), Var("t1")]), LAT)
    assert bound.per_step == (LAT["mul"] + LAT["div"]) / 2
    assert bound.span == 2 and dict(bound.operations) == {"mul": 0.5, "div": 0.5}


def test_inputs_that_are_not_carried_add_nothing():
    # x0' = sqrt(z) + x0: only the add is on the cycle; the sqrt of z is off it
    body = [("t0", Op("sqrt", (Var("z[0]"),))), ("t1", Op("add", (Var("t0"), Var("x[0]"))))]
    bound = carried_bound(_program(body, [Var("t1")], n=1), LAT)
    assert bound.per_step == LAT["add"] and dict(bound.operations) == {"add": 1}


def test_a_check_adds_no_latency_and_unknown_kinds_are_named():
    body = [("t0", Op("mul", (Var("x[0]"), Const(2.0))))]
    program = _program(body, [Var("t0")], n=1)
    assert carried_bound(program, LAT).per_step == LAT["mul"]
    with pytest.raises(KeyError, match="mul"):
        carried_bound(program, {"add": 1.0})


def _bound(model, filt):
    unit = derive_unit(catalog.load(model), filt, {})
    return carried_bound(lower_program(unit.programs["step"], use_fma=True), LAT)


def test_independent_axes_share_one_bound():
    """mpt3d_a is three mpt3d_b axes filtered block by block: the same carried chain."""
    for filt in ("kf", "sskf"):
        a, b = _bound("mpt3d_a", filt), _bound("mpt3d_b", filt)
        assert a.per_step == b.per_step and dict(a.operations) == dict(b.operations)


def test_steady_state_chain_is_two_fmas_deep():
    """x_new = A x + B z with the carried products last: two dependent fmas per step."""
    bound = _bound("mpt3d_b", "sskf")
    assert dict(bound.operations) == {"fma": 2}
    assert bound.per_step == 2 * LAT["fma"]


def test_the_kf_chain_runs_through_its_division():
    bound = _bound("mpt3d_b", "kf")
    assert bound.operations["div"] == 1
    # sub, neg and select take add's latency; a negative fma (c - a*b) takes fma's
    total = sum(LAT.get({"fnma": "fma"}.get(k, k), LAT["add"]) * c
                for k, c in bound.operations.items())
    assert bound.per_step == pytest.approx(total)


def test_a_fir_window_has_no_carried_state():
    assert _bound("cv", "fir") is None
