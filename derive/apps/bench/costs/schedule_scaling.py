"""Both bounds of large block-diagonal KFs: k constant-velocity axes (n = 2k), the
default schedule's carried chain and the latency schedule's (derive.apps.latency), and
the CPU time the latency schedule's search and the two bounds take (``time.process_time``:
the machine may be shared).  Dense random KFs (every entry of F and H non-zero) add rows
of the search alone: their carried bounds are not taken (max-plus over n + n² carried
elements, one strongly connected part: seconds to minutes), their chain through one
step is (the search's own score, in the note)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

from .... import catalog
from ....filters import derive_unit
from ....flops import count
from ....model import LinearModel
from ....schedule import REFERENCE_CYCLES, one_step_chain, scheduled_unit
from ...latency import schedule_bounds
from .compile_size import dense_model

AXES = (3, 12, 48, 120)
"""Constant-velocity axes per model: n = 6, 24, 96, 240."""
AXIS_MODEL = "mpt3d_b"
DENSE_STATES = (16, 24)
"""Dense random KFs (derive.apps.bench.costs.compile_size.dense_model: m = n/3)."""


@dataclass(frozen=True)
class ScheduleRow:
    axes: int | None              # None: a dense random KF
    states: int
    statements: int               # of the default step, optimised (checks included)
    flops: int                    # of the default step (C, fma = 2)
    search_seconds: float         # CPU: the latency schedule of the step
    bounds_seconds: float         # CPU: derive.apps.latency.schedule_bounds (both bounds)
    default_cycles: float | None  # per step, reference cycles
    latency_cycles: float | None
    flops_added: int | None
    note: str = ""


def _axes_model(k: int) -> LinearModel:
    axis = catalog.load(AXIS_MODEL)
    return LinearModel.compose(f"cv{k}", [axis] * k, [f"_{i}" for i in range(k)])


def schedule_rows(axes=AXES, latency: Mapping[str, float] = REFERENCE_CYCLES,
                  tick=lambda text: None) -> list[ScheduleRow]:
    rows = []
    for k in axes:
        tick(f"latency schedule of {k} axes")
        unit = derive_unit(_axes_model(k), "kf", {})
        step = unit.programs["step"]
        cpu = time.process_time()
        scheduled_unit(unit)
        search = time.process_time() - cpu
        cpu = time.process_time()
        both = schedule_bounds(unit, latency)
        bounds = time.process_time() - cpu
        rows.append(ScheduleRow(
            k, 2 * k, len(step.optimize().body), count(step, "c").flops, search, bounds,
            None if both.default is None else both.default.per_step,
            None if both.latency is None else both.latency.per_step,
            both.flops_added, both.note))
    return rows


def dense_rows(states=DENSE_STATES, tick=lambda text: None) -> list[ScheduleRow]:
    """The latency schedule's search on dense random KFs of ``states`` states: its CPU
    time, the flops it adds and the chain through one step before and after."""
    rows = []
    for n in states:
        tick(f"latency schedule of a dense {n}-state KF")
        unit = derive_unit(dense_model(n), "kf", {})
        step = unit.programs["step"]
        cpu = time.process_time()
        scheduled = scheduled_unit(unit).programs["step"]
        search = time.process_time() - cpu
        flops = count(step, "c").flops
        before, after = one_step_chain(step, unit.carried), one_step_chain(scheduled,
                                                                            unit.carried)
        rows.append(ScheduleRow(
            None, n, len(step.optimize().body), flops, search, 0.0, None, None,
            count(scheduled, "c").flops - flops,
            f"bounds not taken; one step's chain {before:g} -> {after:g} cycles"))
    return rows


def schedule_table(rows: list[ScheduleRow]) -> tuple[tuple, list[tuple]]:
    head = ("axes", "n", "statements", "flops", "search CPU", "both bounds CPU",
            "default", "latency schedule", "flops added", "note")
    body = [("dense" if r.axes is None else str(r.axes), str(r.states), str(r.statements),
             str(r.flops),
             f"{r.search_seconds:.2f} s",
             "" if r.axes is None else f"{r.bounds_seconds:.2f} s",
             "" if r.default_cycles is None else f"{r.default_cycles:g}",
             "" if r.latency_cycles is None else f"{r.latency_cycles:g}",
             "" if r.flops_added is None else f"+{r.flops_added}", r.note) for r in rows]
    return head, body
