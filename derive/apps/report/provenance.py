"""Where a result came from: the date, the versions of derive and its key dependencies,
the machine and the command. The report's footer, ``docs/results.md`` and
``derive --version`` all print these.

Versions are read from the installed distributions' metadata (no import of NumPy or
SymPy), so ``derive --version`` stays fast.
"""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import sys
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version

from ...version import __version__

# The distributions whose versions change derive's output or its timings.
KEY_DEPENDENCIES = ("numpy", "sympy", "jinja2", "cffi", "casadi", "matplotlib")


def versions() -> dict[str, str]:
    """{name: version} of derive, Python and the key dependencies ("not installed" when a
    distribution is absent; matplotlib is optional)."""
    out = {"derive": __version__, "python": platform.python_version()}
    for name in KEY_DEPENDENCIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def version_text() -> str:
    """What ``derive --version`` prints: one line per component."""
    return "\n".join(f"{name} {v}" for name, v in versions().items())


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> str:
    """The CPU model, the number of CPUs and the operating system (no host name)."""
    return (f"{_cpu_model()}, {os.cpu_count() or '?'} CPUs, {platform.system()} "
            f"{platform.release()} ({platform.machine()})")


@dataclass(frozen=True)
class Provenance:
    date: str                   # UTC, ISO 8601 to the second
    versions: dict[str, str]
    machine: str
    command: str

    def lines(self) -> list[tuple[str, str]]:
        """(label, value) pairs, in the order the report shows them."""
        v = self.versions
        deps = ", ".join(f"{k} {v[k]}" for k in ("numpy", "sympy", "matplotlib") if k in v)
        return [("date", self.date), ("derive", v["derive"]),
                ("Python", f"{v['python']} ({deps})"), ("machine", self.machine),
                ("command", self.command)]


def collect(command: str | None = None) -> Provenance:
    """The provenance of a run started now; ``command`` defaults to this process's
    command line."""
    if command is None:
        command = shlex.join(["derive", *sys.argv[1:]])
    now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    return Provenance(now.isoformat().replace("+00:00", "Z"), versions(), machine(), command)
