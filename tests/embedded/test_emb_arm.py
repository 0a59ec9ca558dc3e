"""Generated C on ARM (issue 14, item 2): Cortex-M4F sizes per function read from the real
object, and filters built for arm-linux-gnueabihf run under qemu-arm against the NumPy
reference. Skipped only when a cross tool is missing (CI installs them: .ci/run)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import derive.apps.targets.library as library
from derive import catalog, generate
from derive.apps.targets.arm import read_states, run_under_qemu, sizes
from derive.apps.targets.toolchains import CORTEX_M4_FLAGS, SIZE_LEVELS, TARGETS
from derive.apps.verify import LINEAR_TOLERANCE, verify_filter
from derive.cli import main
from derive.errors import NumericalError

M4, LINUX = TARGETS["cortex-m4"], TARGETS["arm-linux"]
needs_m4 = pytest.mark.skipif(bool(M4.missing()),
                              reason=f"Cortex-M4 tools missing: {', '.join(M4.missing())}")
needs_qemu = pytest.mark.skipif(bool(LINUX.missing()),
                                reason=f"arm-linux tools missing: {', '.join(LINUX.missing())}")


def _own_reading(source, level, tmp_path):
    """Compile ``source`` for Cortex-M4F here, and read its symbols with nm ourselves."""
    obj = tmp_path / f"own{level}.o"
    subprocess.run(["arm-none-eabi-gcc", "-std=c99", "-Wall", "-Wextra", "-Werror",
                    "-pedantic", *CORTEX_M4_FLAGS, level, "-c", str(source), "-o", str(obj)],
                   check=True)
    listing = subprocess.run(["arm-none-eabi-nm", "-S", str(obj)], check=True,
                             capture_output=True, text=True).stdout
    return {parts[3]: int(parts[1], 16) for parts in map(str.split, listing.splitlines())
            if len(parts) == 4 and parts[2] in "Tt"}


@needs_m4
@pytest.mark.parametrize("precision", ["float", "double"])
def test_cortex_m4_sizes_are_read_from_the_compiled_object(tmp_path, precision):
    options = {"precision": precision}
    rows = sizes("mpt3d_a", ["kf", "sskf"], options)
    assert [(r.filter, r.level, r.precision) for r in rows] == [
        (f, level, precision) for f in ("kf", "sskf") for level in SIZE_LEVELS]
    generate("mpt3d_a", ["kf", "sskf"], "c", tmp_path, options=options)
    for row in rows:
        own = _own_reading(tmp_path / "mpt3d_a" / f"{row.filter}.c", row.level, tmp_path)
        functions = row.object.functions()
        assert functions == own
        assert {f"mpt3d_a_{row.filter}_step", f"mpt3d_a_{row.filter}_run"} <= set(functions)
        assert 0 < sum(functions.values()) <= row.object.text
        assert row.object.data == row.object.bss == 0   # no globals in generated C
    # the reading follows the code: leaving run_tracks out removes its function and its
    # bytes (GCC may then split or inline run differently: a static step body is shared by
    # run and run_tracks, so the other functions' sizes are not fixed by the option)
    smaller = sizes("mpt3d_a", ["kf"], {**options, "run_tracks": False}, levels=("-Os",))[0]
    full = next(r for r in rows if r.filter == "kf" and r.level == "-Os")
    kept = smaller.object.functions()
    assert "mpt3d_a_kf_run_tracks" in full.object.functions()
    assert "mpt3d_a_kf_run_tracks" not in kept
    assert {"mpt3d_a_kf_step", "mpt3d_a_kf_run"} <= set(kept)
    assert smaller.object.text < full.object.text
    generate("mpt3d_a", ["kf"], "c", tmp_path / "smaller",
             options={**options, "run_tracks": False})
    assert kept == _own_reading(tmp_path / "smaller" / "mpt3d_a" / "kf.c", "-Os", tmp_path)


@needs_m4
def test_derive_size_prints_the_bytes_of_each_function_in_both_precisions(capsys):
    assert main(["size", "cv", "--filter", "kf", "--level", "Os"]) == 0
    out = capsys.readouterr().out
    assert "arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard" in out
    lines = {line.split()[2]: line for line in out.splitlines() if line.startswith("cv ")}
    assert sorted(lines) == ["double", "float"]
    text = {}
    for precision, line in lines.items():
        row = sizes("cv", ["kf"], {"precision": precision}, levels=("-Os",))[0]
        assert row.precision == precision
        assert line.split()[:7] == ["cv", "kf", precision, "-Os", str(row.object.text), "0",
                                    "0"]
        for name, size in row.object.functions().items():
            assert f"{name[len('cv_kf_'):]} {size}" in line
        text[precision] = row.object.text
    # the single-precision FPU runs float code; double arithmetic is calls into libgcc
    assert text["float"] < text["double"]


def test_size_refuses_a_bad_target_in_one_line(capsys):
    assert main(["size", "cv", "--target", "avr"]) == 2
    err = capsys.readouterr().err
    assert "--target" in err and "Traceback" not in err and err.count("\n") == 1


@needs_qemu
@pytest.mark.parametrize("model, names", [("mpt3d_a", ["kf", "sskf"]),
                                          ("gnss_pseudorange", ["ekf"]), ("cv", ["rts", "fir"])])
def test_filters_run_under_qemu_arm_and_agree_with_the_reference(model, names):
    runs = run_under_qemu(model, names, steps=100)
    assert [r.filter for r in runs] == names
    for r in runs:
        assert r.passed, r.line()
        assert r.error <= r.tolerance and (model == "gnss_pseudorange"
                                           or r.tolerance == LINEAR_TOLERANCE)
        # the program's own measure, printed to 4 digits, is the one Python takes
        assert r.printed == pytest.approx(r.error, rel=1e-3, abs=1e-300)


@needs_qemu
def test_the_arm_program_reports_a_wrong_reference(tmp_path, monkeypatch):
    """A reference off by 1e-9 (relative) shows as such under qemu-arm: the comparison
    can fail."""
    real = library.verification_data

    def perturbed(*args, **kwargs):
        data = real(*args, **kwargs)
        data.reference["xs"][:] *= 1.0 + 1e-9
        return data

    monkeypatch.setattr(library, "verification_data", perturbed)
    run = run_under_qemu("cv", ["kf"], steps=50)[0]
    assert not run.passed and 0.5e-9 < run.error < 2e-9
    assert run.printed == pytest.approx(run.error, rel=1e-3)


def test_states_are_read_exactly():
    values = np.array([0.1, -2.5e-300, 1e300, 0.0])
    text = "noise line\nxs " + " ".join(v.hex() for v in values) + "\ncv kf: largest error 0"
    assert np.array_equal(read_states(text)["xs"], values)



def test_a_missing_cross_compiler_is_named_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path))   # no tool at all on PATH
    assert main(["size", "cv", "--filter", "kf"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("derive: error: target cortex-m4: arm-none-eabi-gcc, ")
    assert "apt-get install gcc-arm-none-eabi" in err and err.count("\n") == 1
    assert main(["size", "cv", "--filter", "kf", "--target", "arm-linux", "--qemu"]) == 2
    assert "arm-linux-gnueabihf-gcc" in capsys.readouterr().err


@needs_qemu
def test_float32_runs_under_qemu_arm_within_derive_verifys_float32_tolerance():
    """float32 C on ARM, held to the tolerance derive verify --precision float derives
    (derive.apps.float_tolerance) for the same filter, data and steps."""
    options = {"precision": "float"}
    runs = run_under_qemu("mpt3d_a", ["kf", "udkf"], options, steps=100)
    for r in runs:
        host = verify_filter(catalog.load("mpt3d_a"), r.filter, steps=100, langs=("c",),
                             options=options)[0]
        assert r.precision == "float" and r.bound is not None and r.bound.meaningful
        assert r.tolerance == host.tolerance == host.bound.value
        assert r.passed and r.error <= r.tolerance, r.line()
        # float32, not double, was run: its error is far above double's rounding
        assert r.error > 1e3 * LINEAR_TOLERANCE


@needs_qemu
def test_a_filter_failing_its_own_check_under_qemu_is_a_failed_verification(monkeypatch):
    """The C run returning its status on ARM (S not positive definite, from a P0 of -I
    in the data: a model file's P0 must be positive semidefinite) is a failure of the
    filter on that data, named with its check, not a bug (it was exit 70)."""
    real = library.verification_data

    def negative(*args, **kwargs):
        data = real(*args, **kwargs)
        data.inputs["P0"][:] = -np.eye(data.inputs["P0"].shape[0])
        return data

    monkeypatch.setattr(library, "verification_data", negative)
    with pytest.raises(NumericalError, match="cv kf under qemu-arm: cv_kf_run returned "
                                             "status 1: .*S is not positive definite"):
        run_under_qemu("cv", ["kf"], steps=5)
