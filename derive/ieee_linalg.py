"""Matrix products and solves whose every bit is the same on every machine.

The steady-state filters (SSKF, SSLF, JSSKLF, FIR, N-step prediction) write numbers
computed off line into generated code.  NumPy's ``@`` and ``numpy.linalg.solve`` call the
BLAS and LAPACK kernels chosen for the CPU at hand, which sum in different orders (and
fuse multiply-adds or not): the same model gave constants that differ in the last digits
on an AMD EPYC and an Intel Xeon, so ``generated/`` was not the same file on both.  Here
each result is Python floats (IEEE double, one rounding per operation, no contraction)
combined in one fixed order: a product's sums run over k from first to last, a solve is
Gaussian elimination with partial pivoting (the first row of largest magnitude), rows
eliminated top to bottom and back-substituted bottom to top.

Terms with an exactly zero factor are left out, which leaves every bit as it is: a sum
that starts at +0.0 is never -0.0 (two opposite numbers sum to +0.0), so adding a zero
term to it changes nothing, provided the other factor is finite (and, in a solve, where
sums start from an entry, no entry is -0.0); otherwise the dense order runs.
A model of k independent blocks, whose matrices are nearly all zeros, costs k times a
block, not k³ (the SSKF of 120 axes, n = 240, took 36 s in plain Python without it).

Arguments are anything :func:`numpy.asarray` takes; results are float64 arrays.
"""

from __future__ import annotations

import math

import numpy as np


def _rows(M) -> list[list[float]]:
    A = np.asarray(M, dtype=float)
    if A.ndim != 2:
        raise ValueError(f"expected a matrix, got an array of shape {A.shape}")
    return A.tolist()


def _finite(rows: list[list[float]]) -> bool:
    return all(math.isfinite(v) for row in rows for v in row)


def _ordinary(rows: list[list[float]]) -> bool:
    """Every entry finite and none -0.0: operands whose zero terms may be left out."""
    return all(math.isfinite(v) and (v != 0.0 or math.copysign(1.0, v) > 0)
               for row in rows for v in row)


def _product(A: list[list[float]], B: list[list[float]]) -> list[list[float]]:
    if A and len(A[0]) != len(B):
        raise ValueError(f"matmul: shapes ({len(A)}, {len(A[0])}) and ({len(B)}, ...) "
                         "do not match")
    if not (_finite(A) and _finite(B)):
        return _dense_product(A, B)
    # each entry's sum over k in order, its zero terms left out: row i of the product
    # gathers a_ik times the non-zero entries of row k of B, k ascending
    width = len(B[0]) if B else 0
    nonzero = [[(j, b) for j, b in enumerate(row) if b != 0.0] for row in B]
    out = []
    for row in A:
        total = [0.0] * width
        for k, a in enumerate(row):
            if a != 0.0:
                for j, b in nonzero[k]:
                    total[j] += a * b
        out.append(total)
    return out


def _dense_product(A: list[list[float]], B: list[list[float]]) -> list[list[float]]:
    columns = list(zip(*B)) if B else []
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
    if _ordinary(a) and _ordinary(b):
        x = _eliminate(a, b, sparse=True)
        # an entry once not finite stays so: all finite, no skipped term met one
        if all(_finite(rows) for rows in (a, b, x)):
            return _matrix(x, n, b)
        a, b = _rows(A), _rows(B)
    return _matrix(_eliminate(a, b, sparse=False), n, b)


def _matrix(x: list[list[float]], n: int, b: list[list[float]]) -> np.ndarray:
    return np.array(x, dtype=float).reshape(n, len(b[0]) if n else 0)


def _eliminate(a: list[list[float]], b: list[list[float]], sparse: bool
               ) -> list[list[float]]:
    """Gaussian elimination of ``a x = b`` in place, then back substitution; ``sparse``:
    terms with a zero factor left out (exact when ``a`` and ``b`` hold no -0.0, which
    elimination never makes, and every value stays finite)."""
    n = len(a)
    width = len(b[0]) if b else 0
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(a[r][col]))
        if a[pivot][col] == 0.0:
            raise np.linalg.LinAlgError("Singular matrix")
        if pivot != col:
            a[col], a[pivot] = a[pivot], a[col]
            b[col], b[pivot] = b[pivot], b[col]
        head, rhs = a[col], b[col]
        across = [c for c in range(col + 1, n) if not sparse or head[c] != 0.0]
        along = [c for c in range(width) if not sparse or rhs[c] != 0.0]
        for r in range(col + 1, n):
            factor = a[r][col] / head[col]
            if factor == 0.0:
                continue
            row = a[r]
            for c in across:
                row[c] -= factor * head[c]
            row[col] = 0.0
            target = b[r]
            for c in along:
                target[c] -= factor * rhs[c]
    x: list[list[float]] = [[] for _ in range(n)]
    for r in reversed(range(n)):
        row = a[r]
        known = [k for k in range(r + 1, n) if not sparse or row[k] != 0.0]
        out = []
        for c in range(len(b[r])):
            total = b[r][c]
            for k in known:
                total -= row[k] * x[k][c]
            out.append(total / row[r])
        x[r] = out
    return x


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
