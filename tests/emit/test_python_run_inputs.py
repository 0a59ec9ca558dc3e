"""The generated Python ``run``'s inputs. It takes real numbers only (as the compiled
wrappers do, derive.build.FilterModule.converted): an array it would change silently
(complex, whose imaginary part would be dropped; bool; str, which NumPy parses; object,
where None becomes NaN; an integer float64 cannot hold; a float wider than float64) is
refused with a DtypeError naming the argument, and integers and float32 it holds exactly
are taken. Per-step inputs whose step counts differ are refused naming the input and where
``steps`` came from (the rows of the first per-step input)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from derive.build import load_python
from derive.errors import DtypeError, ShapeError
from derive.pipeline import load_generated


@pytest.fixture(scope="module")
def kf():
    return load_generated("mpt3d_b", "kf", lang="python").python


@pytest.mark.parametrize("make", [
    lambda z: z + 0j, lambda z: z.astype(bool), lambda z: z.astype(str),
    lambda z: np.array([[None], [1.0], [1.0]], dtype=object),
    lambda z: np.full(z.shape, 2**53 + 1, dtype=np.int64),
    lambda z: z.astype(np.longdouble) if np.dtype(np.longdouble).itemsize > 8 else z + 0j,
], ids=["complex", "bool", "str", "object", "int above 2^53", "longdouble"])
def test_an_array_run_would_change_is_refused_naming_it(kf, make):
    zs = np.ones((3, 1))
    with pytest.raises(DtypeError, match=r"^run: zs "):
        kf.run(make(zs), np.zeros(2), np.eye(2))
    with pytest.raises(DtypeError, match=r"^run: P0 "):
        kf.run(zs, np.zeros(2), np.eye(2) + 0j)


def test_integers_and_float32_it_holds_exactly_are_taken(kf):
    rng = np.random.default_rng(2)
    zs = rng.integers(-5, 5, size=(40, 1))
    expected = kf.run(zs.astype(float), np.zeros(2), np.eye(2))
    for given in (zs, zs.astype(np.int32), zs.astype(np.float32), zs.tolist()):
        got = kf.run(given, [0, 0], np.eye(2, dtype=np.float32))
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])


def test_a_step_count_that_differs_names_where_steps_came_from():
    """ins_gnss's run takes z_gnss, z_baro, us and p rows per step: steps are z_gnss's
    rows."""
    module = load_python(Path(__file__).parents[2] / "generated" / "ins_gnss" / "ekf.py")
    rows = {"z_gnss": np.zeros((100, 6)), "z_baro": np.zeros(100), "us": np.zeros((100, 6))}
    start = (np.zeros(16), np.eye(16))
    with pytest.raises(ShapeError, match=r"^run: us must have shape \(steps, 6\), "
                                         r"steps = 100 as z_gnss has, then any track axes; "
                                         r"got \(99, 6\)$"):
        module.run(rows["z_gnss"], rows["z_baro"], rows["us"][:99], *start, [0.01])
    with pytest.raises(ShapeError, match=r"^run: p must have shape \(1,\) or \(steps, 1\), "
                                         r"steps = 100 as z_gnss has"):
        module.run(*rows.values(), *start, np.full((99, 1), 0.01))


def test_one_parameter_may_be_given_as_a_number():
    """A model with one free parameter (ins_gnss: dt) takes it as a number too, as the C
    wrapper does: the same result as the row [dt]."""
    module = load_python(Path(__file__).parents[2] / "generated" / "ins_gnss" / "ekf.py")
    rng = np.random.default_rng(4)
    us = rng.normal(scale=0.01, size=(20, 6)) + [0, 0, 0, 0, 0, -9.80665]
    nan = np.full((20, 6), np.nan)
    start = (np.r_[1.0, np.zeros(15)], np.eye(16) * 0.01)
    as_row = module.run(nan, np.full(20, np.nan), us, *start, [0.01])
    as_number = module.run(nan, np.full(20, np.nan), us, *start, 0.01)
    for a, b in zip(as_row, as_number, strict=True):
        np.testing.assert_array_equal(a, b)
