"""The generated C on ARM: Cortex-M4F code and data sizes per function, and runs under
``qemu-arm`` compared with the NumPy reference.

Sizes: the filters' C is generated (derive.generation, into a scratch directory),
compiled for the ``cortex-m4`` target at each level of
:data:`~derive.apps.targets.toolchains.SIZE_LEVELS`, and each object read back
(:func:`~derive.apps.targets.toolchains.read_sizes`). Runs: the library layout is written
(derive.apps.targets.library: each filter's C and its test program, the verification data
embedded), each filter built with its test program for ``arm-linux-gnueabihf`` (static,
``-O2``) and run under ``qemu-arm --states``; the states it prints (C99 ``%a``: exact) are
compared in Python with the reference by the error measure of ``derive verify``
(derive.apps.verify.relative_error), against the tolerance ``derive verify`` holds the
same C to (float32: derive.apps.float_tolerance's bound).
"""

from __future__ import annotations

import re
import subprocess
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...build import BuildError, parse_interface
from ...errors import NumericalError
from ...generation import generate_units, resolve_model
from ..float_tolerance import FloatTolerance, PropagatedTolerance
from ..verify import relative_error, within_tolerance
from .data import TEST_STEPS
from .library import write_library
from .toolchains import SIZE_LEVELS, TARGETS, ObjectSize, compile_object, link_program, read_sizes

#: A run under the emulator that takes longer than this is a hang.
RUN_TIMEOUT = 600.0
_PRINTED = re.compile(r"largest error (\S+) over (\d+) steps")
_FAILED = re.compile(r"(\w+) returned status (\d+)")


@dataclass(frozen=True)
class FilterSize:
    """One filter compiled for a target at one optimisation level."""

    model: str
    filter: str
    precision: str
    target: str
    level: str
    object: ObjectSize


def sizes(model, filters: Iterable[str] | None = None, options: Mapping | None = None,
          target: str = "cortex-m4", levels: Iterable[str] = SIZE_LEVELS,
          workdir: str | Path | None = None) -> list[FilterSize]:
    """Sizes of the C of ``filters`` (default: all that apply) of ``model`` compiled for
    ``target`` at each level, read from the objects."""
    model = resolve_model(model)
    tgt = TARGETS[target]
    tgt.require()
    out: list[FilterSize] = []
    with tempfile.TemporaryDirectory(prefix="derive-size-", dir=workdir) as scratch:
        _, units = generate_units(model, filters, "c", scratch, options)
        folder = Path(scratch) / model.name
        for unit in units:
            out += file_sizes(folder / f"{unit.filter}.c", model.name, unit.filter,
                              unit.precision, target, levels)
    return out


def file_sizes(source: Path, model: str, name: str, scalar: str, target: str = "cortex-m4",
               levels: Iterable[str] = SIZE_LEVELS) -> list[FilterSize]:
    """Sizes of one written generated ``FILTER.c`` (its header beside it) compiled for
    ``target`` at each level; the objects go beside it in a scratch directory."""
    tgt = TARGETS[target]
    tgt.require()
    out = []
    with tempfile.TemporaryDirectory(prefix="derive-size-") as scratch:
        for level in levels:
            obj = compile_object(tgt, source, Path(scratch) / f"{name}{level}.o", level)
            out.append(FilterSize(model, name, scalar, target, level, read_sizes(tgt, obj)))
    return out


@dataclass(frozen=True)
class ArmRun:
    """One filter run under the emulator: the error Python measured on the states the
    program printed, the error the program printed itself, and the tolerance."""

    model: str
    filter: str
    precision: str
    steps: int
    error: float
    printed: float
    tolerance: float
    bound: FloatTolerance | PropagatedTolerance | None = None

    @property
    def passed(self) -> bool:
        """Within the tolerance, and (float32) a bound below 1, as derive verify judges."""
        return within_tolerance(self.error, self.tolerance, self.bound)

    def line(self) -> str:
        mark = "ok  " if self.passed else "FAIL"
        text = (f"{mark} {self.model:18s} {self.filter:7s} {self.precision:6s} qemu-arm "
                f"{self.steps:4d} steps  max rel err {self.error:9.2e} <= "
                f"{self.tolerance:.1e} (program: {self.printed:.2e})")
        if self.bound is not None:
            text += f"  ({self.bound.text()}"
            text += ")" if self.bound.meaningful else "; >= 1: float32 cannot carry it)"
        return text


def read_states(text: str) -> dict[str, np.ndarray]:
    """{output name: values} from the ``--states`` lines of a test program."""
    states = {}
    for line in text.splitlines():
        name, _, values = line.partition(" ")
        if name.isidentifier() and values and values.lstrip().startswith(("0x", "-0x")):
            states[name] = np.array([float.fromhex(v) for v in values.split()])
    return states


def run_under_qemu(model, filters: Iterable[str] | None = None, options: Mapping | None = None,
                   steps: int = TEST_STEPS, workdir: str | Path | None = None
                   ) -> list[ArmRun]:
    """Build each filter with its test program for arm-linux-gnueabihf, run it under
    qemu-arm and compare the states it prints with the reference."""
    model = resolve_model(model)
    tgt = TARGETS["arm-linux"]
    tgt.require(run=True)
    runs = []
    with tempfile.TemporaryDirectory(prefix="derive-qemu-", dir=workdir) as scratch:
        _, units, data = write_library(model, filters, scratch, options, steps,
                                       refuse_uncarried=False)
        folder = Path(scratch) / model.name
        for unit in units:
            name = unit.filter
            objects = [compile_object(tgt, folder / f"{stem}.c", folder / f"{stem}.o", "-O2",
                                      include=(Path(scratch),))
                       for stem in (name, f"test_{name}")]
            program = link_program(tgt, objects, folder / f"test_{name}")
            done = subprocess.run([tgt.runner, str(program), "--states"], capture_output=True,
                                  text=True, timeout=RUN_TIMEOUT)
            printed = _PRINTED.search(done.stdout)
            failed = _FAILED.search(done.stdout)
            if done.returncode == 2 and failed is not None:   # the filter's own check
                status = int(failed[2])
                checks = parse_interface((folder / f"{name}.h").read_text())[1].get(status, [])
                raise NumericalError(
                    f"{model.name} {name} under {tgt.runner}: {failed[1]} returned status "
                    f"{status}: {' or '.join(checks) or 'unknown check'} (on the data of "
                    "derive verify)")
            if done.returncode not in (0, 1) or printed is None:
                raise BuildError(f"{tgt.runner} {program.name} exited with status "
                                 f"{done.returncode}: {done.stdout[-300:]}{done.stderr[-300:]}")
            states = read_states(done.stdout)
            reference = data[name].reference
            error = 0.0
            for output, ref in reference.items():
                if output not in states:
                    raise BuildError(f"{program.name} printed no {output}")
                error = max(error, relative_error(states[output].reshape(ref.shape), ref))
            runs.append(ArmRun(model.name, name, unit.precision, steps, error,
                               float(printed[1]), data[name].tolerance, data[name].bound))
    return runs


def short_name(function: str, model: str, name: str) -> str:
    """``step`` for ``acme_mpt3d_a_kf_step``: the function without its file's prefix."""
    marker = f"{model}_{name}_"
    return function.split(marker, 1)[1] if marker in function else function


def size_rows(rows: Iterable[FilterSize]) -> list[tuple[str, ...]]:
    """One row per filter and level: model, filter, precision, level, the object's text,
    data and bss, and the code bytes of each function (largest first)."""
    out = []
    for r in rows:
        functions = sorted(r.object.functions().items(), key=lambda kv: (-kv[1], kv[0]))
        out.append((r.model, r.filter, r.precision, r.level, str(r.object.text),
                    str(r.object.data), str(r.object.bss),
                    ", ".join(f"{short_name(f, r.model, r.filter)} {b}" for f, b in functions)))
    return out


SIZE_COLUMNS = ("model", "filter", "precision", "level", "text", "data", "bss",
                "code bytes per function")


def size_table(rows: Iterable[FilterSize]) -> str:
    """The rows as an aligned text table."""
    body = [SIZE_COLUMNS] + size_rows(rows)
    widths = [max(len(row[i]) for row in body) for i in range(len(SIZE_COLUMNS) - 1)]
    numeric = {SIZE_COLUMNS.index(c) for c in ("text", "data", "bss")}
    return "\n".join("  ".join(cell.rjust(w) if i in numeric else cell.ljust(w)
                               for i, (cell, w) in enumerate(zip(row, widths)))
                      + "  " + row[-1] for row in body)
