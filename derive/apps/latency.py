"""The latency bound of a filter's run loop: its loop-carried dependency chain.

A run loop feeds each step's new state (``x_new``, ``P_new``) back as the next step's
``x``, ``P``.  However wide the machine, a step cannot on average finish sooner than
the heaviest cycle through that feedback allows: the maximum, over cycles of state
elements, of the summed operation latencies along the cycle divided by the number of
steps it spans (the maximum cycle mean).  Given a latency per operation kind (cycles,
or seconds measured on this machine by :mod:`derive.apps.bench.machine.probe`),
:func:`carried_bound` computes that bound from the lowered statements exactly as they are
emitted, and the operations along the critical cycle.

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
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from derive.arrivals import operation_latency
from derive.expression_lowering import CARRIED
from derive.flops import count
from derive.lowering import LoweredAssign, LoweredProgram, lower_program
from derive.options import taken_by
from derive.runs.kinds import carried_pass
from derive.schedule import REFERENCE_CYCLES, scheduled_unit
from derive.trees import Const, Op, Tree, Var

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
    """Longest paths from each carried input element to every node of the step, held
    sparsely: per node, only the carried inputs that reach it."""

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
        self._memo: dict[int, dict[int, float]] = {}
        self._names: dict[str, dict[int, float]] = {}

    def arrival(self, tree: Tree) -> dict[int, float]:
        """Per carried input that reaches ``tree``: the longest latency to its value."""
        key = id(tree)
        if key in self._memo:
            return self._memo[key]
        if isinstance(tree, Const):
            value: dict[int, float] = {}
        elif isinstance(tree, Var):
            value = self._var(tree.name)
        else:
            step = operation_latency(tree.kind, self.latency)
            joined: dict[int, float] = {}
            for arg in tree.args:
                for source, at in self.arrival(arg).items():
                    if at > joined.get(source, _NONE):
                        joined[source] = at
            value = {source: at + step for source, at in joined.items()}
        self._memo[key] = value
        return value

    def _var(self, name: str) -> dict[int, float]:
        if name in self._names:
            return self._names[name]
        if name in self.temps:
            value = self.arrival(self.temps[name])
        else:
            value = {self.index[name]: 0.0} if name in self.index else {}
        self._names[name] = value
        return value

    def edges(self) -> dict[tuple[int, int], float]:
        """``{(i, j): latency}``: the longest latency from carried input i to carried
        output j, where i reaches j."""
        return {(i, j): at for j, leaf in enumerate(self.leaves)
                for i, at in self.arrival(leaf).items()}

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
            tree = max(tree.args, key=lambda a: self.arrival(a).get(source, _NONE))


def carried_bound(lowered: LoweredProgram, latency: Mapping[str, float]) -> Bound | None:
    """The maximum cycle mean of the step's feedback, or None without carried state
    (a FIR window) or when no output depends on the carried inputs.

    A cycle lies within one strongly connected part of the feedback graph (carried
    element i to j where i reaches j), so each part's max-plus powers are taken on its
    own (their size, not the whole state's: a block-diagonal model's parts are its
    blocks), the parts scanned together step count by step count as one matrix would
    be (the first cycle of the highest mean, the fewest steps, the lowest element)."""
    graph = _Graph(lowered, latency)
    if not graph.carried:
        return None
    edges = graph.edges()
    parts = _cyclic_parts(len(graph.carried), edges)
    if not parts:
        return None
    longest = max(len(part) for part in parts)
    powers = [_Powers(part, edges, longest) for part in parts]
    best, best_cycle = _NONE, None
    for steps in range(1, longest + 1):
        value, start, owner = max(((p.diagonal[steps - 1][k], -p.nodes[k], p)
                                   for p in powers for k in [p.top[steps - 1]]),
                                  key=lambda item: (item[0], item[1]))
        if value > _NONE and value / steps > best + 1e-15:
            best, best_cycle = value / steps, (owner, -start, steps)
    if best_cycle is None:
        return None
    owner, start, steps = best_cycle
    nodes = [owner.nodes[k] for k in
             _cycle_nodes(owner.via, owner.nodes.index(start), steps)]
    kinds: Counter = Counter()
    for a, b in zip(nodes, nodes[1:] + nodes[:1], strict=True):
        kinds += graph.path_kinds(a, graph.leaves[b])
    return Bound(float(best), {k: v / steps for k, v in kinds.items()}, steps)


def _cyclic_parts(size: int, edges: Mapping[tuple[int, int], float]) -> list[list[int]]:
    """The strongly connected parts of the graph that hold a cycle, each its elements in
    increasing order."""
    if not edges:
        return []
    rows, cols = zip(*edges, strict=True)
    graph = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
    _, labels = connected_components(graph, directed=True, connection="strong")
    members: dict[int, list[int]] = {}
    for node, label in enumerate(labels):
        members.setdefault(int(label), []).append(node)
    return [part for part in members.values()
            if len(part) > 1 or (part[0], part[0]) in edges]


class _Powers:
    """The max-plus powers of one strongly connected part's matrix, 1 to ``steps``:
    per power its diagonal, the element of its greatest diagonal entry (the first), and
    the walks (``via[k][i, j]``: the node before j on the best k+1-edge walk from i)."""

    def __init__(self, nodes: list[int], edges: Mapping[tuple[int, int], float],
                 steps: int):
        self.nodes = nodes
        local = {node: k for k, node in enumerate(nodes)}
        size = len(nodes)
        A = np.full((size, size), _NONE)
        for (i, j), at in edges.items():
            if i in local and j in local:
                A[local[i], local[j]] = at
        power = A.copy()
        self.via = [np.tile(np.arange(size), (size, 1))]
        self.diagonal: list[np.ndarray] = []
        self.top: list[int] = []
        for k in range(1, steps + 1):
            diag = np.diag(power)
            self.diagonal.append(diag)
            self.top.append(int(np.argmax(diag)))
            if k == steps:
                break
            total = power[:, :, None] + A[None, :, :]        # i -> k (steps), k -> j (one)
            arg = np.argmax(total, axis=1)
            power = np.take_along_axis(total, arg[:, None, :], axis=1)[:, 0, :]
            self.via.append(arg)


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
    steady-state two-step pass, :func:`derive.runs.kinds.carried_pass`), per step; None
    for a run that calls its functions (the run kind sensors: no step program)."""
    if "step" not in unit.programs:
        return None
    program, steps = carried_pass(unit)
    bound = carried_bound(lower_program(program, use_fma=True), latency)
    if bound is None:
        return None
    return Bound(bound.per_step / steps, bound.operations, bound.span, steps)


#: Steps of more flops (C, as counted) are not scheduled just to print a bound (``derive
#: burden``, the bench), a note says so; ``--latency-schedule`` still applies it.  The
#: schedule's search takes time in proportion to the work of its rewrites, about 1 to
#: 1.5 ms of CPU per flop of a block-diagonal step (120 constant-velocity axes: 3,000
#: flops, 31,680 statements, 4 s), 0.12 ms of a dense one (16 states: 18,007 flops, 2.2 s).
MAX_BOUND_FLOPS = 4000


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
    flops = count(unit.programs["step"], "c").flops
    if flops > MAX_BOUND_FLOPS:
        return ScheduleBounds(default, None, None, f"latency schedule not computed for a step "
                              f"of {flops} flops (over {MAX_BOUND_FLOPS}); "
                              "--latency-schedule applies it")
    scheduled = scheduled_unit(unit)
    added = count(scheduled.programs["step"], "c").flops - flops
    return ScheduleBounds(default, run_loop_bound(scheduled, latency), added)
