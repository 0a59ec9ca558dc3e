"""The latency schedule on dense steps (derive.schedule): a direct sum is built only when
a lower bound of its arrival could lower the step's score, so a dense step, whose direct
sums are chains of hundreds of terms, schedules in seconds, not minutes; the bound never
changes a decision (the search with it makes the programs of the search that builds every
candidate, bitwise), and the step it makes agrees with the default step.  The CPU-time
limit here only guards against a hang (never a speed assertion)."""

from __future__ import annotations

import math
import random
import signal
from contextlib import contextmanager

import numpy as np
import pytest
import sympy

from derive import LinearModel, catalog
from derive.apps.bench.costs.compile_size import dense_model
from derive.apps.bench.costs.schedule_scaling import dense_rows, schedule_table
from derive.apps.bench.run import Settings, _columns
from derive.arrivals import Arrivals, Form, operation_latency
from derive.filters import derive_unit
from derive.flops import count
from derive.lowering import LoweredAssign, lower_program
from derive.schedule import (
    REFERENCE_CYCLES,
    _affine,
    _Slots,
    _Work,
    latency_schedule,
    one_step_chain,
)
from derive.statements import Assign, InputElement, Temporary
from derive.trees import Op, Var

#: CPU seconds: a dense 20-state step took 38 s before the bound, about 5 s with it.
HANG_GUARD_CPU = 60


@contextmanager
def cpu_guard(seconds: int):
    """Stop the block once it has used ``seconds`` of CPU (the process's, ITIMER_PROF)."""
    def stop(signum, frame):
        raise TimeoutError(f"still running after {seconds} s of CPU")
    previous = signal.signal(signal.SIGPROF, stop)
    signal.setitimer(signal.ITIMER_PROF, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, previous)


def _dense(n: int, m: int = 3, seed: int = 1) -> LinearModel:
    """A KF model whose F is full (near the identity), H full: a dense step."""
    rng = np.random.default_rng(seed)
    F = (np.eye(n) + 0.05 * rng.standard_normal((n, n))).round(3).tolist()
    H = rng.standard_normal((m, n)).round(2).tolist()
    return LinearModel(f"dense{n}", [f"x{i}" for i in range(n)], [f"z{i}" for i in range(m)],
                       F=F, G=np.eye(n).tolist(), H=H, Q=(0.01 * np.eye(n)).tolist(),
                       R=(0.1 * np.eye(m)).tolist())


def _one_step_chain(program) -> float:
    """The longest path, in reference cycles, from a carried input element (x, P) to a
    carried output (x_new, P_new) through one step as lowered with fma: walked on the
    trees here, apart from the search's incremental arrivals (the max-plus bound over
    the 420 carried elements of a dense 20-state step takes ten seconds)."""
    lowered = lower_program(program, use_fma=True)
    ready: dict[str, float] = {}

    def arrival(tree) -> float:
        if isinstance(tree, Var):
            if tree.index is None:
                return ready.get(tree.name, -math.inf)
            return 0.0 if tree.base in ("x", "P") else -math.inf
        if isinstance(tree, Op):
            return max((arrival(a) for a in tree.args), default=-math.inf) + \
                operation_latency(tree.kind, REFERENCE_CYCLES)
        return -math.inf
    for st in lowered.body:
        if isinstance(st, LoweredAssign):
            ready[st.target] = arrival(st.tree)
    results = dict(lowered.results)
    return max(arrival(tree) for name in ("x_new", "P_new") for tree in results[name])


def _value(expr: sympy.Expr, env: dict) -> float:
    """``expr`` in doubles (symbols by name from ``env``)."""
    if expr.is_Symbol:
        return env[expr.name]
    if expr.is_number:
        return float(expr)
    args = [_value(a, env) for a in expr.args]
    if expr.is_Add:
        return math.fsum(args)
    if expr.is_Mul:
        return math.prod(args)
    if expr.is_Pow:
        return args[0] ** args[1]
    raise TypeError(f"no value for {expr.func}")


def _step(program, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    env = {f"{port}[{i}]": float(v) for port, values in inputs.items()
           for i, v in enumerate(values.ravel())}
    for st in program.body:
        if isinstance(st, Assign):
            env[st.target.name] = _value(st.expr, env)
    return {name: np.array([_value(v, env) for v in values])
            for name, values in program.results.items()}


def test_a_dense_20_state_step_schedules_without_a_hang_and_agrees_with_the_default():
    """A dense 20-state KF (m = 3): scheduled within the CPU guard; its carried chain
    through one step no longer than the default's; one step from a random state agrees
    with the default step to 1e-12 of each output's largest magnitude (the schedule
    changes rounding only)."""
    n = 20
    default = derive_unit(_dense(n), "kf", {}).programs["step"]
    with cpu_guard(HANG_GUARD_CPU):
        scheduled = latency_schedule(default)
    assert _one_step_chain(scheduled) <= _one_step_chain(default)
    rng = np.random.default_rng(7)
    a = rng.standard_normal((n, n))
    inputs = {"x": rng.standard_normal(n), "P": a @ a.T / n + np.eye(n),
              "z": rng.standard_normal(3)}
    want, got = _step(default.optimize(), inputs), _step(scheduled, inputs)
    assert set(want) == set(got) == {"x_new", "P_new"}
    for name in want:
        scale = np.max(np.abs(want[name]))
        assert np.max(np.abs(got[name] - want[name])) <= 1e-12 * scale, name


def _every_candidate_built(monkeypatch) -> None:
    """The search as it was: every direct sum built and scored (the bound never
    refuses), every affine form computed afresh."""
    monkeypatch.setattr(_Work, "_direct_bound", lambda self, groups, constant: -math.inf)

    def afresh(self, body):
        forms: dict = {}
        for st in body:
            if isinstance(st, Assign):
                form = _affine(st.expr, forms)
                if form is not None:
                    forms[st.target] = form
        return forms
    monkeypatch.setattr(_Work, "_affine_forms", afresh)


def _listing(program) -> str:
    return "\n".join(map(str, program.body)) + repr(sorted(program.results.items()))


@pytest.mark.parametrize("make", [
    lambda: catalog.load("mpt3d_a"),
    lambda: catalog.load("gsm2d_a"),
    lambda: LinearModel.compose("cv4", [catalog.load("mpt3d_b")] * 4,
                                [f"_{i}" for i in range(4)]),
    lambda: _dense(6),
    lambda: _dense(8, m=2, seed=3),
], ids=["mpt3d_a", "gsm2d_a", "4 axes", "dense 6", "dense 8"])
def test_the_bound_changes_no_decision(make, monkeypatch):
    """The search with the bound and the kept forms makes the program of the search that
    builds and scores every candidate, bitwise (the names a refused direct sum would have
    taken are spent, so later rewrites are named, and their terms ordered, as before)."""
    step = derive_unit(make(), "kf", {}).programs["step"]
    fast = latency_schedule(step)
    with monkeypatch.context() as patched:
        _every_candidate_built(patched)
        full = latency_schedule(step)
    assert _listing(fast) == _listing(full)


def _random_form(rng: random.Random) -> dict:
    """A random affine form over carried (P) and other (z) input elements, coefficients
    drawn from a few values so that groups of equal ones form."""
    coefficients = [sympy.Rational(rng.randint(-3, 3) or 1, rng.choice([1, 2, 5]))
                    for _ in range(rng.randint(1, 4))]
    keys = [InputElement(f"P[{i}]") for i in range(rng.randint(0, 12))] + \
        [InputElement(f"z[{i}]") for i in range(rng.randint(0, 3))]
    rng.shuffle(keys)
    expr = sympy.Add(*[rng.choice(coefficients) * k for k in keys[:max(2, len(keys))]],
                     rng.choice([0, sympy.Rational(1, 10)]))
    return _affine(expr, {})


def test_the_bound_of_a_direct_sum_is_never_above_its_arrival():
    """For random affine forms: the bound of the direct sum (computed from the form's
    coefficient groups) is at most the arrival of the direct sum as built and lowered."""
    rng = random.Random(11)
    program = derive_unit(catalog.load("mpt3d_b"), "kf", {}).programs["step"].optimize()
    checked = 0
    for _ in range(300):
        form = _random_form(rng)
        if form is None or sum(1 for k in form if k is not sympy.S.One) < 2:
            continue
        work = _Work(program, [("x", "x_new"), ("P", "P_new")])
        target = Temporary("target")
        body = [Assign(target, sympy.Integer(0))]
        state = Arrivals(body, work.form, [])
        built = work._build_direct(_Slots(body), target, form)
        groups: dict = {}
        for key in form:
            if key is not sympy.S.One:
                groups.setdefault(form[key], []).append(key)
        bound = work._direct_bound(groups, sympy.S.One in form)
        arrival = state.trial(built[0]).moved["target"]
        assert bound <= arrival, (form, bound, arrival)
        checked += 1
    assert checked > 100


def test_lowers_score_is_the_score_of_the_step_with_that_arrival():
    """Arrivals.lowers_score(name, value): exactly whether the whole step scored again, with
    that statement arriving at ``value``, scores lower (it stops at the first carried
    output that moves)."""
    program = derive_unit(catalog.load("mpt3d_a"), "kf", {}).programs["step"].optimize()
    work = _Work(program, [("x", "x_new"), ("P", "P_new")])
    body = list(program.body)
    state = work.arrivals(body)
    seen = set()
    for st in body:
        if not isinstance(st, Assign):
            continue
        name = st.target.name
        now = state.ready[name]
        for value in (now, now - 4, now - 8, 0.0, -math.inf):
            def form_of(expr, st=st, value=value):
                return Form(value, ()) if expr is st.expr else work.form(expr)
            again = Arrivals(body, form_of, work._carried_leaf_names()).score()
            lowers = state.lowers_score(name, value)
            assert lowers == (again < state.score()), (name, value)
            seen.add(lowers)
    assert seen == {True, False}


def test_lowers_score_follows_each_accepted_edit():
    """The answers lowers_score remembers per temporary are those of the step as edited:
    after each accepted edit (a statement made to arrive at once), every temporary's
    answer is again that of scoring the whole edited step."""
    program = derive_unit(catalog.load("mpt3d_a"), "kf", {}).programs["step"].optimize()
    work = _Work(program, [("x", "x_new"), ("P", "P_new")])
    body = list(program.body)
    state = work.arrivals(body)
    assigns = [st for st in body if isinstance(st, Assign)]
    answers = set()
    for edited in assigns[::7]:
        for st in assigns:
            state.lowers_score(st.target.name, state.ready[st.target.name] - 4)
        body = [Assign(edited.target, sympy.Integer(0)) if st is edited else st
                for st in body]
        state.accept(state.trial([Assign(edited.target, sympy.Integer(0))]))
        for st in assigns:
            name, now = st.target.name, state.ready[st.target.name]
            again = Arrivals(body, lambda e, st=st, now=now, body=body: Form(now - 4, ())
                             if e is st.expr and st in body else work.form(e),
                             work._carried_leaf_names()).score()
            lowers = state.lowers_score(name, now - 4)
            assert lowers == (again < state.score()), (edited.target, name)
            answers.add(lowers)
    assert answers == {True, False}


def test_the_bench_prints_the_search_on_dense_kfs():
    """derive bench's dense rows: the search's CPU, the flops it adds (as counted) and
    the chain through one step before and after (the bounds are not taken)."""
    (row,) = dense_rows((6,))
    unit = derive_unit(dense_model(6), "kf", {})
    scheduled = latency_schedule(unit.programs["step"])
    added = count(scheduled, "c").flops - count(unit.programs["step"], "c").flops
    assert (row.axes, row.states, row.flops_added) == (None, 6, added)
    assert row.default_cycles is None and row.latency_cycles is None
    before, after = one_step_chain(unit.programs["step"]), one_step_chain(scheduled)
    assert after <= before
    assert row.note.endswith(f"one step's chain {before:g} -> {after:g} cycles")
    line = _columns(*schedule_table([row]))[-1]
    assert line.startswith("dense") and f"+{added}" in line
    assert Settings().schedule_dense == (16, 24) and Settings.quick().schedule_dense == ()
