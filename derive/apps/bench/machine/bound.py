"""The latency bound of a case's generated C run loop on this machine: the carried
chain of the loop's pass as emitted (the step, or a steady-state filter's two-step pass;
:mod:`derive.apps.latency`) with the operation latencies measured by
:mod:`derive.apps.bench.machine.probe`; for a time-varying filter also the bound of its latency
schedule (``--latency-schedule``)."""

from __future__ import annotations

from collections.abc import Mapping

from .... import catalog
from ....filters import derive_unit
from ...latency import ScheduleBounds, run_loop_bound, schedule_bounds
from ..cases import Case


def case_bound(case: Case, latency: Mapping[str, float]) -> tuple[float, str] | None:
    """(seconds per step, the operations on the critical cycle) for ``case``'s generated
    C; copies run one after another, so their bounds add up. None without a bound."""
    bound = run_loop_bound(derive_unit(catalog.load(case.model), case.filter, {}), latency)
    if bound is None:
        return None
    per_copy = f" per copy, {case.copies} copies in turn" if case.copies > 1 else ""
    return bound.per_step * case.copies, bound.describe() + per_copy


def case_schedule_bounds(case: Case, latency: Mapping[str, float]) -> ScheduleBounds:
    """Both bounds of one copy of ``case``'s generated C (seconds per step): in the default
    schedule and in the latency schedule (derive.schedule), with the flops it adds."""
    return schedule_bounds(derive_unit(catalog.load(case.model), case.filter, {}), latency)
