"""Files that compile in seconds: a dense random KF of n states (m = n/3) generated, then
its C compiled with derive.build's strict flags (``gcc -std=c99 -O2 ...``): seconds (wall
and CPU) and peak memory of each, and the size of the .c file.

Each is measured in a child process of its own under a small launcher
(:mod:`.child_usage`: ``os.wait4`` gives that child's CPU time and peak resident memory),
so neither the bench's own memory nor another child's counts.
The bars (docs/performance.md): a dense 24-state KF (m = 8) generates and compiles in at
most 30 s and 1 GB each, its .c no larger than SymForce's generated step for the same
model (2.5 MB)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ....build import STRICT_CFLAGS
from ....generation import generate
from ....model import LinearModel
from ..bars import BARS
from ..timing import human
from .child_usage import run_measured

#: The bars (derive.apps.bench.bars): seconds and bytes of memory for each of generation
#: and compilation, bytes of the .c file (SymForce's generated step of the dense 24-state KF).
SECONDS_BAR = BARS["compile_seconds"]
MEMORY_BAR = BARS["compile_bytes"]
SIZE_BAR = BARS["c_file_bytes"]


@dataclass(frozen=True)
class Measured:
    """One child process: wall and CPU (user + system) seconds, peak resident bytes."""

    seconds: float
    cpu_seconds: float
    peak_bytes: float


@dataclass(frozen=True)
class CompileRow:
    case: str
    generate: Measured | None
    compile: Measured | None
    c_bytes: int | None
    note: str = ""


def dense_model(n: int, m: int | None = None, seed: int = 1) -> LinearModel:
    """A stable dense random model of n states and m = n/3 measurements (every entry of F,
    H, Q and R non-zero, rounded to three decimals)."""
    m = max(1, n // 3) if m is None else m
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(n, n))
    F *= 0.95 / max(abs(np.linalg.eigvals(F)))
    H = rng.normal(size=(m, n))
    L = rng.normal(size=(n, n))
    Q = L @ L.T / n + 0.1 * np.eye(n)
    Lr = rng.normal(size=(m, m))
    R = Lr @ Lr.T / m + 0.2 * np.eye(m)

    def short(a):
        return np.round(a, 3).tolist()
    return LinearModel(f"dense{n}", [f"x{i}" for i in range(n)], [f"y{i}" for i in range(m)],
                       short(F), short(H), short((Q + Q.T) / 2), short((R + R.T) / 2))


def _child(cmd: list[str]) -> Measured:
    """Run ``cmd`` to its end: its wall and CPU seconds and peak memory (RuntimeError with
    its output when it fails)."""
    usage = run_measured(cmd)
    if usage.returncode != 0:
        output = (usage.stdout + usage.stderr).strip()
        raise RuntimeError(f"{' '.join(cmd[:3])} ... failed: {output[-500:]}")
    return Measured(usage.seconds, usage.cpu_seconds, usage.peak_bytes)


def generate_dense(n: int, out: str) -> None:
    """Write the C of the dense model's KF (the child process of :func:`compile_row`)."""
    generate(dense_model(n), ["kf"], "c", out)


def compile_row(n: int, workdir: Path) -> CompileRow:
    """Generate the dense n-state KF's C in a child process, then compile it with gcc and
    the strict flags in another."""
    out = workdir / f"dense{n}"
    case = f"dense KF n={n} m={max(1, n // 3)}"
    code = (f"from derive.apps.bench.costs.compile_size import generate_dense; "
            f"generate_dense({n}, {str(out)!r})")
    try:
        generated = _child([sys.executable, "-c", code])
    except RuntimeError as exc:
        return CompileRow(case, None, None, None, f"generation failed: {exc}")
    c_file = out / f"dense{n}" / "kf.c"
    try:
        compiled = _child(["gcc", *STRICT_CFLAGS, "-c", str(c_file), "-o",
                           str(c_file.with_suffix(".o"))])
    except (RuntimeError, OSError) as exc:
        return CompileRow(case, generated, None, c_file.stat().st_size,
                          f"gcc failed: {exc}")
    return CompileRow(case, generated, compiled, c_file.stat().st_size)


def compile_rows(states: tuple[int, ...], workdir: Path, tick=lambda text: None
                 ) -> list[CompileRow]:
    rows = []
    for n in states:
        tick(f"compile size: dense KF, {n} states")
        rows.append(compile_row(n, workdir))
    return rows


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def _measured(m: Measured | None) -> tuple[str, str, str]:
    if m is None:
        return ("failed", "", "")
    return (human(m.seconds), human(m.cpu_seconds), f"{m.peak_bytes / 1e6:,.0f} MB")


def compile_table(rows: list[CompileRow]) -> tuple[tuple, list[tuple], list[str]]:
    """(head, body, bar lines) of the compile-size rows."""
    head = ("case", "generate", "CPU", "peak", f"gcc {' '.join(STRICT_CFLAGS[:2])}", "CPU",
            "peak", ".c size", "note")
    body = [(r.case, *_measured(r.generate), *_measured(r.compile),
             "" if r.c_bytes is None else f"{r.c_bytes / 1e6:.2f} MB", r.note) for r in rows]
    bars = []
    for r in rows:
        for what, m in (("generates", r.generate), ("compiles", r.compile)):
            if m is not None:
                memory = m.peak_bytes <= MEMORY_BAR
                bars.append(f"bar: {r.case} {what} in {human(m.seconds)} (CPU "
                            f"{human(m.cpu_seconds)}), peak {m.peak_bytes / 1e6:,.0f} MB "
                            f"(<= {SECONDS_BAR:g} s and <= {MEMORY_BAR / 1e9:g} GB: "
                            f"{_verdict(m.seconds <= SECONDS_BAR and memory)}; by CPU "
                            f"seconds, which other jobs on the machine do not inflate: "
                            f"{_verdict(m.cpu_seconds <= SECONDS_BAR and memory)})")
        if r.c_bytes is not None:
            bars.append(f"bar: {r.case} .c file {r.c_bytes / 1e6:.2f} MB (<= SymForce's "
                        f"{SIZE_BAR / 1e6:g} MB: {_verdict(r.c_bytes <= SIZE_BAR)})")
    return head, body, bars
