"""Start-up of the command line: wall and CPU seconds of ``derive`` calls that answer at
once (help, ``--version``, a refusal of a bad argument) and of ``derive list``, each in a
fresh process (``python -m derive``), the least over repeats taken in turns; beside them
the floor under every call, the interpreter's own start (``python -c pass``).

The CPU seconds are the child's (``RUSAGE_CHILDREN``), which other processes on a shared
machine do not inflate as much as the wall time.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .... import commands
from ..timing import human

#: (what the row says, the arguments of ``derive``): the calls the start-up is judged on.
CALLS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("derive --help", ("--help",)),
    ("derive --version", ("--version",)),
    ("derive list", ("list",)),
    ("derive frobnicate (unknown command)", ("frobnicate",)),
    ("derive show (missing argument)", ("show",)),
    ("derive generate cv --lang fortran (bad choice)", ("generate", "cv", "--lang", "fortran")),
    ("derive list --jospeh (unknown flag, hint)", ("list", "--jospeh")),
    ("derive show missing.toml (no such file)", ("show", "missing.toml")),
)

FLOOR = "python -c pass (the floor)"


@dataclass(frozen=True)
class StartupRow:
    call: str
    seconds: float       # wall, the least over the repeats
    cpu_seconds: float   # the child's user + system CPU, the least over the repeats
    returncode: int


def _child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _timed(argv: list[str], env: dict[str, str], cwd: str) -> tuple[float, float, int]:
    cpu = _child_cpu()
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, env=env, cwd=cwd, timeout=120,
                          stdin=subprocess.DEVNULL)
    return time.perf_counter() - start, _child_cpu() - cpu, done.returncode


def startup_rows(repeats: int, workdir: Path) -> list[StartupRow]:
    """Every call of :data:`CALLS`, each command's ``--help`` and the floor, ``repeats``
    times in turns (run in ``workdir``, where ``missing.toml`` does not exist); the
    ``derive`` run is the package this process imported."""
    package_root = str(Path(__file__).resolve().parents[3])   # the directory of derive/
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        p for p in (package_root, os.environ.get("PYTHONPATH", "")) if p))
    calls = [(FLOOR, [sys.executable, "-c", "pass"])]
    calls += [(name, [sys.executable, "-m", "derive", *args]) for name, args in CALLS]
    calls += [(f"derive {m.NAME} --help", [sys.executable, "-m", "derive", m.NAME, "--help"])
              for m in commands.modules()]
    best: dict[str, tuple[float, float, int]] = {}
    for _ in range(repeats):
        for name, argv in calls:
            seconds, cpu, status = _timed(argv, env, str(workdir))
            old = best.get(name)
            best[name] = (seconds, cpu, status) if old is None else (
                min(old[0], seconds), min(old[1], cpu), status)
    return [StartupRow(name, *best[name]) for name, _ in calls]


def startup_table(rows: list[StartupRow]) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """(head, body) of the start-up table."""
    head = ("call", "wall", "CPU", "exit")
    body = [(r.call, human(r.seconds), human(r.cpu_seconds), str(r.returncode)) for r in rows]
    return head, body
