"""The main job behind ``derive reproduce``: generate, verify, run the papers'
experiments and write the report, reporting progress stage by stage."""

from __future__ import annotations

import multiprocessing
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from ... import catalog
from . import (
    burden,
    error_state,
    generation,
    gnss,
    mdkf,
    navigation,
    page,
    provenance,
    sizes,
    sspred,
    tracking,
)
from .burden import compute_audit
from .context import Context
from .document import Section
from .generation import GenerationResult


@dataclass
class ReportResult:
    out: Path
    generated: Path | None        # None: a scratch directory, removed at the end
    sections: list[Section] = field(default_factory=list)
    generation: GenerationResult = field(default_factory=GenerationResult)
    seconds: float = 0.0
    stage_seconds: dict[str, float] = field(default_factory=dict)
    index: Path | None = None
    page: Path | None = None
    results: list[Path] = field(default_factory=list)   # results.md and its copies

    @property
    def figures(self) -> int:
        return sum(len(s.figures) for s in self.sections)

    @property
    def tables(self) -> int:
        return sum(len(s.tables) for s in self.sections)

    @property
    def todos(self) -> list[str]:
        return [f"{s.title}: {t.text}" for s in self.sections for t in s.todos]

    @property
    def failures(self) -> list[str]:
        return self.generation.failures

    def summary(self) -> str:
        g = self.generation
        where = str(self.generated) if self.generated else "a scratch directory (removed)"
        lines = [
            f"derive reproduce: {'FAILED' if self.failures else 'done'} in "
            f"{self.seconds:.1f} s",
            f"  generated : {g.filters} filters of {len(g.models)} catalog models, "
            f"{len(g.files)} files, in {where}",
            f"  verified  : {len(g.verifications)} runs (generated Python and C against the "
            f"NumPy reference), max rel error {g.max_error:.1e}, "
            f"{sum(not v.passed for v in g.verifications)} failed",
            f"  jacobians : {witness_text(g.witnesses)}",
            f"  checks    : {len(g.checks)} equivalence claims measured, "
            f"{sum(not c.passed for c in g.checks)} failed",
            f"  report    : {self.page} (and {self.index.name}), {self.figures} figures, "
            f"{self.tables} tables",
            f"  papers    : {page.tally_text(self.sections)}",
            f"  results   : {', '.join(str(p) for p in self.results)}",
        ]
        lines.append("  time      : " + ", ".join(f"{k} {v:.0f} s"
                                                for k, v in self.stage_seconds.items()))
        if self.todos:
            lines.append(f"  TODO      : {len(self.todos)} item(s) for the lead, marked in the "
                         "report")
        lines += [f"  FAIL      : {line}" for line in self.failures[:10]]
        return "\n".join(lines)


def witness_text(witnesses: list) -> str:
    """The summary's line on the CasADi Jacobian witnesses."""
    if not witnesses:
        return "no nonlinear model"
    skipped = [w for w in witnesses if w.check is None]
    if skipped:
        return f"CasADi witness skipped for {len(skipped)} model(s): {skipped[0].skipped}"
    failed = sum(not w.passed for w in witnesses)
    return (f"{len(witnesses)} nonlinear model(s) against CasADi's automatic "
            f"differentiation, {failed} failed")


class _Progress:
    """A rich progress bar on stderr, or plain lines when rich is not installed."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.done, self.bar = total, 0, None
        self.enabled = enabled
        self.current: str | None = None
        self.since = time.perf_counter()
        self.seconds: dict[str, float] = {}
        if not enabled:
            return
        try:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
        except ImportError:
            return
        self.bar = Progress(TextColumn("{task.description:<44}"), BarColumn(),
                            TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(),
                            console=Console(stderr=True), transient=False)
        self.task = self.bar.add_task("starting", total=total)
        self.bar.start()

    def stage(self, text: str, key: str | None = None) -> None:
        """Show ``text``; time spent until the next stage is added to ``key`` (text)."""
        now = time.perf_counter()
        if self.current is not None:
            self.seconds[self.current] = self.seconds.get(self.current, 0.0) + now - self.since
        self.current, self.since = key or text, now
        if self.bar is not None:
            self.bar.update(self.task, description=text)
        elif self.enabled:
            print(f"[{self.done}/{self.total}] {text}", file=sys.stderr, flush=True)

    def advance(self) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(self.task, advance=1)

    def close(self) -> None:
        self.stage("done", "")
        self.seconds.pop("", None)
        if self.bar is not None:
            self.bar.stop()


TITLE = "derive: the papers reproduced"


def _sections() -> list[tuple[str, Callable[[Context], Section]]]:
    return ([(f"experiments: {p.label}", lambda ctx, p=p: tracking.section(ctx, p))
             for p in tracking.PAPERS]
            + [("experiments: SSPRED", sspred.section), ("experiments: MDKF", mdkf.section),
               ("experiments: GNSS", gnss.section),
               ("experiments: INS/GNSS", navigation.section),
               ("experiments: INS/GNSS, error state", error_state.section),
               ("burden", burden.section),
               ("ARM: Cortex-M4F sizes, qemu-arm runs", sizes.section)])


def intro(result: ReportResult, prov: provenance.Provenance, quick: bool) -> list[str]:
    return [f"Produced by `{prov.command}` on {prov.date} in {result.seconds:.0f} s "
            "(details at the end). Every catalog filter was generated, compiled and verified "
            "against the NumPy reference; every estimate comes from the generated code "
            "unless a caption says otherwise. The summary below sets each of the papers' "
            "claims or numbers beside what this run measured; the sections that follow show "
            "the figures and tables, the long verification tables last."
            + (" **Quick run**: fewer steps and seeds than the full report." if quick else "")]


def results_intro(prov: provenance.Provenance, quick: bool) -> str:
    return (f"Written by `{prov.command}` on {prov.date} "
            + ("(**a quick run**: fewer steps and seeds than the full report). " if quick
               else "(the full run). ")
            + "Do not edit this file: it is regenerated by "
            "`derive reproduce --results docs/results.md`. Each row is one of the papers' "
            "claims or numbers, whether this run matched it, and what was measured or why "
            "not; the figures and full tables are in the report that the same command "
            "writes (`report/index.html` by default).")


def _background(ctx: Context):
    """Start the burden audit in a second process (it is pure SymPy work, independent of
    the rest); returns the executor, or None when processes cannot be started."""
    try:
        method = "fork" if "fork" in multiprocessing.get_all_start_methods() else None
        pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context(method))
        ctx.background["audit"] = pool.submit(compute_audit, ctx.quick)
    except (OSError, NotImplementedError):
        return None
    return pool


def run(out: Path, generated: Path | None = None, quick: bool = False,
        progress: bool = True, command: str | None = None,
        results: Path | None = None) -> ReportResult:
    """Run the whole job; the report goes to ``out`` (index.md, index.html, results.md,
    figures/), and a copy of results.md to ``results`` if given. ``command`` is the
    command line the report states (default: this process's)."""
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result = ReportResult(out, Path(generated) if generated else None)
    names = catalog.names()
    stages = _sections()
    pool, bar = None, None
    try:
        with tempfile.TemporaryDirectory(prefix="derive-report-") as scratch:
            target = Path(generated) if generated else Path(scratch) / "generated"
            ctx = Context(out, target, Path(scratch) / "variants", quick,
                          label=None if generated else "generated")
            pool = _background(ctx)
            bar = _Progress(2 * len(names) + len(stages) + 1, progress)
            for name in names:
                bar.stage(f"generate + compile {name}", "generate + compile")
                generation.generate_model(ctx, name, result.generation)
                bar.advance()
            for name in names:
                bar.stage(f"verify {name}", "verify + check")
                generation.verify_model(ctx, name, result.generation)
                bar.advance()
            for label, make in stages:
                bar.stage(label)
                result.sections.append(make(ctx))
                bar.advance()
            result.sections.append(generation.section(result.generation))   # appendix
            bar.stage("write index.md, index.html and results.md")
            result.seconds = time.perf_counter() - start
            prov = provenance.collect(command)
            result.index, result.page = page.write_page(
                out, TITLE, intro(result, prov, quick), result.sections, prov)
            text = page.results_markdown(TITLE, results_intro(prov, quick), result.sections,
                                         prov)
            for path in [out / "results.md"] + ([Path(results)] if results else []):
                path.write_text(text, encoding="utf-8")
                result.results.append(path)
            bar.advance()
    finally:
        if bar is not None:
            bar.close()
            result.stage_seconds = bar.seconds
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return result
