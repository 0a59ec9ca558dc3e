"""The error measure of derive verify (derive.apps.verify.relative_error): an array of
small numbers is judged at its own size, a step of zeros is not divided by its noise, and
the library layout's C test program computes the same figure."""
import dataclasses
import re
import shutil
import subprocess

import numpy as np
import pytest
import sympy

from derive import LinearModel, reference
from derive.apps.float_tolerance import error_floor
from derive.apps.targets.data import verification_data
from derive.apps.targets.library import render_library
from derive.apps.verify import (
    LINEAR_TOLERANCE,
    linear_run,
    relative_error,
    verify_modules,
)
from derive.build import STRICT_CFLAGS
from derive.emit.library import render_test_program
from derive.generation import command_unit
from derive.pipeline import load_generated

SCALE = 1e-20
"""Q, R and P0 times SCALE: P times SCALE, the gain and the states' sizes unchanged."""


def scaled_model() -> LinearModel:
    """A constant-velocity axis whose covariances are ~1e-20."""
    dt, q, r = sympy.symbols("dt q r")
    return LinearModel("tiny", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, dt]], [[q]], [[r]],
                       G=[[dt / 2], [1]], P0=[[SCALE, 0], [0, SCALE]],
                       values={"dt": 1, "q": SCALE, "r": SCALE})


def reference_run(model, steps: int = 200):
    num = model.numeric()
    zs = linear_run(model, steps, seed=7)
    return reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)


def test_a_doubled_P_of_1e_minus_20_is_a_100_percent_error():
    _, Ps = reference_run(scaled_model())
    assert np.abs(Ps).max() < 1e3 * SCALE            # the model is what the test says
    wrong = 2 * Ps                                   # off by P itself, exactly
    assert relative_error(wrong, Ps) == 1.0
    assert relative_error(Ps, Ps) == 0.0


class Doubled:
    """A generated module whose run returns twice the covariances."""

    def __init__(self, module):
        self.module = module

    def __getattr__(self, name):
        return getattr(self.module, name)

    def run(self, *args, **kwargs):
        xs, Ps = self.module.run(*args, **kwargs)
        return xs, 2 * np.asarray(Ps)


@pytest.mark.parametrize("lang", ["python", "c"])
def test_derive_verify_fails_a_doubled_tiny_P_and_passes_the_right_one(tmp_path, lang):
    model = scaled_model()
    generated = load_generated(model, "kf", {}, lang, tmp_path)
    right, = verify_modules(model, "kf", {lang: generated.module(lang)}, steps=200)
    wrong, = verify_modules(model, "kf", {lang: Doubled(generated.module(lang))}, steps=200)
    assert right.passed and right.error <= LINEAR_TOLERANCE
    assert not wrong.passed   # twice P: 100 %, give or take the right run's rounding
    assert wrong.error == pytest.approx(1.0, abs=2 * right.error)


def test_a_step_of_zeros_without_difference_counts_zero():
    ref = np.array([[0.0, 0.0], [3.0, -4.0], [0.0, 0.0]])
    assert relative_error(ref.copy(), ref) == 0.0
    assert relative_error(np.zeros((4, 3)), np.zeros((4, 3))) == 0.0


def test_a_step_of_zeros_is_judged_at_the_typical_step_not_its_noise():
    ref = np.array([[0.0, 0.0], [1e-6, 2e-6], [3e-6, 1e-6], [2e-6, 2e-6]])
    noisy = ref + [[1e-22, 0.0], [0, 0], [0, 0], [0, 0]]
    floor = error_floor(np.abs(ref).max(axis=1))
    assert floor == 2e-6                             # lower median of 2e-6, 3e-6, 2e-6
    assert relative_error(noisy, ref) == 1e-22 / floor


def test_a_difference_against_an_all_zero_reference_is_infinite():
    assert relative_error(np.full((2, 2), 1e-300), np.zeros((2, 2))) == np.inf


def test_the_floor_is_at_most_1_so_large_arrays_keep_the_old_measure():
    ref = np.array([[0.0], [1e6], [2e6]])
    assert error_floor(np.abs(ref).max(axis=1)) == 1.0
    assert relative_error(ref + [[1e-3], [0], [0]], ref) == 1e-3


def test_a_large_start_does_not_set_the_scale_of_the_small_steps_after_it():
    """P0 = 1 settling to 1e-20: the settled steps are the median, judged at their size."""
    ref = np.concatenate([[[1.0]], np.full((9, 1), 1e-20)])
    assert relative_error(2 * ref, ref) == 1.0


PRINTED = re.compile(r"largest error (\S+) over (\d+) steps")


def run_test_program(tmp_path, data):
    """Build the library layout's C test program of the tiny model's KF holding ``data``
    (templates/library/test.c.jinja); (its printed error, its exit status, {output: the
    values --states prints})."""
    model = scaled_model()
    unit = command_unit(model, "kf")
    files, _ = render_library(model, ["kf"], tmp_path, steps=data.steps)
    folder = tmp_path / model.name
    folder.mkdir()
    for name in ("kf.c", "kf.h"):
        (folder / name).write_text(files[name])
    (folder / "test_kf.c").write_text(render_test_program(unit, files["kf.h"], data))
    program = tmp_path / "test_kf"
    subprocess.run([shutil.which("gcc"), *STRICT_CFLAGS, f"-I{tmp_path}", str(folder / "kf.c"),
                    str(folder / "test_kf.c"), "-lm", "-o", str(program)], check=True,
                   timeout=120)
    done = subprocess.run([str(program), "--states"], capture_output=True, text=True,
                          timeout=60)
    states = {}
    for line in done.stdout.splitlines():
        label, *values = line.split(" ")
        if label in data.reference:
            states[label] = np.array([float.fromhex(v) for v in values])
    return float(PRINTED.search(done.stdout)[1]), done.returncode, states


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc")
@pytest.mark.parametrize("halved", [False, True])
def test_the_library_test_program_computes_relative_error_on_a_tiny_model(tmp_path, halved):
    """On the model with P ~ 1e-20 the C test program prints relative_error of its own
    outputs (to the 4 digits it prints): within the bar for the right reference, 1 (100 %)
    for a reference whose P is halved, which it fails (exit status 1); with the floor 1 it
    printed ~1e-20 for both."""
    data = verification_data(scaled_model(), "kf", steps=40)
    if halved:
        data = dataclasses.replace(data, reference={**data.reference,
                                                    "Ps": data.reference["Ps"] / 2})
    printed, status, states = run_test_program(tmp_path, data)
    assert sorted(states) == ["Ps", "xs"]
    own = max(relative_error(np.reshape(states[k], data.reference[k].shape), data.reference[k])
              for k in states)
    assert printed == pytest.approx(own, rel=1e-3, abs=1e-300)
    if halved:
        # out - ref/2 = ref/2 + (out - ref): 100 %, give or take twice the right error
        assert own == pytest.approx(1.0, abs=2 * LINEAR_TOLERANCE) and status == 1
    else:
        assert own <= LINEAR_TOLERANCE and status == 0
