"""The latency bound of a case's generated C run loop on this machine: the carried
chain of the loop's pass as emitted (the step, or a steady-state filter's two-step pass;
:mod:`derive.apps.latency`) with the operation latencies measured by
:mod:`derive.apps.bench.machine.probe`; for a time-varying filter also the bound of its latency
schedule (``--latency-schedule``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .... import catalog
from ....filters import derive_unit
from ...latency import ScheduleBounds, run_loop_bound, schedule_bounds
from ..cases import Case
from ..timing import measure
from .c_kernels import compiled_kernels


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


_STREAM = """#include <stddef.h>
void derive_stream(size_t steps, const double *restrict in, double *restrict out)
{{
    size_t k;
    for (k = 0; k < steps; ++k) {{
        const double *restrict r = in + k * {read};
        double *restrict w = out + k * {written};
{body}
    }}
}}
"""
"""A run loop's memory traffic alone: per step, read ``read`` doubles and write ``written``
(each a copy of one read, so every read is used), over arrays as long as the run's; the
counts are constants, so the loop is as the compiler makes a copy of that shape."""


@dataclass(frozen=True)
class MemoryBound:
    """The least time per step of a C loop moving a run's bytes and nothing else."""

    per_step: float      # seconds per step, all copies
    read: int            # bytes read a step (one copy)
    written: int         # bytes written a step (one copy)

    def describe(self) -> str:
        return (f"a C loop reading {self.read} and writing {self.written} bytes a step over "
                "arrays as long as the run's")


def memory_bound(read: int, written: int, steps: int, repeats: int, copies: int = 1,
                 cflags: Sequence[str] = ()) -> MemoryBound:
    """The memory-traffic bound of a run loop of ``steps`` steps that reads ``read`` (at
    least 1) and writes ``written`` doubles a step, ``copies`` such runs in turn: the
    minimum over ``repeats`` of a C loop streaming the same bytes through arrays of the
    same sizes, compiled with ``cflags``. Where the run's arrays do not fit the cache, no filter on
    them can be faster."""
    body = "\n".join(f"        w[{j}] = r[{j % read}];" for j in range(written))
    lib = compiled_kernels("stream", _STREAM.format(read=read, written=written, body=body),
                           "void derive_stream(size_t steps, const double *in, double *out);",
                           ["-std=c99", *cflags])
    import cffi  # C builds load cffi only when something is compiled

    ffi = cffi.FFI()
    source, target = np.ones(steps * read), np.empty(steps * written)
    args = (steps, ffi.from_buffer("double[]", source), ffi.from_buffer("double[]", target))
    best = measure(lambda: lib.derive_stream(*args), steps, repeats).low
    return MemoryBound(best * copies, 8 * read, 8 * written)
