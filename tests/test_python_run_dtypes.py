"""The generated Python ``run`` takes real numbers only (as the compiled wrappers do,
derive.build.FilterModule.converted): an array it would change silently (complex, whose
imaginary part would be dropped; bool; str, which NumPy parses; object, where None becomes
NaN; an integer float64 cannot hold; a float wider than float64) is refused with a
DtypeError naming the argument, and integers and float32 it holds exactly are taken."""

from __future__ import annotations

import numpy as np
import pytest

from derive.errors import DtypeError
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
