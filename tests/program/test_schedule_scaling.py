"""The latency schedule at scale (derive.schedule, derive.arrivals, derive.apps.latency):
the search scores each tried rewrite on what it changes, and the carried bound is taken
per strongly connected part of the feedback, so a step of thousands of statements gets
both bounds.  Time limits here only guard against hangs (never a speed assertion)."""

from __future__ import annotations

import random

import pytest
import sympy
from _band_models import band_model, hang_guard

from derive import LinearModel, catalog
from derive import schedule as schedule_module
from derive.apps.latency import run_loop_bound, schedule_bounds
from derive.arrivals import Arrivals, statement_form
from derive.expression_lowering import expression_lowerer
from derive.filters import derive_unit
from derive.flops import count
from derive.schedule import REFERENCE_CYCLES
from derive.statements import Assign, Check, InputElement, Temporary

HANG_GUARD = 120    # seconds; the search takes about one on this machine


def _axes(k: int) -> LinearModel:
    axis = catalog.load("mpt3d_b")
    return LinearModel.compose(f"cv{k}", [axis] * k, [f"_{i}" for i in range(k)])


def _assert_valid_order(program) -> None:
    """Each temporary defined once, before anything reads it; every result defined."""
    defined: set = set()
    for st in program.body:
        expr = st.expr if isinstance(st, Assign) else st.value
        read = {s for s in expr.free_symbols if isinstance(s, Temporary)}
        assert read <= defined, (st, read - defined)
        if isinstance(st, Assign):
            assert st.target not in defined, st
            defined.add(st.target)
    for values in program.results.values():
        for v in values:
            assert {s for s in v.free_symbols if isinstance(s, Temporary)} <= defined


@pytest.fixture(scope="module")
def one_axis():
    return derive_unit(_axes(1), "kf", {})


def test_a_step_of_over_a_thousand_statements_gets_both_bounds(one_axis):
    """24 independent axes (n = 48): a step of 1,728 statements. Both bounds are those
    of one axis (the axes never meet), and the flops the schedule adds are 24 times one
    axis's."""
    unit = derive_unit(_axes(24), "kf", {})
    size = len(unit.programs["step"].optimize().body)
    assert size >= 1000
    with hang_guard(HANG_GUARD):
        both = schedule_bounds(unit)
    single = schedule_bounds(one_axis)
    assert both.note == ""
    assert both.default.per_step == single.default.per_step
    assert both.latency.per_step == single.latency.per_step
    assert both.latency.per_step < both.default.per_step
    assert both.flops_added == 24 * single.flops_added


def test_the_large_schedule_is_a_valid_order_with_each_axis_counted_once(one_axis):
    """The scheduled step of 24 axes: a valid order (each temporary defined once, before
    it is read), its checks in the default step's order, and its operations exactly 24
    times those of one scheduled axis, kind by kind."""
    model = _axes(24)
    with hang_guard(HANG_GUARD):
        fast = derive_unit(model, "kf", {"latency_schedule": True}).programs["step"]
    plain = derive_unit(model, "kf", {}).programs["step"].optimize()
    _assert_valid_order(fast)
    assert [st.message for st in fast.body if isinstance(st, Check)] == \
        [st.message for st in plain.body if isinstance(st, Check)]
    one = derive_unit(_axes(1), "kf", {"latency_schedule": True}).programs["step"]
    for lang in ("c", "python"):
        mine, single = count(fast, lang), count(one, lang)
        assert mine.flops == 24 * single.flops
        arithmetic = [k for k, v in vars(mine).items() if isinstance(v, int) and k != "cmp"]
        assert {k: getattr(mine, k) for k in arithmetic} == \
            {k: 24 * getattr(single, k) for k in arithmetic}
        assert mine.cmp == count(plain, lang).cmp     # the P0 pattern's checks, as they were
    lowered_bound = run_loop_bound(derive_unit(model, "kf", {"latency_schedule": True}))
    assert lowered_bound.per_step == run_loop_bound(
        derive_unit(_axes(1), "kf", {"latency_schedule": True})).per_step


def test_120_axes_default_bound_is_one_axis_bound(one_axis):
    """n = 240: 57,840 carried elements, each axis its own part of the feedback."""
    with hang_guard(HANG_GUARD):
        bound = run_loop_bound(derive_unit(_axes(120), "kf", {}))
    assert bound.per_step == run_loop_bound(one_axis).per_step
    assert dict(bound.operations) == dict(run_loop_bound(one_axis).operations)


# -- the incremental arrivals against a whole rescore ---------------------------------

def _random_edits(seed: int):
    """A catalog step and random edits of it: a statement's expression replaced by a sum
    or product of values defined before it, sometimes through a new temporary."""
    rng = random.Random(seed)
    unit = derive_unit(catalog.load(rng.choice(["mpt3d_a", "gsm2d_a", "ca"])), "kf", {})
    program = unit.programs["step"].optimize()
    return rng, program


@pytest.mark.parametrize("seed", range(12))
def test_a_trial_scores_as_a_rescore_of_the_edited_step(seed):
    rng, program = _random_edits(seed)
    lower = expression_lowerer(use_fma=True, state_ports=("x", "P"))

    def form(expr):
        return statement_form(lower(expr), ("x", "P"), REFERENCE_CYCLES)

    leaves = [v.name for out in ("x_new", "P_new") for v in program.results[out]
              if isinstance(v, Temporary)]
    body = list(program.body)
    state = Arrivals(body, form, leaves)
    inputs = [InputElement(f"P[{i}]") for i in range(4)] + [InputElement("x[0]")]
    counter = 0
    for _ in range(30):
        spots = [k for k, st in enumerate(body) if isinstance(st, Assign)]
        k = rng.choice(spots[1:])
        earlier = [st.target for st in body[:k] if isinstance(st, Assign)] + inputs
        a, b = rng.sample(earlier, 2)
        expr = rng.choice([a + b, a * b, a - b, sympy.Integer(3) * a + b])
        changed = []
        if rng.random() < 0.5:
            counter += 1
            new = Temporary(f"e{counter}")
            changed.append(Assign(new, expr))
            expr = new + rng.choice(earlier)
        changed.append(Assign(body[k].target, expr))
        edited = body[:k] + changed + body[k + 1:]
        trial = state.trial(changed)
        whole = Arrivals(edited, form, leaves)
        assert trial.score() == whole.score()
        if rng.random() < 0.7:
            state.accept(trial)
            body = edited
            assert state.score() == whole.score()
            assert state.ready == whole.ready


def test_the_bench_prints_both_bounds_of_k_axes(one_axis):
    """derive bench's table of large KFs: both bounds of k axes, those of one axis."""
    from derive.apps.bench.costs.schedule_scaling import schedule_rows, schedule_table
    from derive.apps.bench.run import Settings, _columns

    single = schedule_bounds(one_axis)
    (row,) = schedule_rows((4,))
    assert (row.axes, row.states, row.default_cycles, row.latency_cycles, row.flops_added) == \
        (4, 8, single.default.per_step, single.latency.per_step, 4 * single.flops_added)
    assert row.flops == 4 * count(one_axis.programs["step"], "c").flops and row.note == ""
    lines = _columns(*schedule_table([row]))
    assert f"+{4 * single.flops_added}" in lines[-1]
    assert 120 in Settings().schedule_axes


# -- late factors: refused unbuilt exactly when scoring the built rewrite would -------------

def _late_edits(monkeypatch, unit, shortcuts: bool):
    """The scheduled step of ``unit`` and, per late-factor rewrite built, whether scoring
    it lowered the step's score (``shortcuts`` False: every candidate built and scored)."""
    built = []
    late = schedule_module._Work._late

    def recorded(self, slots, state, *args):
        edit = late(self, slots, state, *args)
        if edit is not None:
            built.append(state.trial(edit[0]).score() < state.score())
        return edit
    monkeypatch.setattr(schedule_module._Work, "_late", recorded)
    if not shortcuts:
        monkeypatch.setattr(schedule_module._Work, "_late_may_win", lambda *a: True)
        monkeypatch.setattr(schedule_module._Work, "_late_wins", lambda *a: True)
    with hang_guard(HANG_GUARD):
        step = schedule_module.scheduled_unit(unit).programs["step"]
    monkeypatch.undo()
    return step, built


def test_late_factors_are_built_only_when_they_win_and_the_step_is_the_same(monkeypatch):
    """A Joseph-form KF with missing measurements (the search's largest sums): each late
    rewrite that is built lowers the score (a 32-state step tried 3,700 that did not,
    building and lowering sums of hundreds of terms each time), and the scheduled step
    is bitwise the one of building and scoring every candidate."""
    unit = derive_unit(band_model(8), "kf", {"joseph": True, "missing": True})
    fast, built = _late_edits(monkeypatch, unit, shortcuts=True)
    assert built and all(built)
    slow, every = _late_edits(monkeypatch, unit, shortcuts=False)
    assert every.count(True) == len(built) and every.count(False) > len(built)
    assert list(map(str, fast.body)) == list(map(str, slow.body))
    assert fast.results == slow.results
