"""ARM sizes, qemu-arm runs and the library layout for units of the run kind ``sensors``
(several sensors at their own rates, NaN rows between) and for free parameters run at
their examples (ins_gnss: ``dt = { example = 0.01 }``, one p row per step). The data and
tolerance are derive verify's (derive.apps.verify.sensors_case); a free parameter without
an example is one line, exit 2, before any work. Skipped only where a tool is missing."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from derive import generate
from derive.apps.simulate import SENSOR_PERIODS
from derive.apps.targets.arm import run_under_qemu
from derive.apps.targets.data import verification_data
from derive.apps.targets.toolchains import CORTEX_M4_FLAGS, SIZE_LEVELS, TARGETS
from derive.apps.verify import sensors_case
from derive.build import STRICT_CFLAGS
from derive.cli import main
from derive.filters.sensors import sensor_groups
from derive.generation import resolve_model
from derive.options import validate

M4, LINUX = TARGETS["cortex-m4"], TARGETS["arm-linux"]
MAKE = shutil.which("make")
needs_m4 = pytest.mark.skipif(bool(M4.missing()), reason="Cortex-M4 tools missing")
needs_qemu = pytest.mark.skipif(bool(LINUX.missing()), reason="arm-linux tools missing")
needs_make = pytest.mark.skipif(MAKE is None or shutil.which("gcc") is None,
                                reason="no make or gcc")
STEPS = 200
STRICT = " ".join(STRICT_CFLAGS) + " -Wdouble-promotion -Wconversion"
PRINTED = re.compile(r"^\w+ (\w+): largest error (\S+) over (\d+) steps .*: (ok|FAIL)$", re.M)
INS_FUNCTIONS = ("predict", "update_gnss", "update_baro", "run")

CART = """
[model]
name = "cart_free_dt"
states = ["p", "v"]

[parameters]
dt = {{ description = "step (s), free"{example} }}
q = 0.01

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["q*dt", 0], [0, "q*dt"]]

[sensors.gps]
measurements = ["zp"]
H = [[1, 0]]
R = 4

[sensors.speed]
measurements = ["zv"]
H = [[0, 1]]
R = 0.25

[initial]
x0 = [0, 0]
P0 = [[1, 0], [0, 1]]
"""


def _cart(tmp_path, example: str):
    path = tmp_path / "cart_free_dt.toml"
    path.write_text(CART.format(example=example))
    return path


def test_sensors_data_hold_nan_rows_and_p_rows_of_the_example():
    """The run's arguments by their C names: each sensor's rows NaN between its periods,
    p one row per step at the example; the reference and tolerance are verify's."""
    model = resolve_model("ins_gnss")
    data = verification_data(model, "ekf", {"precision": "double"}, steps=STEPS)
    assert list(data.inputs) == ["z_gnss", "z_baro", "u", "x0", "P0", "p"]
    for group, period in zip(sensor_groups(model), SENSOR_PERIODS):
        rows = data.inputs[f"z_{group.name}"]
        assert rows.shape == (STEPS, group.m)
        present = ~np.isnan(rows).any(axis=1)
        assert present.sum() == len(range(0, STEPS, period))
    assert np.isnan(data.inputs["z_baro"]).any()   # baro every 4th step: NaN rows between
    assert np.array_equal(data.inputs["p"], np.full((STEPS, 1), model.examples["dt"]))
    case = sensors_case(model, "ekf", STEPS, 7, validate("ekf", {"precision": "double"}))
    assert data.tolerance == case.tolerance and data.bound is None
    assert np.array_equal(data.reference["xs"], case.reference.xs)


@needs_qemu
def test_ins_gnss_ekf_under_qemu_agrees_with_the_reference_within_verify_tolerance():
    model = resolve_model("ins_gnss")
    case = sensors_case(model, "ekf", STEPS, 7, validate("ekf", {"precision": "double"}))
    (run,) = run_under_qemu("ins_gnss", ["ekf"], {"precision": "double"}, steps=STEPS)
    assert (run.filter, run.precision, run.steps) == ("ekf", "double", STEPS)
    assert run.tolerance == case.tolerance
    assert run.passed and 0.0 < run.error <= case.tolerance, run.line()
    assert run.printed == pytest.approx(run.error, rel=2e-3)   # the program's own measure


@needs_qemu
def test_a_gated_float32_sensors_run_under_qemu_is_held_to_its_float32_bound(tmp_path):
    """float-sensors' bound for a sensors unit: a float32 run is judged by it (gated: the
    run also writes nis_ and applied_ outputs)."""
    path = _cart(tmp_path, ", example = 0.1")
    runs = run_under_qemu(str(path), ["kf"], {"precision": "float", "gate": 0.999},
                          steps=STEPS)
    (run,) = runs
    assert run.bound is not None and run.bound.meaningful
    assert run.tolerance == run.bound.value
    assert run.passed and 1e-12 < run.error <= run.tolerance, run.line()


def _object_functions(source, level, tmp_path):
    obj = tmp_path / f"own{level}.o"
    subprocess.run(["arm-none-eabi-gcc", "-std=c99", "-Wall", "-Wextra", "-Werror",
                    "-pedantic", *CORTEX_M4_FLAGS, level, "-c", str(source), "-o", str(obj)],
                   check=True)
    listing = subprocess.run(["arm-none-eabi-nm", "-S", str(obj)], check=True,
                             capture_output=True, text=True).stdout
    return {parts[3]: int(parts[1], 16) for parts in map(str.split, listing.splitlines())
            if len(parts) == 4 and parts[2] in "Tt"}


@needs_m4
def test_derive_size_prints_every_function_of_ins_gnss_in_both_precisions(tmp_path, capsys):
    assert main(["size", "ins_gnss"]) == 0
    rows = {}
    for line in capsys.readouterr().out.splitlines():
        parts = line.split(None, 7)
        if parts[:2] == ["ins_gnss", "ekf"]:
            rows[parts[2], parts[3]] = dict(
                (name, int(b)) for name, b in (f.split() for f in parts[7].split(", ")))
    assert sorted(rows) == sorted((p, lv) for p in ("float", "double") for lv in SIZE_LEVELS)
    for precision in ("float", "double"):
        out = tmp_path / precision
        generate("ins_gnss", ["ekf"], "c", out, options={"precision": precision})
        for level in SIZE_LEVELS:
            own = _object_functions(out / "ins_gnss" / "ekf.c", level, tmp_path)
            assert rows[precision, level] == {
                name.removeprefix("ins_gnss_ekf_"): size for name, size in own.items()}
            assert sorted(rows[precision, level]) == sorted(INS_FUNCTIONS)


@needs_make
def test_the_ins_gnss_library_builds_with_make_and_its_test_program_passes(tmp_path):
    out = tmp_path / "out"
    assert main(["generate", "ins_gnss", "--layout", "library", "--precision", "double",
                 "--out", str(out)]) == 0
    folder = out / "ins_gnss"
    test = (folder / "test_ekf.c").read_text()
    assert "NAN" in test and f"in_p[{STEPS}]" in test   # NaN rows, one p row per step
    done = subprocess.run([MAKE, "-C", str(folder), f"CFLAGS={STRICT}", "check"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    ((name, error, steps, verdict),) = PRINTED.findall(done.stdout)
    tolerance = verification_data(resolve_model("ins_gnss"), "ekf",
                                  {"precision": "double"}, steps=STEPS).tolerance
    assert (name, int(steps), verdict) == ("ekf", STEPS, "ok")
    assert 0.0 < float(error) <= tolerance


@needs_make
@pytest.mark.parametrize("precision", ["double", "float"])
def test_a_gated_sensors_library_with_a_free_parameter_passes_make_check(tmp_path,
                                                                        precision):
    path = _cart(tmp_path, ", example = 0.1")
    out = tmp_path / "out"
    assert main(["generate", str(path), "--filter", "kf", "--gate", "0.999", "--precision",
                 precision, "--layout", "library", "--out", str(out)]) == 0
    flags = STRICT + (" -Wfloat-conversion" if precision == "float" else "")
    done = subprocess.run([MAKE, "-C", str(out / "cart_free_dt"), f"CFLAGS={flags}", "check"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    data = verification_data(resolve_model(str(path)), "kf",
                             {"precision": precision, "gate": 0.999}, steps=STEPS)
    ((_, error, _, verdict),) = PRINTED.findall(done.stdout)
    assert verdict == "ok" and float(error) <= data.tolerance
    assert (data.bound is not None) == (precision == "float")


def test_a_free_parameter_without_an_example_is_one_refusal_line(tmp_path, capsys):
    path = _cart(tmp_path, "")
    out = tmp_path / "out"
    commands = [["size", str(path), "--qemu"],
                ["generate", str(path), "--layout", "library", "--out", str(out)]]
    for argv in commands:
        assert main(argv) == 2
        captured = capsys.readouterr()
        assert captured.err.count("\n") == 1, captured.err
        assert "['dt'] have no example" in captured.err and "Traceback" not in captured.err
        assert "model" not in captured.out   # refused before any table
    assert not out.exists()


def test_free_parameters_outside_a_sensors_run_run_at_their_examples(tmp_path, capsys):
    """One sensor, no gate: not a sensors run; the library's test program runs dt at its
    example as derive verify does (p one row per step)."""
    path = tmp_path / "one_free_dt.toml"
    path.write_text(CART.format(example=", example = 0.1").split("[sensors.speed]")[0]
                    + "[initial]\nx0 = [0, 0]\nP0 = [[1, 0], [0, 1]]\n")
    out = tmp_path / "out"
    assert main(["generate", str(path), "--filter", "kf", "--layout", "library",
                 "--out", str(out)]) == 0, capsys.readouterr().err
    library = out / "cart_free_dt"
    assert "cart_free_dt_kf_run(STEPS, in_z, in_x0, in_P0, out_xs, out_Ps, in_p, 1)" in (
        library / "test_kf.c").read_text()   # p: one row per step
    done = subprocess.run(["make", "-C", str(library), "check"], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and "): ok" in done.stdout, done.stdout + done.stderr
