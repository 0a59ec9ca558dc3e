"""Matrix products and solves whose every bit is the same on every machine.

The steady-state filters (SSKF, SSLF, JSSKLF, FIR, N-step prediction) write numbers
computed off line into generated code.  NumPy's ``@`` and ``numpy.linalg.solve`` call the
BLAS and LAPACK kernels chosen for the CPU at hand, which sum in different orders (and
fuse multiply-adds or not): the same model gave constants that differ in the last digits
on an AMD EPYC and an Intel Xeon, so ``generated/`` was not the same file on both.  Here
each result is Python floats (IEEE double, one rounding per operation, no contraction)
combined in one fixed order: a product's sums run over k from first to last, a solve is
Gaussian elimination with partial pivoting (the first row of largest magnitude), rows
eliminated top to bottom and back-substituted bottom to top.  The matrices are small
(the catalog's are at most a few dozen states), so plain Python is fast enough.

Arguments are anything :func:`numpy.asarray` takes; results are float64 arrays.
"""

from __future__ import annotations

import numpy as np


def _rows(M) -> list[list[float]]:
    A = np.asarray(M, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"expected a matrix, got an array of shape {A.shape}")
    return A.tolist()


def _product(A: list[list[float]], B: list[list[float]]) -> list[list[float]]:
    columns = list(zip(*B)) if B else []
    if A and len(A[0]) != len(B):
        raise ValueError(f"matmul: shapes ({len(A)}, {len(A[0])}) and ({len(B)}, ...) "
                         "do not match")
    out = []
    for row in A:
        out_row = []
        for column in columns:
            total = 0.0
            for a, b in zip(row, column):
                total += a * b
            out_row.append(total)
        out.append(out_row)
    return out


def matmul(*matrices) -> np.ndarray:
    """``M1 @ M2 @ ...``, from the left."""
    rows = _rows(matrices[0])
    for M in matrices[1:]:
        rows = _product(rows, _rows(M))
    return np.array(rows, dtype=float).reshape(len(rows), -1 if rows and rows[0] else 0)


def solve(A, B) -> np.ndarray:
    """``X`` with ``A X = B`` (``B`` a matrix); numpy.linalg.LinAlgError when ``A`` is
    singular (an exactly zero pivot)."""
    a, b = _rows(A), _rows(B)
    n = len(a)
    if any(len(row) != n for row in a) or len(b) != n:
        raise ValueError(f"solve: A must be square and B have its rows, got "
                         f"{np.shape(A)} and {np.shape(B)}")
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(a[r][col]))
        if a[pivot][col] == 0.0:
            raise np.linalg.LinAlgError("Singular matrix")
        if pivot != col:
            a[col], a[pivot] = a[pivot], a[col]
            b[col], b[pivot] = b[pivot], b[col]
        head, rhs = a[col], b[col]
        for r in range(col + 1, n):
            factor = a[r][col] / head[col]
            if factor == 0.0:
                continue
            row = a[r]
            for c in range(col + 1, n):
                row[c] -= factor * head[c]
            row[col] = 0.0
            target = b[r]
            for c in range(len(target)):
                target[c] -= factor * rhs[c]
    x: list[list[float]] = [[] for _ in range(n)]
    for r in reversed(range(n)):
        out = []
        for c in range(len(b[r])):
            total = b[r][c]
            for k in range(r + 1, n):
                total -= a[r][k] * x[k][c]
            out.append(total / a[r][r])
        x[r] = out
    return np.array(x, dtype=float).reshape(n, len(b[0]) if n else 0)


def inverse(A) -> np.ndarray:
    """``A⁻¹`` (:func:`solve` of the identity)."""
    return solve(A, np.eye(np.shape(A)[0]))


def power(A, k: int) -> np.ndarray:
    """``A**k`` for ``k >= 0`` by repeated squaring (the bits of ``k`` from the lowest,
    each square multiplied in from the right)."""
    out = np.eye(np.shape(A)[0])
    square = np.asarray(A, dtype=float)
    while k:
        if k & 1:
            out = matmul(out, square)
        k >>= 1
        if k:
            square = matmul(square, square)
    return out
