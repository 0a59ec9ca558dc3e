"""The library layout (issue 14, item 5): ``derive generate MODEL --layout library`` writes
the C, a test program per filter (the verification data embedded), a CMakeLists.txt and a
Makefile into OUT/MODEL/ through the one writer; both build systems build it on this
machine and the test programs print the largest error against the NumPy reference."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
import subprocess

import numpy as np
import pytest

from derive.apps.targets.arm import sizes
from derive.apps.targets.data import verification_data
from derive.apps.targets.library import render_library
from derive.apps.targets.toolchains import CORTEX_M4_FLAGS, TARGETS
from derive.apps.verify import LINEAR_TOLERANCE, relative_error, verify_filter
from derive.build import STRICT_CFLAGS, build_c
from derive.cli import main
from derive.emit.library import render_test_program
from derive.generation import command_unit, resolve_model

GCC, CMAKE, MAKE = shutil.which("gcc"), shutil.which("cmake"), shutil.which("make")
needs_cmake = pytest.mark.skipif(CMAKE is None or GCC is None, reason="no cmake or gcc")
needs_make = pytest.mark.skipif(MAKE is None or GCC is None, reason="no make or gcc")
FILTERS = ("kf", "rts", "sskf", "fir")
STRICT = " ".join(STRICT_CFLAGS)
PRINTED = re.compile(r"^\w+ (\w+): largest error (\S+) over (\d+) steps .*: (ok|FAIL)$", re.M)


@pytest.fixture
def library(tmp_path):
    argv = ["generate", "cv", *(a for f in FILTERS for a in ("--filter", f)),
            "--layout", "library", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    return tmp_path / "out" / "cv"


def test_the_library_holds_sources_headers_tests_and_build_files(library):
    names = sorted(p.name for p in library.iterdir())
    assert names == sorted(["CMakeLists.txt", "Makefile"] + [
        f"{prefix}{f}.{ext}" for f in FILTERS for prefix, ext in
        (("", "c"), ("", "h"), ("test_", "c"))])   # nothing hidden left by the writer
    test = (library / "test_kf.c").read_text()
    assert '#include "cv/kf.h"' in test
    assert "--layout library" in (library / "kf.h").read_text().split("*/")[0]
    assert ("derive generate cv --filter kf --filter rts --filter sskf --filter fir --layout "
            "library") in (library / "CMakeLists.txt").read_text()


def _errors(output: str) -> dict[str, tuple[float, int, str]]:
    return {m[1]: (float(m[2]), int(m[3]), m[4]) for m in PRINTED.finditer(output)}


def _python_errors(library, steps: int) -> dict[str, float]:
    """The error measure on the same data, computed here: the library's C built through
    cffi, run on the data, compared with the reference by derive verify's measure."""
    model = resolve_model("cv")
    out = {}
    for name in FILTERS:
        data = verification_data(model, name, steps=steps)
        generated = build_c(library / f"{name}.c")
        run = generated.functions["run"]
        result = generated.run(*(data.inputs[a.name] for a in run.arguments if not a.output))
        result = result if isinstance(result, tuple) else (result,)
        out[name] = max(relative_error(np.reshape(r, data.reference[k].shape),
                                       data.reference[k])
                        for r, k in zip(result, ("xs", "Ps")) if k in data.reference)
    return out


def _check_printed(output: str, library) -> None:
    errors = _errors(output)
    assert sorted(errors) == sorted(FILTERS), output
    steps = {s for _, s, _ in errors.values()}
    assert len(steps) == 1
    own = _python_errors(library, steps.pop())
    for name, (error, _, verdict) in errors.items():
        assert verdict == "ok" and error <= LINEAR_TOLERANCE, output
        assert error == pytest.approx(own[name], rel=2e-3, abs=1e-300), name


@needs_cmake
def test_cmake_builds_the_library_and_ctest_runs_its_tests(library, tmp_path):
    build = tmp_path / "build"
    flags = f"-DCMAKE_C_FLAGS={STRICT} -Wdouble-promotion -Wconversion"
    for command in ([CMAKE, "-S", str(library), "-B", str(build), flags],
                    [CMAKE, "--build", str(build)],
                    ["ctest", "--test-dir", str(build), "--output-on-failure"]):
        done = subprocess.run(command, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stdout + done.stderr
    assert "100% tests passed" in done.stdout
    output = "".join(subprocess.run([str(build / f"cv_test_{f}")], capture_output=True,
                                    text=True, check=True).stdout for f in FILTERS)
    _check_printed(output, library)


@needs_make
def test_make_builds_the_library_and_make_check_runs_its_tests(library):
    done = subprocess.run([MAKE, "-C", str(library), f"CFLAGS={STRICT} -Wdouble-promotion "
                           "-Wconversion", "check"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (library / "libcv.a").is_file()
    _check_printed(done.stdout, library)


@pytest.mark.skipif(GCC is None, reason="no gcc")
def test_the_test_program_fails_on_a_wrong_reference(tmp_path):
    """A reference off by 1e-9 relative: the program prints that error and exits 1."""
    model = resolve_model("cv")
    unit = command_unit(model, "kf")
    files, _ = render_library(model, ["kf"], tmp_path, steps=40)
    data = verification_data(model, "kf", steps=40)
    wrong = dataclasses.replace(data, reference={
        k: v * (1.0 + 1e-9) for k, v in data.reference.items()})
    folder = tmp_path / "cv"
    folder.mkdir()
    for name in ("kf.c", "kf.h"):
        (folder / name).write_text(files[name])
    (folder / "test_kf.c").write_text(render_test_program(unit, files["kf.h"], wrong))
    program = tmp_path / "test_kf"
    subprocess.run([GCC, *STRICT_CFLAGS, f"-I{tmp_path}", str(folder / "kf.c"),
                    str(folder / "test_kf.c"), "-lm", "-o", str(program)], check=True)
    done = subprocess.run([str(program)], capture_output=True, text=True, timeout=60)
    error, steps, verdict = _errors(done.stdout)["kf"]
    assert done.returncode == 1 and verdict == "FAIL" and steps == 40
    assert 0.5e-9 < error < 2e-9


def test_library_refuses_python_and_bad_options_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["generate", "cv", "--filter", "kf", "--layout", "library", "--lang",
                 "python", "--out", str(out)]) == 2
    assert main(["generate", "cv", "--filter", "kf", "--layout", "library", "--prefix", "9",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "Traceback" not in err and "--lang python" in err
    assert not (out / "cv").exists()


@needs_make
def test_a_float32_library_builds_under_the_conversion_warnings_within_its_tolerance(tmp_path):
    """--precision float: float arrays, float literals; the test programs' errors within
    the float32 tolerance derive verify --precision float derives for the same data."""
    out = tmp_path / "out"
    assert main(["generate", "mpt3d_a", "--filter", "kf", "--filter", "udkf", "--precision",
                 "float", "--layout", "library", "--out", str(out)]) == 0
    assert "static const float in_z[" in (out / "mpt3d_a" / "test_kf.c").read_text()
    done = subprocess.run([MAKE, "-C", str(out / "mpt3d_a"), f"CFLAGS={STRICT} "
                           "-Wdouble-promotion -Wfloat-conversion -Wconversion", "check"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    errors = _errors(done.stdout)
    assert sorted(errors) == ["kf", "udkf"]
    model = resolve_model("mpt3d_a")
    for name, (error, steps, verdict) in errors.items():
        host = verify_filter(model, name, steps=steps, langs=("c",),
                             options={"precision": "float"})[0]
        assert verdict == "ok" and LINEAR_TOLERANCE < error <= host.tolerance, done.stdout
        assert error == pytest.approx(host.error, rel=2e-3)   # the same float32 C, data


#: A constant-velocity track whose P0 is 10^8 times R (tests/embedded/test_emb_float_verify.py's
#: ill-conditioned model): the KF's update cancels ~1e6 against ~1e6 to leave ~1e-2,
#: beyond float32 (spacing 0.06 at 1e6); its bound says so (kappa >= 1e6).
ILL_CONDITIONED = """\
[model]
name = "illcond"
states = ["s", "v"]
measurements = ["z"]

[discrete]
F = [[1, 1], [0, 1]]
H = [[1, 0]]
Q = [[1e-6, 0], [0, 1e-6]]
R = [[1e-2]]

[initial]
x0 = [0, 0]
P0 = [[1e6, 0], [0, 1e6]]
P0_pattern = "dense"
"""


def test_a_filter_float32_cannot_carry_gets_no_library(tmp_path, capsys):
    model = tmp_path / "illcond.toml"
    model.write_text(ILL_CONDITIONED, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["generate", str(model), "--filter", "kf", "--precision", "float",
                 "--layout", "library", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "float32 cannot carry" in err and err.count("\n") == 1
    assert not (out / "illcond").exists()


@needs_make
@pytest.mark.skipif(bool(TARGETS["cortex-m4"].missing()), reason="no arm-none-eabi tools")
def test_make_cross_builds_the_library_for_cortex_m4_with_the_sizes_derive_reports(library):
    """The Makefile's documented cross build: the archive's objects are those derive size
    measures (same compiler and flags), byte for byte in size."""
    flags = " ".join(["-std=c99", "-Os", "-Wall", "-Wextra", "-Werror", "-pedantic",
                      *CORTEX_M4_FLAGS])
    done = subprocess.run([MAKE, "-C", str(library), "CC=arm-none-eabi-gcc",
                           "AR=arm-none-eabi-ar", f"CFLAGS={flags}", "libcv.a"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    listing = subprocess.run(["arm-none-eabi-size", "-B", str(library / "libcv.a")],
                             capture_output=True, text=True, check=True).stdout
    # "text data bss dec hex kf.o (ex .../libcv.a)"
    archived = {line.split()[5][:-len(".o")]: int(line.split()[0])
                for line in listing.splitlines()[1:]}
    measured = {r.filter: r.object.text for r in sizes("cv", FILTERS, levels=("-Os",))}
    assert archived == measured


def test_an_infinite_tolerance_is_a_c_constant(tmp_path):
    """A float32 bound can be infinite (derive then marks the run failed): the test
    program states it as HUGE_VAL, not ``inf``, which is no C, and compiles."""
    model = resolve_model("cv")
    unit = command_unit(model, "kf")
    files, _ = render_library(model, ["kf"], tmp_path, steps=5)
    data = dataclasses.replace(verification_data(model, "kf", steps=5), tolerance=math.inf)
    folder = tmp_path / "cv"
    folder.mkdir()
    for name in ("kf.c", "kf.h"):
        (folder / name).write_text(files[name])
    source = render_test_program(unit, files["kf.h"], data)
    assert "#define TOLERANCE HUGE_VAL" in source
    (folder / "test_kf.c").write_text(source)
    program = tmp_path / "test_kf"
    subprocess.run([GCC, *STRICT_CFLAGS, f"-I{tmp_path}", str(folder / "kf.c"),
                    str(folder / "test_kf.c"), "-lm", "-o", str(program)], check=True)
    done = subprocess.run([str(program)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "tolerance inf" in done.stdout
