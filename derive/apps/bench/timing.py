"""Timing: per-step time of a run, the median over repeats with its range."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Timing:
    """Seconds per step: median, min and max over ``repeats`` runs of ``steps`` steps."""

    median: float
    low: float
    high: float
    steps: int
    repeats: int


def measure(run: Callable[[], object], steps: int, repeats: int) -> Timing:
    """Time ``run()`` (which performs ``steps`` steps) ``repeats`` times after one warm-up
    call; per-step times are the run times divided by ``steps``."""
    if steps < 1 or repeats < 1:
        raise ValueError(f"need steps >= 1 and repeats >= 1, got {steps}, {repeats}")
    run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append((time.perf_counter() - start) / steps)
    return _timing(times, steps, repeats)


def measure_turns(runs: Sequence[Callable[[], object]], steps: int, repeats: int
                  ) -> list[Timing]:
    """:func:`measure` of several runs taking turns within each repeat, so that a moment of
    load on a shared machine slows each alike: the ratio of their minima is the figure that
    stays when the load moves."""
    if steps < 1 or repeats < 1:
        raise ValueError(f"need steps >= 1 and repeats >= 1, got {steps}, {repeats}")
    for run in runs:
        run()
    times: list[list[float]] = [[] for _ in runs]
    for _ in range(repeats):
        for run, kept in zip(runs, times):
            start = time.perf_counter()
            run()
            kept.append((time.perf_counter() - start) / steps)
    return [_timing(kept, steps, repeats) for kept in times]


def _timing(times: list[float], steps: int, repeats: int) -> Timing:
    times = sorted(times)
    mid = len(times) // 2
    median = times[mid] if len(times) % 2 else (times[mid - 1] + times[mid]) / 2
    return Timing(median, times[0], times[-1], steps, repeats)


def timing_cells(timing: Timing | None, ratio: float | None, agreement: float | None
                 ) -> tuple[str, str, str, str]:
    """A timed row's cells: median, min-max, ratio and agreement ("skipped" untimed)."""
    return (human(timing.median) if timing else "skipped",
            f"{human(timing.low)}-{human(timing.high)}" if timing else "",
            "" if ratio is None else f"{ratio:,.1f}x",
            "" if agreement is None else f"{agreement:.1e}")


def human(seconds: float) -> str:
    """A duration with a unit that keeps three significant digits (ns, µs, ms, s)."""
    for unit, scale in (("ns", 1e-9), ("µs", 1e-6), ("ms", 1e-3)):
        if seconds < 1000 * scale:
            return f"{seconds / scale:.3g} {unit}"
    return f"{seconds:.3g} s"


def columns(head, body) -> list[str]:
    """A text table: the head, a rule and the rows, each column as wide as its widest
    cell."""
    widths = [max(len(str(r[i])) for r in [head, *body]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return [fmt.format(*head).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()] + \
        [fmt.format(*r).rstrip() for r in body]
