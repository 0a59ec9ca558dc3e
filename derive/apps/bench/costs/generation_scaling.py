"""Generation time of large models: k independent constant-velocity axes (n = 2k, block
diagonal) for kf, lf and sskf, and a dense random 24-state KF (m = 8).

Each generation runs in its own Python process, which builds the model through the
Python API and times :func:`derive.generation.render_unit` (derivation and rendering of
both languages, nothing written); its peak resident memory is read by
:mod:`.child_usage` (a small launcher, so the bench's own memory does not count).
Times are wall-clock and CPU (user + system of the generation), since the machine may
be shared: CPU time is what the work costs, wall time what a user waits.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from ..bars import BARS
from .child_usage import run_measured

AXES = (15, 30, 60, 120)
"""Constant-velocity axes per model: n = 30, 60, 120, 240."""
FILTERS = ("kf", "lf", "sskf")
AXIS_MODEL = "mpt3d_b"
"""The catalog's constant-velocity axis (position measured)."""
DENSE_STATES, DENSE_MEASUREMENTS, DENSE_SEED = 24, 8, 24
AXES_BAR = BARS["axes_generation"]     # seconds, 120 axes, each of kf, lf, sskf
DENSE_BAR = BARS["dense_generation"]    # seconds, the dense 24-state KF
DENSE_MEMORY_BAR = BARS["dense_generation_bytes"]   # bytes
TIMEOUT = 1800.0    # seconds, a hang guard per generation

_CHILD = r"""
import json, os, sys, time
from derive import LinearModel, catalog
from derive.apps.bench.costs.compile_size import dense_model
from derive.flops import count
from derive.generation import render_unit

kind, size, name = sys.argv[1], int(sys.argv[2]), sys.argv[3]
if kind == "axes":
    axis = catalog.load(sys.argv[4])
    model = LinearModel.compose(f"cv{size}", [axis] * size, [f"_{i}" for i in range(size)])
else:
    model = dense_model(size, int(sys.argv[4]), int(sys.argv[5]))
def cpu_seconds():   # this process's and its finished children's (a background rendering)
    usage = os.times()
    return usage.user + usage.system + usage.children_user + usage.children_system
wall, cpu = time.perf_counter(), cpu_seconds()
unit, files = render_unit(model, name, "all")
wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
flops = count(unit.programs["step"], "c").flops
print(json.dumps({"n": model.n, "seconds": wall, "cpu_seconds": cpu, "flops": flops,
                  "bytes": sum(len(t) for t in files.values())}))
"""


@dataclass(frozen=True)
class GenerationRow:
    model: str                    # "120 CV axes", "dense random"
    filter: str
    states: int
    seconds: float | None         # wall-clock of the generation
    cpu_seconds: float | None
    peak_bytes: int | None        # peak resident memory of the whole process
    flops: int | None             # of the generated step (C, fma = 2)
    note: str = ""

    @property
    def ms_per_flop(self) -> float | None:
        if not self.cpu_seconds or not self.flops:
            return None
        return 1000 * self.cpu_seconds / self.flops


def _run(args: list[str], label: str, name: str, timeout: float) -> GenerationRow:
    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}
    env.pop("DERIVE_PROGRESS", None)
    try:
        usage = run_measured([sys.executable, "-c", _CHILD, *args], timeout, env)
    except TimeoutError:
        return GenerationRow(label, name, 0, None, None, None, None,
                             f"stopped after {timeout:.0f} s")
    if usage.returncode != 0:
        last = (usage.stderr.strip().splitlines() or ["no output"])[-1]
        return GenerationRow(label, name, 0, None, None, None, None, f"failed: {last}")
    result = json.loads(usage.stdout.strip().splitlines()[-1])
    return GenerationRow(label, name, result["n"], result["seconds"], result["cpu_seconds"],
                         int(usage.peak_bytes), result["flops"])


def generation_rows(axes=AXES, filters=FILTERS, dense: bool = True, tick=lambda text: None,
                    timeout: float = TIMEOUT) -> list[GenerationRow]:
    """kf, lf, sskf for each number of axes, then the dense 24-state KF."""
    rows = []
    for k in axes:
        for name in filters:
            tick(f"generation: {name}, {k} constant-velocity axes")
            rows.append(_run(["axes", str(k), name, AXIS_MODEL], f"{k} CV axes", name,
                             timeout))
    if dense:
        tick(f"generation: kf, dense random {DENSE_STATES} states")
        rows.append(_run(["dense", str(DENSE_STATES), "kf", str(DENSE_MEASUREMENTS),
                          str(DENSE_SEED)], f"dense random (m = {DENSE_MEASUREMENTS})", "kf",
                         timeout))
    return rows


def _mb(value: int | None) -> str:
    return "" if value is None else f"{value / 2**20:,.0f} MB"


def generation_table(rows: list[GenerationRow]) -> tuple[tuple, list[tuple]]:
    head = ("model", "filter", "n", "wall", "CPU", "peak memory", "flops", "CPU per flop",
            "note")
    body = [(r.model, r.filter, str(r.states) if r.states else "",
             "" if r.seconds is None else f"{r.seconds:.2f} s",
             "" if r.cpu_seconds is None else f"{r.cpu_seconds:.2f} s",
             _mb(r.peak_bytes), "" if r.flops is None else f"{r.flops:,}",
             "" if r.ms_per_flop is None else f"{r.ms_per_flop:.3f} ms", r.note)
            for r in rows]
    return head, body


def generation_bars(rows: list[GenerationRow]) -> list[tuple[str, float | None, float, str, str]]:
    """(claim, value, bar, kind, note) of the generation targets, for derive.apps.bench.run."""
    out = []
    largest = max((int(r.model.split()[0]) for r in rows if r.model.endswith("CV axes")),
                  default=None)
    for name in FILTERS:
        row = next((r for r in rows if r.filter == name and largest is not None
                    and r.model == f"{largest} CV axes"), None)
        if row is None:
            continue
        out.append((f"generating {name} for {largest} constant-velocity axes (n = "
                    f"{row.states}), wall-clock", row.seconds, AXES_BAR, "time",
                    "" if row.cpu_seconds is None else f"CPU {row.cpu_seconds:.2f} s"))
    dense = next((r for r in rows if r.model.startswith("dense")), None)
    if dense is not None:
        memory = ("n/a" if dense.peak_bytes is None else
                  "met" if dense.peak_bytes <= DENSE_MEMORY_BAR else "NOT met")
        per_flop = ("" if dense.ms_per_flop is None else
                    f"; CPU per emitted flop {dense.ms_per_flop:.3f} ms")
        out.append((f"generating the KF of a dense random {DENSE_STATES}-state model, "
                    "wall-clock", dense.seconds, DENSE_BAR, "time",
                    f"peak memory {_mb(dense.peak_bytes)} (<= {_mb(DENSE_MEMORY_BAR)}: "
                    f"{memory}){per_flop}"))
    return out


__all__ = ["AXES", "FILTERS", "GenerationRow", "generation_bars", "generation_rows",
           "generation_table"]
