"""Status numbers are the file's, not the program's (robustness item "C status numbers
overlap across programs"): the programs of one generated file number their checks apart,
so a status (what a C function returns; what run returns from whichever program failed)
names exactly one check. Before, each program counted from 1: udkf's step 1 and enter 1,
a sensors unit's predict 1 and update_gps 1, and run's error named both ("... or ...")."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import LinearModel, generate, interface, load_python
from derive.errors import NumericalError
from derive.modelfile import loads_model
from derive.pipeline import load_generated

ROOT = Path(__file__).resolve().parents[2]
HEADERS = sorted((ROOT / "generated").glob("*/*.h"))


@pytest.mark.parametrize("header", HEADERS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_every_status_of_a_generated_file_names_one_check(header):
    """In the interface line, the status list and the enum: one check per number."""
    text = header.read_text()
    described = interface.read(text)
    numbers = Counter(s.number for s in described.statuses)
    assert not [n for n, count in numbers.items() if count > 1], numbers
    assert all(len(texts) == 1 for texts in described.messages().values())
    enum = re.findall(r"_STATUS_\w+ = (\d+)", text)
    assert len(enum) == len(set(enum)) == len(described.statuses) + bool(enum)


def test_the_catalog_has_files_whose_programs_share_a_run():
    """The property above is not empty: files with checks in two programs exist (udkf's
    step and enter), their numbers now consecutive across the file."""
    described = interface.read((ROOT / "generated" / "cv" / "udkf.h").read_text())
    programs = [s.program for s in described.statuses]
    assert {"step", "enter"} <= set(programs)
    assert [s.number for s in described.statuses] == list(range(1, len(programs) + 1))


def test_a_failed_enter_in_a_c_run_names_only_its_own_check():
    """udkf's run calls enter (P0's factorisation) and step: a P0 that is not positive
    semidefinite fails enter's pivot check, and the error names that check alone."""
    generated = load_generated("cv", "udkf", {}, lang="c")
    with pytest.raises(NumericalError) as raised:
        generated.c.run(np.zeros((3, 1)), np.zeros(2), np.diag([1.0, -1.0]))
    message = str(raised.value)
    assert "enter: P is not positive semidefinite: pivot 1" in message
    assert " or " not in message and "step:" not in message


SENSORS = """
[model]
name = "cart"
states = ["p", "v"]

[parameters]
dt = { description = "step, one value per step in p" }

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["dt", 0], [0, "dt"]]

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


def test_a_failed_update_in_a_sensors_run_names_only_that_sensor():
    """A NaN dt makes the first update's S NaN: the C run's status is update_gps's check
    (it named update_speed's too, the same number)."""
    generated = load_generated(loads_model(SENSORS), "kf", {}, lang="c")
    steps = 4
    zs = np.ones((steps, 1))
    dt = np.full((steps, 1), np.nan)
    with pytest.raises(NumericalError) as raised:
        generated.c.run(zs, zs, np.zeros(2), np.eye(2), dt)
    message = str(raised.value)
    assert "update_gps: S is not positive definite" in message
    assert " or " not in message and "update_speed" not in message


def test_the_pattern_status_of_each_program_is_its_own():
    """The zero checks of a program (its P pattern) share one status, after the program's
    positive checks and apart from every other program's."""
    model = LinearModel("axes", ["a", "b"], ["za", "zb"], [[1, 0], [0, 1]],
                        [[1, 0], [0, 1]], [[0.1, 0], [0, 0.1]], [[1, 0], [0, 1]],
                        P0=[[1, 0], [0, 1]], P0_pattern="diagonal")
    generated = load_generated(model, "udkf", {}, lang="c")
    described = generated.c.interface
    by_number = Counter(s.number for s in described.statuses)
    assert max(by_number.values()) == 1
    assert {s.program for s in described.statuses if s.zero} >= {"enter"}


def test_the_update_first_ikf_names_P0_whose_pivot_fails(tmp_path):
    """With start=update step 0 inverts P0 itself (no prediction): a P0 that is not
    positive definite is named as P0, not as a predicted P."""
    model = LinearModel("cv_ikf", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]],
                        [[0.01, 0], [0, 0.01]], [[1.0]], P0=np.eye(2).tolist())
    generate(model, ["ikf"], lang="python", out=tmp_path, options={"start": "update"})
    ikf = load_python(tmp_path / "cv_ikf" / "ikf.py")
    with pytest.raises(NumericalError, match=r"^step 0: P0 is not positive definite"):
        ikf.run(np.ones((3, 1)), np.zeros(2), -np.eye(2))
    assert ikf.run(np.ones((3, 1)), np.zeros(2), np.eye(2))[0].shape == (3, 2)


def test_the_ikf_names_the_matrix_whose_pivot_fails(tmp_path):
    """A free R given negative: the IKF's LDL^T solve of R fails at its first pivot, and
    the status says R (it said "S is not positive definite", and an IKF has no S)."""
    r = sympy.Symbol("r", real=True)
    model = LinearModel("free_r", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]], [[0.01]],
                        [[r]], G=[[0.5], [1]], P0=np.eye(2).tolist(), parameters=[r])
    generate(model, ["ikf"], lang="python", out=tmp_path)
    ikf = load_python(tmp_path / "free_r" / "ikf.py")
    with pytest.raises(NumericalError, match=r"^step 0: R is not positive definite: pivot 0"):
        ikf.run(np.ones((3, 1)), np.zeros(2), np.eye(2), np.full((3, 1), -1.0))
