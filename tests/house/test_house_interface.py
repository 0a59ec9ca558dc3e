"""One module (derive.interface) owns a unit's interface: the header's prose is rendered
from it and derive.build reads the machine-readable line, never the prose."""

from __future__ import annotations

import pytest
from _backend_kf import kf_unit

from derive import catalog, interface
from derive.build import BuildError, parse_interface
from derive.emit.render import describe, render_files
from derive.generation import derive_unit
from derive.lowering import lower_program
from derive.runs.unit import run_arguments


def _header(unit) -> str:
    return render_files(unit, ("c",))[f"{unit.filter}.h"]


def _unit():
    return derive_unit(catalog.load("mpt3d_a"), "kf", {})


def test_header_prose_is_rendered_from_the_description():
    unit = _unit()
    lowered = {name: lower_program(unit.programs[name], use_fma=True)
               for name in unit.programs}
    described = describe(unit.prefix, lowered, run_arguments(unit))
    text = _header(unit)
    assert len(described.c_lines()) == 2  # step, run (run_tracks: only when told)
    for line in described.c_lines() + described.status_lines("NumericalError, or "
                                                             "PatternError for P's pattern"):
        assert f" * {line}\n" in text
    read = interface.read(text)
    assert [f.name for f in read.functions] == [
        f"{unit.prefix}_step", f"{unit.prefix}_run", f"{unit.prefix}_run_tracks"]


def test_build_reads_the_description_not_the_prose():
    text = _header(kf_unit(axes=1))
    functions, statuses = parse_interface(text)
    # the prose interface and status lines removed: build reads the same interface
    stripped = "\n".join(line for line in text.splitlines()
                         if not line.startswith((" *     ", " * status")))
    assert parse_interface(stripped) == (functions, statuses)
    assert [f.name for f in functions] == ["cv_kf_step", "cv_kf_run", "cv_kf_run_tracks"]
    # without the description line there is no interface, whatever the prose says
    without = "\n".join(line for line in text.splitlines() if interface.MARKER not in line)
    with pytest.raises(BuildError, match="states no interface"):
        parse_interface(without)


def test_pattern_status_states_the_checked_elements():
    unit = _unit()
    read = interface.read(_header(unit))
    pattern = [s for s in read.statuses if s.zero]
    assert pattern, "mpt3d_a: P is block diagonal, so run checks P0"
    n = unit.n
    assert all(k // n != k % n for s in pattern for k in s.zero)   # the blocks exclude them


def test_unreadable_description_is_one_clear_error():
    text = _header(kf_unit(axes=1)).replace(interface.MARKER + "{", interface.MARKER + "{oops")
    with pytest.raises(BuildError, match="interface line cannot be read"):
        parse_interface(text)
