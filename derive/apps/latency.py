"""The latency bound of a filter's run loop: its loop-carried dependency chain.

A run loop feeds each step's new state (``x_new``, ``P_new``) back as the next step's
``x``, ``P``.  However wide the machine, a step cannot on average finish sooner than
the heaviest cycle through that feedback allows: the maximum, over cycles of state
elements, of the summed operation latencies along the cycle divided by the number of
steps it spans (the maximum cycle mean).  Given a latency per operation kind (cycles,
or seconds measured on this machine by :mod:`derive.apps.bench.probe`), :func:`carried_bound`
computes that bound from the lowered statements exactly as they are emitted, and the
operations along the critical cycle.

Operation kinds are those of :mod:`derive.lowering`; a check (``cmp``) only branches,
so it adds no latency to the data path.  :func:`schedule_bounds` gives both bounds of a
time-varying filter: its default schedule's and the latency schedule's
(:mod:`derive.schedule`, ``--latency-schedule``), with the flops the latter adds.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from derive.arrivals import operation_latency
from derive.emit.lookahead import run_pass
from derive.flops import count
from derive.lowering import (
    CARRIED,
    Const,
    LoweredAssign,
    LoweredProgram,
    Op,
    Tree,
    Var,
    lower_program,
)
from derive.options import taken_by
from derive.schedule import REFERENCE_CYCLES, scheduled_unit

_NONE = -np.inf


@dataclass(frozen=True)
class Bound:
    """Latency per step of the critical cycle and the operations on it per pass of the
    loop (a pass is ``steps`` steps: 2 for a steady-state two-step pass, else 1)."""

    per_step: float
    operations: Mapping[str, float]
    span: int                      # passes the critical cycle spans
    steps: int = 1

    def describe(self) -> str:
        ops = ", ".join(f"{c:g} {k}" for k, c in sorted(self.operations.items()))
        return ops + (f" per pass of {self.steps} steps" if self.steps > 1 else "")


class _Graph:
    """Longest paths from each carried input element to every node of the step."""

    def __init__(self, lowered: LoweredProgram, latency: Mapping[str, float]):
        self.latency = latency
        results = dict(lowered.results)
        self.pairs = [(out, port) for port, out in CARRIED
                      if out in results and any(p.name == port for p in lowered.inputs)]
        self.carried = [f"{port}[{i}]" for out, port in self.pairs
                        for i in range(len(results[out]))]
        self.index = {name: i for i, name in enumerate(self.carried)}
        self.temps: dict[str, Tree] = {st.target: st.tree for st in lowered.body
                                       if isinstance(st, LoweredAssign)}
        self.leaves = [leaf for out, _ in self.pairs for leaf in results[out]]
        self._memo: dict[int, np.ndarray] = {}
        self._names: dict[str, np.ndarray] = {}

    def arrival(self, tree: Tree) -> np.ndarray:
        """Per carried input: the longest latency from it to ``tree``'s value."""
        key = id(tree)
        if key in self._memo:
            return self._memo[key]
        size = len(self.carried)
        if isinstance(tree, Const):
            value = np.full(size, _NONE)
        elif isinstance(tree, Var):
            value = self._var(tree.name)
        else:
            value = np.full(size, _NONE)
            for arg in tree.args:
                value = np.maximum(value, self.arrival(arg))
            value = value + operation_latency(tree.kind, self.latency)
        self._memo[key] = value
        return value

    def _var(self, name: str) -> np.ndarray:
        if name in self._names:
            return self._names[name]
        size = len(self.carried)
        if name in self.temps:
            value = self.arrival(self.temps[name])
        else:
            value = np.full(size, _NONE)
            if name in self.index:
                value[self.index[name]] = 0.0
        self._names[name] = value
        return value

    def matrix(self) -> np.ndarray:
        """``A[i, j]``: longest latency from carried input i to carried output j."""
        return np.stack([self.arrival(leaf) for leaf in self.leaves], axis=1)

    def path_kinds(self, source: int, tree: Tree) -> Counter:
        """Operation kinds on a longest path from carried input ``source`` to ``tree``."""
        kinds: Counter = Counter()
        while True:
            if isinstance(tree, Var):
                if tree.name not in self.temps:
                    return kinds
                tree = self.temps[tree.name]
                continue
            if not isinstance(tree, Op):
                return kinds
            if tree.kind != "cmp":
                kinds[tree.kind] += 1
            tree = max(tree.args, key=lambda a: self.arrival(a)[source])


def carried_bound(lowered: LoweredProgram, latency: Mapping[str, float]) -> Bound | None:
    """The maximum cycle mean of the step's feedback, or None without carried state
    (a FIR window) or when no output depends on the carried inputs."""
    graph = _Graph(lowered, latency)
    if not graph.carried:
        return None
    A = graph.matrix()
    size = len(A)
    best, best_cycle = _NONE, None
    power = A.copy()
    via = [np.tile(np.arange(size), (size, 1))]   # via[k][i, j]: the node after i
    for steps in range(1, size + 1):
        diag = np.diag(power)
        i = int(np.argmax(diag))
        if diag[i] > _NONE and diag[i] / steps > best + 1e-15:
            best, best_cycle = diag[i] / steps, (i, steps)
        if steps == size:
            break
        total = power[:, :, None] + A[None, :, :]        # i -> k (steps), k -> j (one)
        arg = np.argmax(total, axis=1)
        power = np.take_along_axis(total, arg[:, None, :], axis=1)[:, 0, :]
        via.append(arg)
    if best_cycle is None:
        return None
    start, steps = best_cycle
    nodes = _cycle_nodes(via, start, steps)
    kinds: Counter = Counter()
    for a, b in zip(nodes, nodes[1:] + nodes[:1], strict=True):
        kinds += graph.path_kinds(a, graph.leaves[b])
    return Bound(float(best), {k: v / steps for k, v in kinds.items()}, steps)


def _cycle_nodes(via: list[np.ndarray], start: int, steps: int) -> list[int]:
    """The carried elements on the best ``steps``-edge walk from ``start`` back to it, in
    order from ``start`` (``via[k - 1][start, j]``: the node before j on the best k-edge
    walk from ``start`` to j)."""
    walk, j = [start], start
    for k in range(steps, 1, -1):
        j = int(via[k - 1][start, j])
        walk.append(j)
    walk.reverse()          # start's successor ... the node before the end
    return [start] + walk[:-1] if steps > 1 else [start]


def run_loop_bound(unit, latency: Mapping[str, float] = REFERENCE_CYCLES) -> Bound | None:
    """The bound of ``unit``'s generated C run loop as emitted: its pass (the step, or a
    steady-state two-step pass, :func:`derive.emit.lookahead.run_pass`), per step; None
    for a run that calls its functions (the run kind sensors: no step program)."""
    if "step" not in unit.programs:
        return None
    program, steps = run_pass(unit)
    bound = carried_bound(lower_program(program, use_fma=True), latency)
    if bound is None:
        return None
    return Bound(bound.per_step / steps, bound.operations, bound.span, steps)


#: Steps with more statements are not scheduled just to print a bound (``derive burden``,
#: the bench): the schedule's search grows with the square of the step's size (about 6 s
#: at 300 statements, twelve axes of mpt3d_b); ``--latency-schedule`` still applies it.
MAX_BOUND_STATEMENTS = 400


@dataclass(frozen=True)
class ScheduleBounds:
    """A filter's run-loop bound in its default schedule and in the latency schedule
    (None where the latency schedule does not apply: a two-step pass, no carried state,
    a filter without the option; or where it was not computed, ``note`` says why), and
    the flops per step the latency schedule adds (C, as counted)."""

    default: Bound | None
    latency: Bound | None
    flops_added: int | None
    note: str = ""


def schedule_bounds(unit, latency: Mapping[str, float] = REFERENCE_CYCLES) -> ScheduleBounds:
    """Both bounds of ``unit`` (derived in its default schedule); the latency schedule's
    for a filter that takes the option ``latency_schedule``."""
    default = run_loop_bound(unit, latency)
    if default is None or unit.lookahead is not None or \
            "latency_schedule" not in taken_by(unit.filter):
        return ScheduleBounds(default, None, None)
    size = len(unit.programs["step"].optimize().body)
    if size > MAX_BOUND_STATEMENTS:
        return ScheduleBounds(default, None, None, f"latency schedule not computed for a step "
                              f"of {size} statements (over {MAX_BOUND_STATEMENTS}); "
                              "--latency-schedule applies it")
    scheduled = scheduled_unit(unit)
    added = count(scheduled.programs["step"], "c").flops - count(unit.programs["step"], "c").flops
    return ScheduleBounds(default, run_loop_bound(scheduled, latency), added)
