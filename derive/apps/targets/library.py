"""``derive generate MODEL --layout library``: the C of the filters, a test program per
filter (the verification data embedded), a CMakeLists.txt and a Makefile, written into
``OUT/MODEL/`` together through derive.emit.write (all rendered before any is written;
the files of one call replaced together).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from pathlib import Path

from ...emit.library import render_build_files, render_test_program, test_program_name
from ...emit.render import render_unit
from ...emit.write import write_files
from ...errors import FilterError, NameError_
from ...filters import available, check_before_deriving, kind
from ...generation import command_unit, resolve_model
from ...options import per_filter
from ...runs.unit import Unit
from .data import TEST_STEPS, require_examples, verification_data


def library_command(ref: str, units: list[Unit], out: str) -> str:
    """The command that regenerates the whole library: every filter of the call, and the
    option flags their own regenerate commands carry (each filter takes those it takes)."""
    flags: dict[str, None] = {}
    for unit in units:
        head = f"derive generate {ref} --filter {unit.filter} --layout library --out {out}"
        if not unit.command.startswith(head):
            raise ValueError(f"{unit.prefix}: regenerate command {unit.command!r} does not "
                             f"start with {head!r}")
        flags.update(dict.fromkeys(unit.command[len(head):].split(" --")))
    filters = " ".join(f"--filter {u.filter}" for u in units)
    options = " --".join(f for f in flags if f)
    return (f"derive generate {ref} {filters} --layout library --out {out}"
            + (f" --{options}" if options else ""))


CTEST_DASHBOARD_TARGETS = frozenset(
    [mode + part for mode in ("Experimental", "Nightly", "Continuous")
     for part in ("", "Start", "Update", "Configure", "Build", "Test", "Coverage", "MemCheck",
                  "Submit")] + ["NightlyMemoryCheck"])
"""The dashboard targets ``include(CTest)`` defines (CTestTargets.cmake: each mode, and the
mode followed by each dashboard step): a firmware project that includes CTest and adds
the library with ``add_subdirectory`` fails at configure on a library target of one of
these names."""

CMAKE_RESERVED_TARGETS = frozenset((
    "all", "clean", "help", "install", "preinstall", "rebuild_cache", "edit_cache",
    "ALL_BUILD", "ZERO_CHECK", "INSTALL", "test", "RUN_TESTS", "package",
    "package_source", "PACKAGE")) | CTEST_DASHBOARD_TARGETS
"""Target names CMake reserves (policy CMP0037; ``test`` and ``RUN_TESTS`` with CTest,
the ``package`` ones with CPack) and CTest's dashboard targets: the library's
CMakeLists.txt names its target after the model, so a model of one of these names could
not be configured."""


def check_library_name(name: str) -> None:
    """Refuse a model name the library layout cannot use as a CMake target (NameError_)."""
    if name in CMAKE_RESERVED_TARGETS:
        raise NameError_(f"model name {name!r} is reserved by CMake as a target name, and "
                         "--layout library names its CMake library target after the model; "
                         "rename the model")


def render_library(model, filters: Iterable[str] | None = None, out: str | Path = "generated",
                   options: Mapping | None = None, steps: int = TEST_STEPS,
                   ref: str | None = None, with_data: bool = False,
                   refuse_uncarried: bool = True):
    """({file name: text} of the library of ``model``, the units), rendered, not written;
    ``with_data``: also {filter: its VerificationData}; ``refuse_uncarried``: a FilterError
    for a filter float32 cannot carry (derive.apps.float_tolerance)."""
    model = resolve_model(model)
    check_library_name(model.name)
    require_examples(model)   # the test programs run free parameters at their examples
    ref = ref or model.name
    names = list(filters) if filters is not None else available(model)
    for name in names:
        kind(name)
    typed = per_filter(names, options, None, named=filters is not None)
    check_before_deriving(model, names, typed, named=filters is not None)
    files: dict[str, str] = {}
    units: list[Unit] = []
    tests: dict[str, str] = {}
    data = {}
    for name in names:
        unit = command_unit(model, name, typed[name], ref, str(out))
        unit = dataclasses.replace(unit, command=unit.command.replace(
            " --lang all", " --layout library", 1))
        texts = render_unit(unit, "c")
        files.update(texts)
        data[name] = verification_data(model, name, typed[name], steps, unit=unit)
        if refuse_uncarried and not data[name].meaningful:
            raise FilterError(f"{model.name} {name}: float32 cannot carry this filter (its "
                              f"bound {data[name].bound.text()} is 1 or more), so its test "
                              "program would hold it to nothing; generate it in double")
        tests[name] = test_program_name(unit)
        files[tests[name]] = render_test_program(unit, texts[f"{name}.h"], data[name])
        units.append(unit)
    files.update(render_build_files(model.name, names, library_command(ref, units, str(out)),
                                    tests))
    return (files, units, data) if with_data else (files, units)


def generate_library(model, filters: Iterable[str] | None = None,
                     out: str | Path = "generated", options: Mapping | None = None,
                     steps: int = TEST_STEPS) -> tuple[list[Path], list[Unit]]:
    """Write the library of ``model`` into ``out/MODEL/``; (the paths written, the units)."""
    paths, units, _ = write_library(model, filters, out, options, steps)
    return paths, units


def write_library(model, filters: Iterable[str] | None = None, out: str | Path = "generated",
                  options: Mapping | None = None, steps: int = TEST_STEPS,
                  refuse_uncarried: bool = True):
    """:func:`generate_library`, also returning {filter: its VerificationData} (what the
    test programs embed, for a caller that runs them: derive.apps.targets.arm)."""
    ref = model if isinstance(model, str) else None
    model = resolve_model(model)
    files, units, data = render_library(model, filters, out, options, steps, ref,
                                        with_data=True, refuse_uncarried=refuse_uncarried)
    return write_files(out, model.name, files), units, data
