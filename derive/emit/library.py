"""The library layout: a model's generated C as a package a firmware project drops in.

``OUT/MODEL/`` holds, beside each filter's ``FILTER.c`` and ``FILTER.h`` (included as
``"MODEL/FILTER.h"``, as everywhere), a test program ``test_FILTER.c`` per filter, a
``CMakeLists.txt`` (a static library ``MODEL``, alias ``derive::MODEL``, whose users get
``OUT`` on their include path; one test per filter for ``ctest``) and a ``Makefile``
(``libMODEL.a``, ``make check`` runs the tests).

The test program is rendered from the interface the header states (derive.interface):
it calls ``PREFIX_run`` with the verification data embedded as C arrays (hexadecimal
floating literals: exact), compares every output with the reference row by row (the
error measure of ``derive verify``) and prints the largest error. The data come from the
caller (an object with ``steps``, ``inputs``, ``reference`` and ``tolerance``: see
derive.apps.targets.data); emit computes no reference.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from derive import interface
from derive.emit.render import derive_version, environment
from derive.errors import FilterError
from derive.precision import DOUBLE, Precision, precision
from derive.runs.unit import Unit

_PER_LINE = 4


@dataclass(frozen=True)
class _Array:
    name: str
    type: str
    size: int
    values: str


def _literals(values: np.ndarray, kind: Precision, missing: bool = False) -> str:
    """Exact C literals of ``kind``, ``_PER_LINE`` a line: hexadecimal floating constants
    of each value rounded once to the type (float: to the nearest float, as build_c's
    wrappers and derive verify give a float kernel its inputs). ``missing``: a NaN (a
    sensor's row without a measurement) is C99's ``NAN`` of math.h, a constant
    expression of type float (a quiet NaN in either type; clean under the strict and
    conversion warnings)."""
    flat = np.asarray(values, dtype=float).ravel()
    finite = np.isfinite(flat) | (missing & np.isnan(flat))
    if not finite.all():
        raise FilterError("the verification data hold a value that is not finite")
    rounded = flat.astype(kind.dtype)
    texts = ["NAN" if np.isnan(v) else float(v).hex() + kind.suffix for v in rounded]
    return ",\n".join("    " + ", ".join(texts[i:i + _PER_LINE])
                      for i in range(0, len(texts), _PER_LINE))


def test_program_name(unit: Unit) -> str:
    return f"test_{unit.filter}.c"


def render_test_program(unit: Unit, header: str, data) -> str:
    """``test_FILTER.c``: runs the unit's ``run`` over ``data`` and prints the largest error
    against ``data.reference``; ``header``: the unit's rendered ``FILTER.h`` (its interface
    line gives the functions, their arguments and the arrays' element type)."""
    described = interface.read(header)
    kind = precision(described.element)
    runs = [f for f in described.functions if f.program == "run"]
    if not runs:
        raise FilterError(f"{unit.prefix} has no run function for a test program")
    run = runs[0]
    steps = int(data.steps)
    inputs, outputs, references, comparisons, args, strides = [], [], [], [], [], []
    sensor_rows = {s.z_c for s in unit.sensors}  # a NaN row: no measurement
    compared = []
    for arg in run.arguments:
        if arg.output:
            name = f"out_{arg.name}"
            outputs.append(_Array(name, kind.c_type, arg.size(steps), ""))
            args.append(name)
            ref = data.reference.get(arg.name)
            if ref is not None and not arg.scratch:
                ref_name = f"ref_{arg.name}"
                references.append(_Array(ref_name, "double", arg.size(steps),
                                         _literals(np.reshape(ref, arg.size(steps)), DOUBLE)))
                comparisons.append({"output": name, "reference": ref_name,
                                    "width": arg.size(steps) // steps, "size": arg.size(steps),
                                    "label": arg.name})
                compared.append(arg.name)
            continue
        value = data.inputs.get(arg.name)
        if value is None:
            raise FilterError(f"{run.name} takes {arg.name!r}, which the verification data "
                              "do not hold")
        value = np.asarray(value, dtype=float)
        per_step_rows = arg.strided and value.ndim == 2
        expected = steps * arg.size() if per_step_rows else arg.size(steps)
        if value.size != expected:
            raise FilterError(f"{run.name}: verification data {arg.name!r} of {value.size} "
                              f"values, expected {expected}")
        name = f"in_{arg.name}"
        inputs.append(_Array(name, kind.c_type, value.size,
                             _literals(value, kind, missing=arg.name in sensor_rows)))
        args.append(name)
        if arg.strided:  # run's stride: a row's length for one row per step, 0 for one row
            strides.append(str(arg.size()) if per_step_rows else "0")
    call_args = (["STEPS"] if run.has_steps else []) + args + strides
    env = environment()
    return env.get_template("library/test.c.jinja").render(
        title=unit.title, model=unit.model, filter=unit.filter, run=run.name,
        about="the scenario and seed of derive verify", steps=steps,
        compared=" and ".join(compared) or "nothing", include=f"{unit.model}/{unit.filter}.h",
        # a bound float32 cannot carry may be infinite (derive marks the run failed)
        tolerance_literal=(float(data.tolerance).hex() if math.isfinite(data.tolerance)
                           else "HUGE_VAL"),
        tolerance_text=f"{float(data.tolerance):.1e}", version=derive_version(),
        command=unit.command, inputs=inputs, references=references, outputs=outputs,
        scalar=kind.c_type, comparisons=comparisons,
        returns_status=run.returns_status, call=f"{run.name}({', '.join(call_args)})")


def render_build_files(model: str, filters: Sequence[str], command: str,
                       tests: Mapping[str, str]) -> dict[str, str]:
    """``CMakeLists.txt`` and ``Makefile`` building ``filters``' C files into the static
    library ``MODEL`` and each test program (``tests``: {filter: test program file})."""
    env = environment()
    context = {"model": model, "sources": [f"{f}.c" for f in filters],
               "headers": [f"{f}.h" for f in filters],
               "tests": [(f, tests[f][:-2]) for f in filters if f in tests],
               "command": command, "version": derive_version()}
    return {"CMakeLists.txt": env.get_template("library/CMakeLists.txt.jinja").render(context),
            "Makefile": env.get_template("library/Makefile.jinja").render(context)}
