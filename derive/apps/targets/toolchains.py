"""The cross toolchains derive builds its generated C with, and what it reads back.

A :class:`Target` is a compiler command and its flags: ``cortex-m4`` (bare metal,
``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard``: the
FPU is single precision, so double arithmetic runs in software) and ``arm-linux``
(``arm-linux-gnueabihf-gcc``, linked statically so ``qemu-arm`` runs it without a
sysroot). Sizes are read from the object the compiler wrote: per function from
``nm --size-sort -S`` (the symbol's size in ``.text``; literal pools included), per
object from ``size`` (text, data, bss): nothing is estimated.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from ...build import STRICT_CFLAGS, BuildEnvironmentError, BuildError
from ...errors import OptionError

#: Cortex-M4F: Thumb-2, the single-precision FPU, floats passed in FPU registers.
CORTEX_M4_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard")
#: The optimisation levels sizes are reported for.
SIZE_LEVELS = ("-Os", "-O2")
#: Symbol types of nm that are code, initialised data and zeroed data (upper: global).
_TEXT, _DATA, _BSS = set("Tt"), set("DdRr"), set("BbCc")


@dataclass(frozen=True)
class Target:
    """A cross compiler: ``cc`` with ``flags`` before the optimisation level; ``nm`` and
    ``size`` read its objects; ``runner``: the emulator that runs its programs (or None)."""

    name: str
    cc: str
    flags: tuple[str, ...]
    nm: str
    size: str
    runner: str | None = None
    link_flags: tuple[str, ...] = ()

    def missing(self) -> list[str]:
        """The tools of this target not on PATH."""
        tools = [self.cc, self.nm, self.size] + ([self.runner] if self.runner else [])
        return [tool for tool in tools if shutil.which(tool) is None]

    def require(self, run: bool = False) -> None:
        """BuildEnvironmentError naming the missing tools (the runner only if ``run``)."""
        missing = [t for t in self.missing() if run or t != self.runner]
        if missing:
            raise BuildEnvironmentError(
                f"target {self.name}: {', '.join(missing)} not found on PATH (Debian: "
                "apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi "
                "gcc-arm-linux-gnueabihf qemu-user)")


TARGETS = {
    "cortex-m4": Target("cortex-m4", "arm-none-eabi-gcc", CORTEX_M4_FLAGS,
                        "arm-none-eabi-nm", "arm-none-eabi-size"),
    "arm-linux": Target("arm-linux", "arm-linux-gnueabihf-gcc", (),
                        "arm-linux-gnueabihf-nm", "arm-linux-gnueabihf-size",
                        runner="qemu-arm", link_flags=("-static",)),
}


def target(name: str) -> Target:
    if name not in TARGETS:
        raise OptionError(f"target {name!r} is not one of {', '.join(TARGETS)}")
    return TARGETS[name]


def _run(command: list[str], what: str) -> str:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise BuildError(f"{what} failed: {' '.join(command)}\n{done.stderr.strip()}")
    return done.stdout


def compile_object(tgt: Target, source: Path, obj: Path, level: str = "-O2",
                   include: tuple[Path, ...] = (), extra: tuple[str, ...] = ()) -> Path:
    """Compile ``source`` to ``obj`` with the strict flags (``-std=c99 -Wall -Wextra
    -Werror -pedantic``), the target's flags and ``level``."""
    strict = [f for f in STRICT_CFLAGS if not f.startswith("-O")]
    command = [tgt.cc, *strict, *tgt.flags, level, *extra,
               *(f"-I{d}" for d in include), "-c", str(source), "-o", str(obj)]
    _run(command, f"{tgt.name} compile")
    return obj


def link_program(tgt: Target, objects: list[Path], program: Path) -> Path:
    """Link ``objects`` into ``program`` (with libm and the target's link flags)."""
    _run([tgt.cc, *tgt.flags, *tgt.link_flags, *map(str, objects), "-lm", "-o", str(program)],
         f"{tgt.name} link")
    return program


@dataclass(frozen=True)
class FunctionSize:
    """One symbol of an object: its name, nm's type letter and its size in bytes."""

    name: str
    kind: str
    size: int

    @property
    def section(self) -> str:
        return ("text" if self.kind in _TEXT else "data" if self.kind in _DATA
                else "bss" if self.kind in _BSS else self.kind)


@dataclass(frozen=True)
class ObjectSize:
    """What ``size`` reports for one object (bytes), and its symbols by ``nm``."""

    text: int
    data: int
    bss: int
    symbols: tuple[FunctionSize, ...]

    def functions(self) -> dict[str, int]:
        """{function name: bytes of code} of the object's code symbols."""
        return {s.name: s.size for s in self.symbols if s.section == "text"}


def read_sizes(tgt: Target, obj: Path) -> ObjectSize:
    """Sizes of ``obj``, read by the target's ``size`` (Berkeley format) and
    ``nm --size-sort -S`` (symbols with a size only)."""
    lines = _run([tgt.size, "-B", str(obj)], f"{tgt.name} size").splitlines()
    text, data, bss = (int(v) for v in lines[1].split()[:3])
    symbols = []
    for line in _run([tgt.nm, "--size-sort", "-S", str(obj)], f"{tgt.name} nm").splitlines():
        parts = line.split()
        if len(parts) == 4:
            symbols.append(FunctionSize(parts[3], parts[2], int(parts[1], 16)))
    return ObjectSize(text, data, bss, tuple(symbols))
