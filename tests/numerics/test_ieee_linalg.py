"""derive.ieee_linalg: products and solves in one fixed order of IEEE double operations,
against NumPy's (whose kernels differ between CPUs) at a tolerance derived from their
error bounds, and the errors it raises."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import ieee_linalg

EPS = np.finfo(float).eps
SETTINGS = settings(max_examples=60, deadline=None)


def _matrix(seed: int, rows: int, cols: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((rows, cols))


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 9), st.integers(1, 9), st.integers(1, 9))
def test_matmul_agrees_with_numpy_within_the_bound_of_a_sum(seed, n, k, m):
    A, B = _matrix(seed, n, k), _matrix(seed + 1, k, m)
    got = ieee_linalg.matmul(A, B)
    # each entry is a k-term sum: |error| <= k eps sum_k |a||b| for either order
    bound = 2 * k * EPS * (np.abs(A) @ np.abs(B))
    assert got.shape == (n, m)
    assert np.all(np.abs(got - A @ B) <= bound)


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 9), st.integers(1, 4))
def test_solve_agrees_with_numpy_on_well_conditioned_systems(seed, n, m):
    A = _matrix(seed, n, n) + 3 * n * np.eye(n)     # diagonally dominant: cond(A) < 3
    B = _matrix(seed + 1, n, m)
    got = ieee_linalg.solve(A, B)
    assert got.shape == (n, m)
    # backward-stable elimination: residual a small multiple of n eps |A| |X|
    residual = np.abs(A @ got - B)
    assert np.all(residual <= 8 * n * EPS * (np.abs(A) @ np.abs(got) + np.abs(B)))
    cond = np.linalg.cond(A)
    assert np.allclose(got, np.linalg.solve(A, B), rtol=16 * n * cond * EPS,
                       atol=16 * n * cond * EPS * np.abs(got).max())


def test_solve_pivots_on_the_largest_entry():
    A = np.array([[1e-20, 1.0], [1.0, 1.0]])
    got = ieee_linalg.solve(A, np.array([[1.0], [2.0]]))
    assert np.allclose(got, [[1.0], [1.0]], rtol=4 * EPS)   # unpivoted: x0 = 0


def test_inverse_and_power():
    A = np.array([[2.0, 1.0], [0.5, 3.0]])
    assert np.allclose(ieee_linalg.inverse(A) @ A, np.eye(2), atol=8 * EPS)
    for k in (0, 1, 2, 7, 64):
        assert np.allclose(ieee_linalg.power(A, k), np.linalg.matrix_power(A, k),
                           rtol=4 * k * EPS + EPS)


def test_singular_and_misshaped_inputs_are_refused():
    with pytest.raises(np.linalg.LinAlgError):
        ieee_linalg.solve(np.zeros((2, 2)), np.eye(2))
    with pytest.raises(ValueError, match="square"):
        ieee_linalg.solve(np.ones((2, 3)), np.ones((2, 1)))
    with pytest.raises(ValueError, match="do not match"):
        ieee_linalg.matmul(np.ones((2, 3)), np.ones((2, 3)))


def test_one_order_of_operations_whatever_numpy_links():
    """The result is the left-to-right sum of Python float products, bit for bit."""
    A, B = _matrix(7, 5, 6), _matrix(8, 6, 4)
    rows, cols = A.tolist(), B.T.tolist()
    expected = []
    for row in rows:
        out = []
        for col in cols:
            total = 0.0
            for a, b in zip(row, col):
                total += a * b
            out.append(total)
        expected.append(out)
    assert ieee_linalg.matmul(A, B).tolist() == expected
