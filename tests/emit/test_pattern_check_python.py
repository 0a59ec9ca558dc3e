"""The generated Python's pattern check (``_require_zero``): one comparison over every
entry outside the pattern and every track, and the message names the first offending
entry in the pattern's order with its value, as the entry-by-entry check did."""

import numpy as np
import pytest

from derive import catalog
from derive.build import load_python
from derive.errors import PatternError
from derive.generation import render_filter


@pytest.fixture(scope="module")
def kf(tmp_path_factory):
    path = tmp_path_factory.mktemp("pattern") / "kf.py"
    path.write_text(render_filter(catalog.load("mpt3d_a"), "kf", "python")["kf.py"])
    return load_python(path)


def _outside(module) -> list[tuple[int, int]]:
    """The (row, column) of every entry outside P's pattern, in the check's order."""
    P = np.eye(6)
    outside = []
    for i in range(6):
        for j in range(i + 1, 6):
            bad = P.copy()
            bad[i, j] = bad[j, i] = 1.0
            try:
                module.step(np.zeros(6), bad, np.zeros(3))
            except PatternError:
                outside.append((i, j))
    return outside


def test_the_first_entry_out_of_the_pattern_is_named_with_its_value(kf):
    outside = _outside(kf)
    assert len(outside) == 12     # three 2x2 blocks of 6 states: 12 pairs outside
    (i1, j1), (i2, j2) = outside[3], outside[7]
    P = np.eye(6)
    P[i2, j2] = P[j2, i2] = 7.0
    P[i1, j1] = P[j1, i1] = float("nan")
    with pytest.raises(PatternError, match=rf"^P\[{i1}\]\[{j1}\] = nan: "):
        kf.step(np.zeros(6), P, np.zeros(3))
    with pytest.raises(PatternError, match=rf"^P0\[{i1}\]\[{j1}\] = nan: "):
        kf.run(np.zeros((4, 3)), np.zeros(6), P)


def test_one_track_out_of_many_is_found_and_its_value_named(kf):
    tracks = 5
    (i, j) = _outside(kf)[-1]
    P0 = np.repeat(np.eye(6)[:, :, None], tracks, axis=2)
    kf.run(np.zeros((3, 3, tracks)), np.zeros((6, tracks)), P0)   # in the pattern: runs
    P0[i, j, 3] = P0[j, i, 3] = -0.25
    with pytest.raises(PatternError, match=rf"^P0\[{i}\]\[{j}\] = -0.25: "):
        kf.run(np.zeros((3, 3, tracks)), np.zeros((6, tracks)), P0)


class _Reads(np.ndarray):
    """An array that counts how often it is indexed."""

    reads = 0

    def __getitem__(self, key):
        type(self).reads += 1
        return np.asarray(self)[key]


def test_an_array_is_checked_in_one_read_not_one_per_entry(kf):
    P = np.eye(6).reshape(36).view(_Reads)
    indices = tuple(6 * i + j for i, j in _outside(kf))
    _Reads.reads = 0
    kf._require_zero(P, indices, 6, "P", "outside")
    assert _Reads.reads == 1
