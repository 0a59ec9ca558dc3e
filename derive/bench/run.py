"""The whole benchmark: every case with every implementation, then batch throughput;
the result as one text table or JSON."""

from __future__ import annotations

import os
import platform
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import batch, casadi_c, generated, peers
from .cases import CASES, Case, Skip, make_data, states
from .timing import Timing, human, measure

IMPLEMENTATIONS: tuple[tuple[str, Callable, bool], ...] = (
    # (name, prepare(case, data, workdir), loop in C: long runs)
    ("generated C", generated.generated_c, True),
    ("generated Python", generated.generated_python, False),
    ("NumPy reference", peers.numpy_reference, False),
    ("FilterPy", peers.filterpy, False),
    ("pykalman", peers.pykalman, False),
    ("CasADi C", casadi_c.casadi_c, True),
)


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

    @classmethod
    def quick(cls) -> Settings:
        """Tiny counts, for tests: the same rows, meaningless times."""
        return cls(c_steps=300, python_steps=30, nonlinear_python_steps=20, repeats=2,
                   check_steps=20, batch_tracks=50, batch_steps=10, batch_repeats=2)


@dataclass(frozen=True)
class Row:
    case: str
    implementation: str
    timing: Timing | None
    ratio: float | None           # time per step / generated C's
    agreement: float | None       # max rel error of the states against the NumPy reference
    note: str = ""


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

    def row(self, case: str, implementation: str) -> Row | None:
        return next((r for r in self.rows if r.case == case and r.implementation ==
                     implementation), None)

    def as_json(self) -> dict:
        return {"settings": asdict(self.settings), "machine": self.machine,
                "rows": [asdict(r) for r in self.rows], "batch": [asdict(b) for b in self.batch],
                "bars": [dict(zip(("claim", "value", "bar", "met"), b)) for b in self.bars()]}

    def bars(self) -> list[tuple[str, float | None, float, bool | None]]:
        """The issue's bars: (claim, measured ratio, required ratio, met)."""
        out = []
        kf = self.row("KF mpt3d_a", "generated C")
        for peer, need in (("FilterPy", 1000.0), ("CasADi C", 4.0)):
            r = self.row("KF mpt3d_a", peer)
            value = r.ratio if r is not None and kf is not None and kf.timing else None
            out.append((f"generated C KF mpt3d_a faster per step than {peer}", value, need,
                        None if value is None else value >= need))
        b = next((x for x in self.batch if x.implementation == "generated C, run_tracks"),
                 None)
        value = b.ratio if b is not None else None
        out.append(("batch throughput of generated C over simdkalman's", value, 50.0,
                    None if value is None else value >= 50.0))
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
        head = ("case", "implementation", "per step", "min-max", "ratio", "agrees", "note")
        body = []
        for r in self.rows:
            t = r.timing
            body.append((r.case, r.implementation, human(t.median) if t else "skipped",
                         f"{human(t.low)}-{human(t.high)}" if t else "",
                         "" if r.ratio is None else f"{r.ratio:,.1f}x",
                         "" if r.agreement is None else f"{r.agreement:.1e}", r.note))
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
        for claim, value, need, met in self.bars():
            verdict = "n/a" if met is None else ("met" if met else "NOT met")
            shown = "n/a" if value is None else f"{value:,.1f}x"
            lines.append(f"bar: {claim}: {shown} (>= {need:g}x: {verdict})")
        return "\n".join(lines)


def _columns(head, body) -> list[str]:
    widths = [max(len(str(r[i])) for r in [head, *body]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return [fmt.format(*head).rstrip(), fmt.format(*("-" * w for w in widths)).rstrip()] + \
        [fmt.format(*r).rstrip() for r in body]


def machine_info() -> dict:
    from ..build import STRICT_CFLAGS

    info = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "load": "n/a", "python": platform.python_version(), "numpy": np.__version__,
            "generated_cflags": list(STRICT_CFLAGS) + list(generated.CFLAGS)}
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


def _case_rows(case: Case, s: Settings, workdir: Path, tick) -> list[Row]:
    from ..verify import relative_error

    python_steps = s.nonlinear_python_steps if case.nonlinear else s.python_steps
    data = make_data(case, max(s.c_steps, python_steps, s.check_steps))
    reference = states(peers.numpy_reference(case, data)(s.check_steps), s.check_steps)
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
        rows.append(Row(case.label, name, timing, None if base is None else
                        timing.median / base, agreement, note))
    return rows


_NOTES = {
    ("ukf", "FilterPy"): "updates with the predicted sigma points (spread P, not P + Q)",
    ("kf", "pykalman"): "whole-series filter(); starts from x(1/0)",
    ("kf", "CasADi C"): "dense P, symbolic inverse of S",
    ("ekf", "CasADi C"): "dense P, symbolic Jacobian and inverse",
    ("ukf", "CasADi C"): "dense P, symbolic Cholesky and inverse",
}


def _batch_rows(s: Settings, workdir: Path, tick) -> list[BatchRow]:
    from ..verify import relative_error

    b = batch.make_batch(s.batch_tracks, s.batch_steps)
    check = sorted({0, 1, s.batch_tracks - 1} & set(range(s.batch_tracks)))  # the last may
    reference = {t: batch.batch_reference(b, t) for t in check}      # be in a partial block
    impls = (("generated C, run_tracks", lambda: batch.generated_c_tracks(b, workdir)),
             (f"generated C, step, {batch.INTERLEAVE} tracks interleaved",
              lambda: batch.generated_c(b, workdir, "batch_step")),
             ("generated C, run per track", lambda: batch.generated_c(b, workdir, "batch_run")),
             ("generated Python (NumPy arrays)", lambda: batch.generated_python(b, workdir)),
             ("vectorised NumPy KF", lambda: (lambda: batch.numpy_kf(b))),
             ("simdkalman", lambda: batch.simdkalman_kf(b)))
    rows = []
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
                             agreement))
    simd = next((r for r in rows if r.implementation == "simdkalman"
                 and r.track_steps_per_second), None)
    return [BatchRow(r.implementation, r.track_steps_per_second, r.seconds,
                     None if simd is None or r.track_steps_per_second is None else
                     r.track_steps_per_second / simd.track_steps_per_second, r.agreement,
                     r.note) for r in rows]


def run_bench(settings: Settings | None = None, progress=None) -> BenchResult:
    """Measure every case and the batch; ``progress(text)`` is called before each part."""
    s = settings or Settings()
    tick = progress or (lambda text: None)
    result = BenchResult(s, machine_info())
    with tempfile.TemporaryDirectory(prefix="derive-bench-") as tmp:
        for case in CASES:
            result.rows += _case_rows(case, s, Path(tmp), tick)
        result.batch = _batch_rows(s, Path(tmp), tick)
    return result
