"""When the carried inputs reach each temporary of a step, kept up to date edit by edit.

The latency schedule (:mod:`derive.schedule`) tries thousands of small rewrites of a step
(a statement replaced, a few inserted) and scores each by the latest time a carried input
(an element of ``x`` or ``P``) reaches the carried outputs, on the statements as the
lowering (:mod:`derive.lowering`, with fma) emits them.  Scoring the whole step again for
every trial costs time in the square of the step's size; here a step's arrivals are
held once, and a trial re-evaluates only the statements it changes and those downstream
whose arrival actually moves (:meth:`Arrivals.trial`), and an accepted trial updates
them in place (:meth:`Arrivals.accept`).

A statement's arrival is the longest path through its lowered tree: the maximum, over
the tree's leaves, of the leaf's arrival plus the latencies of the operations between the
leaf and the root.  Each statement is reduced once to that form (:class:`Form`: the
carried input elements' part and, per temporary read, its path's latency), so that an
arrival is a few additions and a maximum.  With latencies in whole cycles (as
:data:`derive.schedule.REFERENCE_CYCLES`) every sum is exact, so the arrivals, the
maximum and the sum over the outputs are bitwise those of scoring the whole step in order.
"""

from __future__ import annotations

import heapq
import math
from bisect import insort
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import sympy

from derive.statements import Assign, Statement
from derive.trees import Op, Tree, Var

_NEVER = -math.inf


def operation_latency(kind: str, latency: Mapping[str, float]) -> float:
    """The latency of one operation of ``kind`` (a kind of :mod:`derive.lowering`) in
    ``latency``: ``sub``, ``neg``, ``select`` and ``gate`` (a compare and a select) as
    ``add``, ``fnma`` (``c - a*b``, one fused instruction) as ``fma``, a call as ``call``;
    a check (``cmp``) only branches, so it adds nothing to the data path."""
    if kind == "cmp":
        return 0.0
    if kind in latency:
        return float(latency[kind])
    if kind == "fnma" and "fma" in latency:
        return float(latency["fma"])
    if kind in ("sub", "neg", "select", "gate") and "add" in latency:
        return float(latency["add"])
    if kind.startswith("call:") and "call" in latency:
        return float(latency["call"])
    raise KeyError(f"no latency given for operation kind {kind!r}")


@dataclass(frozen=True)
class Form:
    """A statement's arrival as a function of the temporaries it reads: ``max(carried,
    max(arrival(t) + path for t, path in reads))`` (``-inf`` when nothing carried
    reaches it)."""

    carried: float
    reads: tuple[tuple[str, float], ...]

    def arrival(self, ready: Callable[[str], float]) -> float:
        value = self.carried
        for name, path in self.reads:
            value = max(value, ready(name) + path)
        return value


def statement_form(tree: Tree, carried_ports: Iterable[str],
                   latency: Mapping[str, float]) -> Form:
    """The :class:`Form` of a lowered tree (``carried_ports``: the ports whose elements
    arrive at 0; a variable without an index is a temporary)."""
    ports = set(carried_ports)
    carried = _NEVER
    reads: dict[str, float] = {}
    stack: list[tuple[Tree, float]] = [(tree, 0.0)]
    while stack:
        node, above = stack.pop()
        if isinstance(node, Var):
            if node.index is None:
                reads[node.name] = max(reads.get(node.name, _NEVER), above)
            elif node.base in ports:
                carried = max(carried, above)
        elif isinstance(node, Op):
            below = above + operation_latency(node.kind, latency)
            stack.extend((arg, below) for arg in node.args)
    return Form(carried, tuple(sorted(reads.items())))


def arrival_times(body: Sequence[Statement], form_of: Callable[[sympy.Expr], Form]
                  ) -> dict[str, float]:
    """Per temporary of ``body`` (in order): its arrival, nothing kept for edits."""
    ready: dict[str, float] = {}
    for st in body:
        if isinstance(st, Assign):
            ready[st.target.name] = form_of(st.expr).arrival(
                lambda name: ready.get(name, _NEVER))
    return ready


class Arrivals:
    """The arrivals of one step's temporaries (statements in a valid order: each
    temporary defined before it is read) and the score of its carried outputs.

    ``form_of``: an expression's :class:`Form`; ``leaves``: the carried outputs'
    temporaries (one entry per output element, so a temporary that is two elements
    counts twice)."""

    def __init__(self, body: Sequence[Statement], form_of: Callable[[sympy.Expr], Form],
                 leaves: Iterable[str]) -> None:
        self.form_of = form_of
        self.forms: dict[str, Form] = {}
        self.ready: dict[str, float] = {}
        self.readers: dict[str, set[str]] = {}
        self.height: dict[str, int] = {}
        self.leaves = Counter(leaves)
        for st in body:
            if isinstance(st, Assign):
                name = st.target.name
                self._define(name, form_of(st.expr))
                self.ready[name] = self.forms[name].arrival(self._ready)
        self.counts: Counter = Counter()
        for name, times in self.leaves.items():
            value = self.ready.get(name, _NEVER)
            if value > _NEVER:
                self.counts[value] += times
        self.values = sorted(self.counts)            # the distinct finite leaf arrivals
        self.total = sum(value * times for value, times in self.counts.items())
        self.version = 0                  # counts the accepted edits: what callers remember
        self.criticals: dict[str, bool] = {}

    def _ready(self, name: str) -> float:
        return self.ready.get(name, _NEVER)

    def _define(self, name: str, form: Form) -> None:
        old = self.forms.get(name)
        if old is not None:
            for read, _ in old.reads:
                self.readers.get(read, set()).discard(name)
        self.forms[name] = form
        for read, _ in form.reads:
            self.readers.setdefault(read, set()).add(name)
        height = 1 + max((self.height.get(read, 0) for read, _ in form.reads), default=0)
        self._raise(name, height)

    def _raise(self, name: str, height: int) -> None:
        """Height ``height`` at least for ``name``, and each reader above what it reads."""
        work = [(name, height)]
        while work:
            name, height = work.pop()
            if self.height.get(name, 0) >= height and name in self.height:
                continue
            self.height[name] = height
            work.extend((reader, height + 1) for reader in self.readers.get(name, ()))

    def score(self) -> tuple[float, float]:
        """(the latest carried output, the sum over the carried outputs): smaller is
        better; (0, 0) when nothing carried reaches them."""
        return (self.values[-1] if self.values else 0.0, self.total)

    def trial(self, changed: Sequence[Assign]) -> Trial:
        """The arrivals after ``changed`` (statements new or rewritten, in the order of
        the step; what they read is unchanged or among them) replace their targets."""
        moved: dict[str, float] = {}

        def ready(name: str) -> float:
            value = moved.get(name)
            return self.ready.get(name, _NEVER) if value is None else value

        forms = {}
        for st in changed:
            name = st.target.name
            forms[name] = form = self.form_of(st.expr)
            moved[name] = form.arrival(ready)
        return self._propagate(forms, moved)

    def lowers_score(self, name: str, value: float) -> bool:
        """Whether the score gets lower when temporary ``name`` (of the step) arrives at
        ``value``, its statement's form left as it is.  The score is monotone in each
        arrival (arrivals are maxima of sums), so asking with a lower bound of a
        rewrite's arrival tells whether the rewrite could lower it.

        The answer is the same for every ``value`` below the current arrival: a reader's
        arrival falls exactly when none of its unmoved reads (nor its carried part)
        reaches its current arrival, whatever the moved ones fell to, so which
        statements fall does not depend on how far ``name`` falls.  It is therefore
        remembered per temporary until an edit is accepted (:meth:`critical`)."""
        return value < self.ready.get(name, _NEVER) and self.critical(name)

    def critical(self, name: str) -> bool:
        """Whether an earlier arrival of temporary ``name`` lowers the score: the score
        is lower exactly when a carried output's arrival falls from above 0 (the sum over
        the outputs drops; one at 0 can only fall to "never", leaving both), so the walk
        downstream stops at the first that does."""
        known = self.criticals.get(name)
        if known is None:
            known = self.criticals[name] = self._falls_to_a_leaf(name)
        return known

    def _falls_to_a_leaf(self, name: str) -> bool:
        ready, forms, readers, height = self.ready, self.forms, self.readers, self.height
        leaves = self.leaves
        if name in leaves and ready[name] > 0:
            return True
        fallen = {name}
        queue = [(height[reader], reader) for reader in readers.get(name, ())]
        heapq.heapify(queue)
        queued = {name, *readers.get(name, ())}
        while queue:
            _, current = heapq.heappop(queue)
            form = forms[current]
            old = ready[current]
            if form.carried >= old or any(read not in fallen and
                                          ready.get(read, _NEVER) + path >= old
                                          for read, path in form.reads):
                continue
            if current in leaves and old > 0:
                return True
            fallen.add(current)
            for reader in readers.get(current, ()):
                if reader not in queued:
                    queued.add(reader)
                    heapq.heappush(queue, (height[reader], reader))
        return False

    def _propagate(self, forms: dict[str, Form], moved: dict[str, float]) -> Trial:
        """``moved`` (the arrivals of ``forms``' statements, or of the named ones) carried
        to the statements downstream whose arrival moves."""

        def ready(name: str) -> float:
            value = moved.get(name)
            return self.ready.get(name, _NEVER) if value is None else value

        queue: list[tuple[int, str]] = []
        queued: set[str] = set(moved)

        def enqueue(name: str) -> None:
            for reader in self.readers.get(name, ()):
                if reader not in queued:
                    queued.add(reader)
                    heapq.heappush(queue, (self.height[reader], reader))

        for name in list(moved):
            if moved[name] != self.ready.get(name, _NEVER):
                enqueue(name)
        while queue:
            _, name = heapq.heappop(queue)
            value = self.forms[name].arrival(ready)
            if value != self.ready[name]:
                moved[name] = value
                enqueue(name)
        return Trial(self, forms, moved)

    def accept(self, trial: Trial) -> None:
        """Make ``trial`` (of this step, nothing accepted since) the step's state."""
        for name, form in trial.forms.items():
            self._define(name, form)
        for name, value in trial.leaf_changes():
            old, times = self.ready.get(name, _NEVER), self.leaves[name]
            if old > _NEVER:
                self.counts[old] -= times
                self.total -= old * times
                if not self.counts[old]:
                    del self.counts[old]
                    self.values.remove(old)
            if value > _NEVER:
                if value not in self.counts:
                    insort(self.values, value)
                self.counts[value] += times
                self.total += value * times
        self.ready.update(trial.moved)
        self.version += 1
        self.criticals.clear()


@dataclass
class Trial:
    """A tried edit of a step: the forms of the statements it changes and the arrivals
    that move."""

    arrivals: Arrivals
    forms: dict[str, Form]
    moved: dict[str, float]

    def leaf_changes(self) -> list[tuple[str, float]]:
        leaves = self.arrivals.leaves
        return [(name, value) for name, value in self.moved.items() if name in leaves]

    def score(self) -> tuple[float, float]:
        """:meth:`Arrivals.score` of the step after this edit."""
        base = self.arrivals
        changes = self.leaf_changes()
        if not changes:
            return base.score()
        delta: Counter = Counter()
        total = base.total
        for name, value in changes:
            old, times = base.ready.get(name, _NEVER), base.leaves[name]
            if old > _NEVER:
                delta[old] -= times
                total -= old * times
            if value > _NEVER:
                delta[value] += times
                total += value * times
        latest = max((value for value, times in delta.items() if times > 0), default=_NEVER)
        for value in reversed(base.values):
            if value <= latest:
                break
            if base.counts[value] + delta.get(value, 0) > 0:
                latest = value
                break
        return (latest if latest > _NEVER else 0.0, total)
