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


# -- zero terms left out: bitwise the dense order -----------------------------------------

SPECIAL = [0.0, -0.0, 0.0, 1.0, -2.5, 1e-300, -1e300, np.inf, np.nan]


def _sparse(seed: int, rows: int, cols: int, zeros: float, special: bool) -> np.ndarray:
    """A random matrix with a share ``zeros`` of exact zeros (signed), and with
    ``special`` a few of -0.0, tiny, huge and non-finite entries."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((rows, cols))
    M[rng.random((rows, cols)) < zeros] = 0.0
    M[rng.random((rows, cols)) < zeros / 4] = -0.0
    if special:
        picks = rng.random((rows, cols)) < 0.1
        M[picks] = rng.choice(SPECIAL, size=int(picks.sum()))
    return M


def _bits(M: np.ndarray) -> bytes:
    return np.ascontiguousarray(M, dtype=float).tobytes()


def _dense_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    a, b = A.tolist(), B.tolist()
    return np.array(ieee_linalg._eliminate(a, b, sparse=False), dtype=float)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.integers(1, 8), st.integers(1, 8),
       st.sampled_from([0.0, 0.5, 0.9]), st.booleans())
def test_a_product_without_its_zero_terms_is_the_dense_product_bit_for_bit(
        seed, n, k, m, zeros, special):
    A, B = _sparse(seed, n, k, zeros, special), _sparse(seed + 1, k, m, zeros, special)
    dense = np.array(ieee_linalg._dense_product(A.tolist(), B.tolist()), dtype=float)
    assert _bits(ieee_linalg.matmul(A, B)) == _bits(dense)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.integers(1, 4),
       st.sampled_from([0.0, 0.5, 0.8]), st.booleans())
def test_a_solve_without_its_zero_terms_is_the_dense_solve_bit_for_bit(
        seed, n, m, zeros, special):
    A = _sparse(seed, n, n, zeros, special) + np.diag(np.full(n, 3.0 * n))
    B = _sparse(seed + 1, n, m, zeros, special)
    try:
        dense = _dense_solve(A, B)
    except np.linalg.LinAlgError:
        with pytest.raises(np.linalg.LinAlgError):
            ieee_linalg.solve(A, B)
        return
    assert _bits(ieee_linalg.solve(A, B)) == _bits(dense)


def test_a_block_diagonal_model_costs_its_blocks():
    """120 blocks of 2 (n = 240): each product touches the non-zero terms only, so the
    doubling of the 120-axis SSKF takes seconds, not the 36 s of every term in Python."""
    calls = []

    class Counted(float):
        def __mul__(self, other):
            calls.append(1)
            return float.__mul__(self, other)
    blocks = [_matrix(seed, 2, 2) for seed in range(120)]
    A = np.zeros((240, 240))
    for i, block in enumerate(blocks):
        A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = block
    rows = [[Counted(v) for v in row] for row in A.tolist()]
    product = ieee_linalg._product(rows, A.tolist())
    assert len(calls) == 120 * 2 * 2 * 2          # per block: 2 x 2 entries of 2 terms
    # each entry a two-term sum: |error| <= 2 eps sum |a||b|, against NumPy's product
    assert np.all(np.abs(np.array(product) - A @ A) <= 4 * EPS * (np.abs(A) @ np.abs(A)))
