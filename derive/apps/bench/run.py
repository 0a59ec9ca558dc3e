"""The whole benchmark: every case with every implementation, then batch throughput;
the result as one text table or JSON."""

from __future__ import annotations

import os
import platform
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ... import catalog
from ...build import STRICT_CFLAGS
from ...errors import ModelError
from ...generation import generate
from ...structure import find_blocks
from ..verify import relative_error
from . import generated
from .bars import BARS, REFERENCE
from .cases import CASES, Case, Skip, make_data, states
from .costs import compile_size, generation_scaling, schedule_scaling, startup
from .machine import python_floor
from .machine.bound import case_bound, case_schedule_bounds, memory_bound
from .machine.probe import measure_latencies
from .peers import casadi_c, libraries, navigation
from .throughput import batch, scaling
from .timing import Timing, columns, human, measure, timing_cells

IMPLEMENTATIONS: tuple[tuple[str, Callable, bool], ...] = (
    # (name, prepare(case, data, workdir), loop in C: long runs)
    ("generated C", generated.generated_c, True),
    ("generated Python", generated.generated_python, False),
    ("NumPy reference", libraries.numpy_reference, False),
    ("FilterPy", libraries.filterpy, False),
    ("pykalman", libraries.pykalman, False),
    ("CasADi C", casadi_c.casadi_c, True),
)


#: The row of the generated C in the latency schedule (time-varying filters).
LATENCY_SCHEDULE = "generated C, --latency-schedule"

#: The sections ``Settings.only`` (``derive bench --only``) can run alone: navigation (the
#: INS EKFs against their peers), catalog (the catalog's cases, the batch and every-core
#: rows, with their bars).
ONLY = ("navigation", "catalog")

@dataclass(frozen=True)
class Settings:
    c_steps: int = 100_000        # loop in C: enough steps to amortise the cffi call
    python_steps: int = 2_000     # loop in Python, linear cases
    nonlinear_python_steps: int = 500
    repeats: int = 7
    check_steps: int = 200        # agreement with derive's NumPy reference
    batch_tracks: int = batch.TRACKS
    batch_steps: int = batch.STEPS
    batch_repeats: int = 5
    scale_tracks: int = scaling.TRACKS   # derive.batch on every core; 0: left out
    scale_steps: int = scaling.STEPS
    scale_repeats: int = 3
    catalog_generation: bool = True   # time `derive generate --all` (the 30 s target)
    navigation_calls: int = 20_000    # ins_gnss EKF: calls per C loop (bench/peers/navigation.py)
    navigation_python_calls: int = 200   # ... per FilterPy timing
    navigation_symforce: bool = True  # ... SymForce's codegen of the same functions
    navigation_peer_calls: int = 200     # SymForce's C++ timed beside derive's (0: left out)
    navigation_peer_repeats: int = 60    # ... short windows, many repeats: their minimum
    only: str | None = None           # one section alone: "navigation" or "catalog" (ONLY)
    generation_scaling: bool = True   # large models: CV axes up to n = 240, dense 24 states
    compile_states: tuple[int, ...] = (16, 24)   # dense KFs generated and compiled
    startup_repeats: int = 5          # each `derive` start-up call; 0: left out
    schedule_axes: tuple[int, ...] = schedule_scaling.AXES   # both bounds of k CV axes
    schedule_dense: tuple[int, ...] = schedule_scaling.DENSE_STATES   # the search, dense KFs

    @classmethod
    def quick(cls) -> Settings:
        """Tiny counts, for tests: the same rows, meaningless times."""
        return cls(c_steps=300, python_steps=30, nonlinear_python_steps=20, repeats=2,
                   check_steps=20, batch_tracks=50, batch_steps=10, batch_repeats=2,
                   scale_tracks=2_000, scale_steps=10, scale_repeats=1,
                   catalog_generation=False, navigation_calls=200, navigation_python_calls=3,
                   navigation_symforce=False, navigation_peer_calls=0,
                   generation_scaling=False, compile_states=(3,), startup_repeats=1,
                   schedule_axes=(3,), schedule_dense=())


@dataclass(frozen=True)
class Row:
    case: str
    implementation: str
    timing: Timing | None
    ratio: float | None           # time per step / generated C's
    agreement: float | None       # max rel error of the states against the NumPy reference
    note: str = ""
    bound: float | None = None    # generated C: latency bound of the carried chain, s/step
    latency_bound: float | None = None   # the same in the latency schedule (time-varying)
    floor: float | None = None    # generated Python: its loop keeping nothing, s/step
    unequal: float | None = None  # generated Python: from a P0 whose blocks differ, s/step
    memory: float | None = None   # generated C: memory-traffic bound of its run, s/step

    @property
    def limit(self) -> tuple[float | None, str]:
        """The bound that applies, the larger of the chain's and the memory's, and which
        it is: a run cannot beat the bytes it must stream, whatever its chain."""
        if self.bound is None or self.memory is None or self.bound >= self.memory:
            return self.bound, "chain"
        return self.memory, "memory traffic"


@dataclass(frozen=True)
class BatchRow:
    implementation: str
    track_steps_per_second: float | None
    seconds: float | None
    ratio: float | None           # throughput / simdkalman's
    agreement: float | None
    note: str = ""


@dataclass
class BenchResult:
    settings: Settings
    machine: dict
    rows: list[Row] = field(default_factory=list)
    batch: list[BatchRow] = field(default_factory=list)
    generation_seconds: float | None = None
    scale: list[scaling.ScaleRow] = field(default_factory=list)   # derive.batch, every core
    navigation: navigation.NavigationResult | None = None
    generation: list[generation_scaling.GenerationRow] = field(default_factory=list)
    compile: list[compile_size.CompileRow] = field(default_factory=list)
    startup: list[startup.StartupRow] = field(default_factory=list)
    startup_load: tuple[float, float, float] | None = None   # load average before it
    schedule: list[schedule_scaling.ScheduleRow] = field(default_factory=list)

    def row(self, case: str, implementation: str) -> Row | None:
        return next((r for r in self.rows if r.case == case and r.implementation ==
                     implementation), None)

    def as_json(self) -> dict:
        return {"settings": asdict(self.settings), "machine": self.machine,
                "rows": [asdict(r) for r in self.rows], "batch": [asdict(b) for b in self.batch],
                "scale": [asdict(r) for r in self.scale],
                "generation_seconds": self.generation_seconds,
                "navigation": self.navigation.as_json() if self.navigation else None,
                "generation": [asdict(r) for r in self.generation],
                "compile": [asdict(r) for r in self.compile],
                "startup": [asdict(r) for r in self.startup], "startup_load": self.startup_load,
                "schedule": [asdict(r) for r in self.schedule],
                "bars": [asdict(b) for b in self.bars()]}

    def _seconds(self, case: str, implementation: str) -> float | None:
        r = self.row(case, implementation)
        return r.timing.median if r is not None and r.timing else None

    def bars(self) -> list[Bar]:
        """The performance targets (docs/performance.md), each with the measured value and
        whether it is met (with ``only``, that section's)."""
        if self.settings.only == "navigation":
            return self.navigation.bars(Bar) if self.navigation is not None else []
        out = []
        for peer, need in (("FilterPy", BARS["kf_c_over_filterpy"]),
                           ("CasADi C", BARS["kf_c_over_casadi"])):
            r = self.row("KF mpt3d_a", peer)
            value = r.ratio if r is not None and self._seconds("KF mpt3d_a", "generated C") \
                else None
            out.append(Bar(f"generated C KF mpt3d_a faster per step than {peer}", value, need,
                           "ratio"))
        b = next((x for x in self.batch if x.implementation == "generated C, run_tracks"),
                 None)
        out.append(Bar("batch throughput of generated C over simdkalman's",
                       b.ratio if b is not None else None, BARS["batch_over_simdkalman"],
                       "ratio"))
        kf = self.row("KF mpt3d_a", "generated C")
        out.append(Bar("generated C KF mpt3d_a per step", self._seconds("KF mpt3d_a",
                                                                        "generated C"),
                       BARS["kf_c_step"], "time", _bound_note(kf)))
        sskf = self.row("SSKF mpt3d_a", "generated C")
        fma2 = 2 * self.machine["latency"]["fma"] if self.machine.get("latency") else None
        out.append(Bar("generated C SSKF mpt3d_b x 3 axes in one loop (mpt3d_a, blocks found "
                       "automatically) per step", self._seconds("SSKF mpt3d_a", "generated C"),
                       BARS["sskf_c_step"], "time",
                       _bound_note(sskf) + ("" if fma2 is None else
                                            f"; two dependent fmas here take {human(fma2)}")))
        # issue 16's bar: the generated run of the three axes, one loop over all blocks
        # (mpt3d_a is mpt3d_b three times, composed); three runs of one axis beside it
        python = self.row("KF mpt3d_a", "generated Python")
        apart = self._seconds("KF mpt3d_b x 3", "generated Python")
        out.append(Bar("generated pure-Python KF mpt3d_b x 3 axes in one loop (mpt3d_a) per "
                       "step", self._seconds("KF mpt3d_a", "generated Python"),
                       BARS["kf_python_step"], "time",
                       "; ".join(part for part in (
                           _floor_note(python),
                           "" if python is None or python.unequal is None else
                           f"from a P0 whose blocks differ (the full loop) {human(python.unequal)}",
                           "" if apart is None else
                           f"three runs of one axis (KF mpt3d_b x 3) {human(apart)}") if part)))
        out += self._chain_bars()
        if self.settings.catalog_generation and self.generation_seconds is not None:
            out.append(Bar("generating the whole catalog (derive generate --all)",
                           self.generation_seconds, BARS["catalog_generation"], "time"))
        out += [Bar(*bar) for bar in generation_scaling.generation_bars(self.generation)]
        out += self._scaled_bars(fma2)
        if self.navigation is not None:
            out += self.navigation.bars(Bar)
        return out

    def _chain_bars(self) -> list[Bar]:
        """The time per step against the bound of the run derive emits by default (its
        chain's latency or its memory traffic, the larger), measured in this run; and the
        latency schedule's bound against the default's."""
        kf, sskf = self.row("KF mpt3d_a", "generated C"), self.row("SSKF mpt3d_a",
                                                                    "generated C")
        fast = self.row("KF mpt3d_a", LATENCY_SCHEDULE)
        out = []
        for row, need in ((kf, BARS["kf_over_bound"]), (sskf, BARS["sskf_over_bound"])):
            bound = row.limit[0] if row is not None else None
            # the fastest repeat: the bounds are the least times of their probes too, so a
            # moment of load does not count against the code
            out.append(Bar(f"generated C {row.case if row else '?'} per step (fastest "
                           f"repeat) within {need:g}x its bound here (the latency bound of its "
                           "chain, default schedule, or the memory traffic of its run, the "
                           "larger)", row.timing.low if bound and row.timing else None,
                           need * (bound or 0.0), "time", _limit_note(row)))
        default = kf.bound if kf is not None else None
        share = BARS["latency_schedule_share"]
        out.append(Bar("latency schedule (--latency-schedule): bound of the KF mpt3d_a chain "
                       f"within {share:g}x the default schedule's, same run",
                       kf.latency_bound if default else None, share * (default or 0.0), "time",
                       "" if fast is None or fast.timing is None else
                       f"it runs at {human(fast.timing.median)} per step, "
                       f"{fast.timing.median / fast.latency_bound:.2f}x its bound"))
        return out

    def _scaled_bars(self, fma2: float | None) -> list[Bar]:
        """The time targets restated for this machine through their own reference
        points measured in this run: CasADi's C for the KF step (about 48 ns where the
        bars were set), two dependent fmas for the SSKF (the bar's definition), FilterPy's
        KF step (about 17 µs) for the pure-Python KF."""
        out = []
        casadi = self._seconds("KF mpt3d_a", "CasADi C")
        if casadi is not None:
            where = REFERENCE["casadi_kf_step"]
            out.append(Bar(f"scaled: generated C KF mpt3d_a per step, bar "
                           f"{human(BARS['kf_c_step'])} x CasADi's {human(casadi)} here / its "
                           f"{human(where)} where the bar was set",
                           self._seconds("KF mpt3d_a", "generated C"),
                           BARS["kf_c_step"] * casadi / where, "time"))
        if fma2 is not None:
            over = BARS["sskf_over_two_fmas"]
            out.append(Bar("scaled: generated C SSKF mpt3d_a per step, within "
                           f"{round(100 * (over - 1)):d}% of two dependent fmas here "
                           f"({human(fma2)})",
                           self._seconds("SSKF mpt3d_a", "generated C"), over * fma2, "time"))
        filterpy = self._seconds("KF mpt3d_a", "FilterPy")
        if filterpy is not None:
            bar, where = BARS["kf_python_step_scaled"], REFERENCE["filterpy_kf_step"]
            out.append(Bar(f"scaled: generated pure-Python KF mpt3d_b x 3 per step, bar "
                           f"{human(bar)} x FilterPy's {human(filterpy)} here / its "
                           f"{human(where)} where the bar was set",
                           self._seconds("KF mpt3d_b x 3", "generated Python"),
                           bar * filterpy / where, "time"))
        return out

    def text(self) -> str:
        s = self.settings
        lines = [
            "derive bench: time per filter step, median of "
            f"{s.repeats} repeats (min-max); ratio = time / generated C's time (same case)",
            f"machine: {self.machine['cpu']}, {self.machine['cores']} cores, load average "
            f"{self.machine['load']} at start; Python {self.machine['python']}, NumPy "
            f"{self.machine['numpy']}",
            f"generated C: gcc {' '.join(self.machine['generated_cflags'])} through cffi, the "
            f"run loop in C, {s.c_steps:,} steps per run; CasADi C: casadi "
            f"{self.machine.get('casadi', '?')} CodeGenerator, a C loop, gcc "
            f"{' '.join(casadi_c.CFLAGS)}, {s.c_steps:,} steps",
            f"Python loops (generated Python, NumPy reference, FilterPy, pykalman): "
            f"{s.python_steps:,} steps (EKF/UKF {s.nonlinear_python_steps:,}); 'agrees': max "
            f"rel error of the states against derive's NumPy reference over {s.check_steps} "
            "steps",
            ""]
        if s.only == "navigation":
            return "\n".join(lines[:2] + [""] + (self.navigation.lines() if self.navigation
                                                 else []) + [bar.text() for bar in self.bars()])
        head = ("case", "implementation", "per step", "min-max", "ratio", "agrees", "note")
        body = []
        for r in self.rows:
            body.append((r.case, r.implementation,
                         *timing_cells(r.timing, r.ratio, r.agreement), r.note))
        lines += _columns(head, body)
        lines += ["", f"batch: {s.batch_tracks:,} independent tracks x {s.batch_steps} steps of "
                      f"{batch.MODEL} (KF), median of {s.batch_repeats} runs; ratio = "
                      "throughput / simdkalman's", ""]
        head = ("implementation", "track-steps/s", "time per run", "ratio", "agrees", "note")
        body = [(b.implementation,
                 "skipped" if b.track_steps_per_second is None else
                 f"{b.track_steps_per_second:,.3g}",
                 "" if b.seconds is None else human(b.seconds),
                 "" if b.ratio is None else f"{b.ratio:,.1f}x",
                 "" if b.agreement is None else f"{b.agreement:.1e}", b.note)
                for b in self.batch]
        lines += _columns(head, body)
        lines.append("")
        if self.scale:
            lines += [f"every core: derive.batch.run_tracks, {s.scale_tracks:,} tracks x "
                      f"{s.scale_steps} steps of {batch.MODEL} (KF, no covariances stored), "
                      f"median of {s.scale_repeats} runs; threads split the NumPy arrays, "
                      "Dask runs a LocalCluster of worker processes (1 thread each); "
                      "'bitwise': equal to the threaded result", ""]
            head, body, scaled = scaling.scaling_table(self.scale)
            lines += _columns(head, body) + scaled + [""]
        if self.navigation is not None:
            lines += self.navigation.lines() + [""]
        if self.generation:
            lines += ["generation of large models (derive.apps.bench.costs.generation_scaling): "
                      "one process each, the model built through the Python API, then "
                      "render_unit (derive and render Python and C, nothing written)", ""]
            lines += _columns(*generation_scaling.generation_table(self.generation)) + [""]
        if self.schedule:
            lines += ["both bounds of large KFs (derive.apps.bench.costs.schedule_scaling): k CV "
                      "axes, carried chain per step in reference cycles; CPU seconds of the "
                      "latency schedule's search and of both bounds (derive burden's); "
                      "dense random KFs: the search only", ""]
            lines += _columns(*schedule_scaling.schedule_table(self.schedule)) + [""]
        if self.compile:
            head, body, compile_bars = compile_size.compile_table(self.compile)
            lines += ["files that compile in seconds: a dense random KF generated (a child "
                      "process), then compiled (gcc and derive.build's strict flags); wall "
                      "and CPU seconds, peak memory of each", ""]
            lines += _columns(head, body) + compile_bars + [""]
        if self.startup:
            lines += [f"start-up of the command line (derive.apps.bench.costs.startup): a fresh "
                      f"`python -m derive` per call, least wall and CPU time of "
                      f"{s.startup_repeats} runs taken in turns; load average "
                      f"{self.startup_load} before it", ""]
            lines += _columns(*startup.startup_table(self.startup)) + [""]
        lat = self.machine.get("latency")
        if lat:
            lines.append("latency of one dependent operation here "
                         "(derive.apps.bench.machine.probe): " +
                         ", ".join(f"{k} {human(v)}" for k, v in lat.items()))
        lines += [bar.text() for bar in self.bars()]
        return "\n".join(lines)


@dataclass(frozen=True)
class Bar:
    """A performance target: a ratio to reach (``>=``) or a time to stay under (``<=``)."""

    claim: str
    value: float | None
    bar: float
    kind: str                     # "ratio" (>=), "share" (a ratio, <=) or "time" (s, <=)
    note: str = ""

    @property
    def met(self) -> bool | None:
        if self.value is None:
            return None
        return self.value >= self.bar if self.kind == "ratio" else self.value <= self.bar

    def text(self) -> str:
        verdict = "n/a" if self.met is None else ("met" if self.met else "NOT met")
        if self.kind == "ratio":
            shown = "n/a" if self.value is None else f"{self.value:,.1f}x"
            need = f">= {self.bar:g}x"
        elif self.kind == "share":
            shown = "n/a" if self.value is None else f"{self.value:.2f}x"
            need = f"<= {self.bar:g}x"
        else:
            shown = "n/a" if self.value is None else human(self.value)
            need = f"<= {human(self.bar)}"
        note = f"; {self.note}" if self.note else ""
        return f"bar: {self.claim}: {shown} ({need}: {verdict}){note}"


def _floor_note(row: Row | None) -> str:
    if row is None or row.floor is None:
        return ""
    return (f"the same loop keeping nothing (its float operations, checks and iteration "
            f"alone) here {human(row.floor)}")


def _limit_note(row: Row | None) -> str:
    """Both bounds of a generated C row and which applies."""
    if row is None or row.bound is None:
        return "no bound measured"
    if row.memory is None:
        return f"chain bound {human(row.bound)}"
    return (f"chain bound {human(row.bound)}, memory-traffic bound {human(row.memory)}: "
            f"the {row.limit[1]} applies")


def _bound_note(row: Row | None) -> str:
    if row is None or row.bound is None:
        return ""
    return f"latency bound of its carried chain here {human(row.bound)}"


def _columns(head, body) -> list[str]:
    return columns(head, body)


def machine_info() -> dict:
    info = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "load": "n/a", "python": platform.python_version(), "numpy": np.__version__,
            "generated_cflags": list(STRICT_CFLAGS) + list(generated.CFLAGS)}
    try:
        info["latency"] = measure_latencies(generated.CFLAGS)
    except Exception as exc:  # no compiler or cffi failure: the bounds are left out
        info["latency"] = {}
        info["latency_error"] = str(exc).splitlines()[0][:200]
    try:
        info["load"] = f"{os.getloadavg()[0]:.2f}"
    except OSError:
        pass
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            name = next((line.split(":", 1)[1].strip() for line in f
                         if line.startswith("model name")), None)
        info["cpu"] = name or info["cpu"]
    except OSError:
        pass
    try:
        import casadi

        info["casadi"] = casadi.__version__
    except ImportError:
        pass
    return info


def _case_rows(case: Case, s: Settings, workdir: Path, tick, latency=None) -> list[Row]:
    python_steps = s.nonlinear_python_steps if case.nonlinear else s.python_steps
    data = make_data(case, max(s.c_steps, python_steps, s.check_steps))
    reference = states(libraries.numpy_reference(case, data)(s.check_steps), s.check_steps)
    rows, base = [], None
    for name, prepare, in_c in IMPLEMENTATIONS:
        tick(f"{case.label}: {name}")
        try:
            run = prepare(case, data, workdir)
        except Skip as exc:
            rows.append(Row(case.label, name, None, None, None, f"skipped: {exc}"))
            continue
        agreement = relative_error(states(run(s.check_steps), s.check_steps), reference)
        steps = s.c_steps if in_c else python_steps
        timing = measure(lambda run=run, steps=steps: run(steps), steps, s.repeats)
        if name == "generated C":
            base = timing.median
        note = _NOTES.get((case.filter, name), "")
        bound = fast = floor = unequal = memory = None
        if name == "generated Python":
            floor = _python_floor(case, data, workdir, steps, s.repeats)
            if floor is not None:
                note = (note + "; " if note else "") + \
                    f"the loop keeping nothing: {human(floor)}"
            unequal = _python_unequal_start(case, data, workdir, steps, s.repeats)
            if unequal is not None:
                note = (note + "; " if note else "") + \
                    f"from a P0 whose blocks differ (the full loop): {human(unequal)}"
        if name == "generated C" and latency:
            found = case_bound(case, latency)
            if found is not None:
                bound = found[0]
                note = f"latency bound {human(bound)}: carried chain {found[1]}"
            traffic = _memory_bound(data, steps, s.repeats, case.copies)
            memory = traffic.per_step
            note += (f"; memory-traffic bound {human(memory)} ({traffic.describe()}): the "
                     f"{'chain' if bound is None or bound >= memory else 'memory'}'s applies")
            both = case_schedule_bounds(case, latency)
            if both.latency is not None:
                fast = both.latency.per_step * case.copies
                note += (f"; latency schedule's bound {human(fast)} "
                         f"({both.latency.describe()}, {both.flops_added:+d} flops a copy)")
        rows.append(Row(case.label, name, timing, None if base is None else
                        timing.median / base, agreement, note, bound, fast, floor, unequal,
                        memory))
        if fast is not None:
            rows.append(_latency_schedule_row(case, data, workdir, s, reference, base, fast))
    return rows


def _memory_bound(data, steps: int, repeats: int, copies: int):
    """The memory-traffic bound of the generated C run of ``data``: per step it reads z
    (and u) and writes x, covariances not stored."""
    read = data.zs[0].shape[1] + (0 if data.us is None else data.us.shape[1])
    return memory_bound(read, len(data.x0), steps, repeats, copies, generated.CFLAGS)


def _python_floor(case: Case, data, workdir: Path, steps: int, repeats: int) -> float | None:
    """Seconds per step of the generated Python's single-track loop keeping nothing
    (derive.apps.bench.machine.python_floor), timed as the generated Python row; None without
    such a loop."""
    try:
        run = python_floor.python_floor(case, data, workdir)
    except Skip:
        return None
    return measure(lambda: run(steps), steps, repeats).median


def _python_unequal_start(case: Case, data, workdir: Path, steps: int, repeats: int
                          ) -> float | None:
    """Seconds per step of the generated Python from the case's P0 with a different number
    added to each diagonal entry, so no two blocks start equal and the single-track run
    takes its full loop (derive.runs.shared); None for a case without P0 or whose
    model is one block (the runners pass P0 to the KF's run)."""
    if case.nonlinear or case.filter != "kf":
        return None
    try:
        if len(find_blocks(data.model)) < 2:
            return None
    except ModelError:
        return None
    n = len(data.x0)
    P0 = data.P0 + np.diag(1e-3 * np.arange(1, n + 1))
    run = generated.generated_python(case, replace(data, P0=P0), workdir)
    return measure(lambda: run(steps), steps, repeats).median


def _latency_schedule_row(case: Case, data, workdir: Path, s: Settings, reference,
                          base: float | None, fast: float) -> Row:
    """The generated C in the latency schedule (``--latency-schedule``), timed as the
    default's."""
    run = generated.generated_c_latency_schedule(case, data, workdir)
    agreement = relative_error(states(run(s.check_steps), s.check_steps), reference)
    timing = measure(lambda: run(s.c_steps), s.c_steps, s.repeats)
    return Row(case.label, LATENCY_SCHEDULE, timing, None if base is None else
               timing.median / base, agreement, f"its latency bound {human(fast)}", fast,
               fast)


_NOTES = {
    ("ukf", "FilterPy"): "updates with the predicted sigma points (spread P, not P + Q)",
    ("kf", "pykalman"): "whole-series filter(); starts from x(1/0)",
    ("kf", "CasADi C"): "dense P, symbolic inverse of S",
    ("ekf", "CasADi C"): "dense P, symbolic Jacobian and inverse",
    ("ukf", "CasADi C"): "dense P, symbolic Cholesky and inverse",
}


def _batch_rows(s: Settings, workdir: Path, tick) -> list[BatchRow]:
    b = batch.make_batch(s.batch_tracks, s.batch_steps)
    check = sorted({0, 1, s.batch_tracks - 1} & set(range(s.batch_tracks)))  # the last may
    reference = {t: batch.batch_reference(b, t) for t in check}      # be in a partial block
    impls = (("generated C, run_tracks", lambda: batch.generated_c_tracks(b, workdir)),
             ("generated C, run_tracks, covariances stored",
              lambda: batch.generated_c_tracks(b, workdir, with_covariance=True)),
             (f"generated C, step, {batch.INTERLEAVE} tracks interleaved",
              lambda: batch.generated_c(b, workdir, "batch_step")),
             ("generated C, run per track", lambda: batch.generated_c(b, workdir, "batch_run")),
             ("generated Python (NumPy arrays)", lambda: batch.generated_python(b, workdir)),
             ("vectorised NumPy KF", lambda: (lambda: batch.numpy_kf(b))),
             ("simdkalman", lambda: batch.simdkalman_kf(b)))
    rows = []
    bandwidth = batch.copy_bandwidth()
    for name, prepare in impls:
        tick(f"batch: {name}")
        try:
            run = prepare()
        except Skip as exc:
            rows.append(BatchRow(name, None, None, None, None, f"skipped: {exc}"))
            continue
        out = np.asarray(run())
        agreement = max(relative_error(out[t], reference[t]) for t in check)
        timing = measure(run, 1, s.batch_repeats)
        rows.append(BatchRow(name, b.track_steps / timing.median, timing.median, None,
                             agreement, _traffic_note(b, name, bandwidth)))
    simd = next((r for r in rows if r.implementation == "simdkalman"
                 and r.track_steps_per_second), None)
    return [BatchRow(r.implementation, r.track_steps_per_second, r.seconds,
                     None if simd is None or r.track_steps_per_second is None else
                     r.track_steps_per_second / simd.track_steps_per_second, r.agreement,
                     r.note) for r in rows]


def _traffic_note(b: batch.Batch, name: str, bandwidth: float) -> str:
    """For run_tracks: the memory-traffic bound, this machine's copy bandwidth over the
    bytes a track-step moves (with or without its covariance)."""
    if not name.startswith("generated C, run_tracks"):
        return ""
    stored = "covariances stored" in name
    per = batch.track_step_bytes(b, stored)
    return (f"memory-traffic bound {bandwidth / per:,.3g} track-steps/s ({per} bytes a "
            f"track-step at {bandwidth / 1e9:.1f} GB/s, a NumPy copy here)")


def run_bench(settings: Settings | None = None, progress=None) -> BenchResult:
    """Measure every case and the batch; ``progress(text)`` is called before each part."""
    s = settings or Settings()
    tick = progress or (lambda text: None)
    result = BenchResult(s, machine_info())
    with tempfile.TemporaryDirectory(prefix="derive-bench-") as tmp:
        if s.only == "navigation":
            result.navigation = _navigation(s, Path(tmp), tick)
            return result
        for case in CASES:
            result.rows += _case_rows(case, s, Path(tmp), tick, result.machine.get("latency"))
        result.batch = _batch_rows(s, Path(tmp), tick)
        if s.scale_tracks:
            result.scale = scaling.scaling_rows(s.scale_tracks, s.scale_steps, Path(tmp),
                                                  s.scale_repeats, tick)
        if s.only == "catalog":
            return result
        result.navigation = _navigation(s, Path(tmp), tick)
        if s.generation_scaling:
            result.generation = generation_scaling.generation_rows(tick=tick)
        result.compile = compile_size.compile_rows(s.compile_states, Path(tmp), tick)
        if s.startup_repeats:
            tick("start-up of the command line")
            result.startup_load = os.getloadavg()
            result.startup = startup.startup_rows(s.startup_repeats, Path(tmp))
        result.schedule = schedule_scaling.schedule_rows(s.schedule_axes, tick=tick) + \
            schedule_scaling.dense_rows(s.schedule_dense, tick=tick)
        if s.catalog_generation:
            tick("derive generate --all")
            result.generation_seconds = time_catalog_generation(Path(tmp) / "catalog")
    return result


def _navigation(s: Settings, tmp: Path, tick) -> navigation.NavigationResult:
    return navigation.run_navigation(tmp / "navigation", s.navigation_calls,
                                     s.navigation_python_calls, s.repeats,
                                     s.navigation_symforce, tick, s.navigation_peer_calls,
                                     s.navigation_peer_repeats)


def time_catalog_generation(out: Path) -> float:
    """Seconds that generating the catalog takes (what ``derive generate --all --out OUT``
    writes), in this process."""
    start = time.perf_counter()
    for name in catalog.names():
        generate(name, None, "all", out)
    return time.perf_counter() - start
