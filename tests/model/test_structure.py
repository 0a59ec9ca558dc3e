"""Block detection and composition."""

import numpy as np
import pytest
import sympy
from conftest import axis_model

from derive import LinearModel
from derive.errors import SymbolError


def test_composed_model_splits_back_into_its_axes():
    b = axis_model()
    a = LinearModel.compose("a", [b, b, b], ["x", "y", "z"])
    assert a.states == ("sx", "vx", "sy", "vy", "sz", "vz")
    blocks = a.blocks()
    assert [blk.states for blk in blocks] == [(0, 1), (2, 3), (4, 5)]
    assert [blk.measurements for blk in blocks] == [(0,), (1,), (2,)]
    for blk in blocks:
        for k in ("F", "G", "H", "Q", "R"):
            np.testing.assert_array_equal(getattr(blk.model.numeric(), k),
                                          getattr(b.numeric(), k))


def test_blocks_found_under_a_permutation():
    """Interleaved states and measurements: blocks are found whatever the order."""
    F = sympy.Matrix([[1, 0, 1, 0], [0, 1, 0, 2], [0, 0, 1, 0], [0, 0, 0, 1]])
    H = sympy.Matrix([[0, 1, 0, 0], [1, 0, 0, 0]])
    m = LinearModel("perm", ["a", "b", "c", "d"], ["zb", "za"], F, H, sympy.eye(4),
                    sympy.eye(2))
    blocks = m.blocks()
    assert [(blk.states, blk.measurements) for blk in blocks] == [((0, 2), (1,)),
                                                                  ((1, 3), (0,))]


def test_coupling_through_noise_or_R_joins_blocks():
    F, H = sympy.eye(2), sympy.eye(2)
    q = sympy.Matrix([[1, 0.5], [0.5, 1]])
    assert len(LinearModel("n", ["a", "b"], ["y1", "y2"], F, H, q, sympy.eye(2)).blocks()) == 1
    assert len(LinearModel("r", ["a", "b"], ["y1", "y2"], F, H, sympy.eye(2), q).blocks()) == 1
    assert len(LinearModel("i", ["a", "b"], ["y1", "y2"], F, H, sympy.eye(2),
                           sympy.eye(2)).blocks()) == 2


def test_value_zero_decouples():
    k = sympy.Symbol("k")
    F = sympy.Matrix([[1, k], [0, 1]])
    m = LinearModel("z", ["a", "b"], ["y1", "y2"], F, sympy.eye(2), sympy.eye(2), sympy.eye(2),
                    values={"k": 0})
    assert len(m.blocks()) == 2
    free = LinearModel("f", ["a", "b"], ["y1", "y2"], F, sympy.eye(2), sympy.eye(2),
                       sympy.eye(2), parameters=[k])
    assert len(free.blocks()) == 1


def test_unobserved_block_is_an_error():
    m = LinearModel("u", ["a", "b"], ["y"], sympy.eye(2), [[1, 0]], sympy.eye(2), [[1]])
    with pytest.raises(SymbolError, match="'b'.*observed by no measurement"):
        m.blocks()


def test_compose_rejects_a_symbol_with_two_values():
    b1 = axis_model("one", values={"dt": 1, "sq2": 0.01, "sr2": 0.1})
    b2 = axis_model("two", values={"dt": 2, "sq2": 0.01, "sr2": 0.1})
    with pytest.raises(SymbolError, match="'dt' has two values"):
        LinearModel.compose("ab", [b1, b2], ["x", "y"])
