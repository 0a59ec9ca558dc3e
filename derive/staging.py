"""Staged matrix algebra on a :class:`~derive.program.Program`.

Every function takes sympy matrices whose entries are atoms (input elements,
temporaries, numbers, possibly negated) and returns such a matrix: each
non-trivial result entry becomes one temporary through ``prog.let``; an entry
whose terms are all negative is staged positive and returned as ``-t``, so its
sign folds into the sums that use it (``0 - t`` costs nothing).  sympy folds ``0*a``, ``1*a``
and ``a + 0`` as the entries are built, so structurally zero entries never
produce temporaries and independent blocks stay decoupled (an exactly zero
``S[i, j]`` of a block-diagonal ``S`` gives an exactly zero ``L[i, j]`` in
:func:`ldl`).  Stage sums before scaling them: sympy distributes a numeric
factor over a sum (``2*(a + b)`` becomes ``2*a + 2*b``).

``symmetric_result=True`` computes only the upper triangle and mirrors it.
The factorisations are unrolled and unpivoted; the symmetric positive-definite
ones check every pivot at runtime (``Program.require_positive``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import sympy

from derive.errors import MatrixPropertyError, ShapeError
from derive.expression_lowering import negative_number
from derive.monomials import product, sum_of
from derive.program import Program

_ZERO, _ONE = sympy.S.Zero, sympy.S.One


def _shape(M: sympy.Matrix) -> tuple[int, int]:
    return (M.rows, M.cols)


def _need_matrix(M, what: str) -> sympy.Matrix:
    if not isinstance(M, sympy.MatrixBase):
        raise ShapeError(f"{what}: expected a sympy Matrix, got {type(M).__name__}")
    return M


def _need_square(M: sympy.Matrix, name: str, what: str) -> int:
    _need_matrix(M, what)
    if M.rows != M.cols or M.rows == 0:
        raise ShapeError(f"{what}: {name} must be square, got shape {_shape(M)}")
    return M.rows


def _dot(terms: Sequence[sympy.Expr]) -> sympy.Expr:
    return sympy.Add(*terms)


def dot(pairs: Iterable[tuple[sympy.Expr, sympy.Expr]]) -> sympy.Expr:
    """``sum(a*b for a, b in pairs)``, the same sympy expression, without building the
    products of an exact zero (sympy would fold each to 0 through a full ``Mul``) or of an
    exact one, so a banded or sparse factor costs its nonzero entries, not its size; the
    products and their sum as :mod:`derive.monomials` builds them."""
    terms = []
    for a, b in pairs:
        if a is _ZERO or b is _ZERO:
            continue
        terms.append(b if a is _ONE else a if b is _ONE else product(a, b))
    return sum_of(terms)


def _stage(prog: Program, expr: sympy.Expr, hint: str = "t") -> sympy.Expr:
    """``prog.let(expr)``; an expression whose every term is negative is staged positive and
    returned negated (``-t``), so the sign folds into later sums instead of costing a neg."""
    expr = sympy.sympify(expr)
    if not expr.is_number and all(negative_number(term.as_coeff_Mul()[0])
                                  for term in sympy.Add.make_args(expr)):
        return -prog.let(-expr, hint)
    return prog.let(expr, hint)


def stage(prog: Program, expr: sympy.Expr, hint: str = "t") -> sympy.Expr:
    """One entry staged as every function here stages its entries (an atom as it is, an
    entry whose every term is negative as ``-t``): for programs that stage expressions
    one at a time rather than as a matrix."""
    return _stage(prog, expr, hint)


def _build(prog: Program, rows: int, cols: int, entry: Callable[[int, int], sympy.Expr],
           symmetric_result: bool, hint: str, what: str) -> sympy.Matrix:
    if symmetric_result and rows != cols:
        raise ShapeError(f"{what}: a symmetric result must be square, got shape {(rows, cols)}")
    out = sympy.zeros(rows, cols)
    for i in range(rows):
        for j in range(i if symmetric_result else 0, cols):
            out[i, j] = _stage(prog, entry(i, j), hint)
            if symmetric_result:
                out[j, i] = out[i, j]
    return out


def let_matrix(prog: Program, M: sympy.Matrix, *, symmetric_result: bool = False,
               hint: str = "t") -> sympy.Matrix:
    """Give every non-atomic entry of ``M`` a temporary (stage an arbitrary matrix)."""
    _need_matrix(M, "let_matrix")
    return _build(prog, M.rows, M.cols, lambda i, j: M[i, j], symmetric_result, hint,
                  "let_matrix")


def matmul(prog: Program, A: sympy.Matrix, B: sympy.Matrix, *, symmetric_result: bool = False,
           hint: str = "t") -> sympy.Matrix:
    """``A B``, one temporary per entry (upper triangle only with ``symmetric_result``)."""
    _need_matrix(A, "matmul")
    _need_matrix(B, "matmul")
    if A.cols != B.rows:
        raise ShapeError(f"matmul: A has shape {_shape(A)} and B has shape {_shape(B)}; "
                         "A.cols must equal B.rows")
    rows, columns = A.tolist(), B.T.tolist()       # sympy's indexing is slow
    return _build(prog, A.rows, B.cols, lambda i, j: dot(zip(rows[i], columns[j])),
                  symmetric_result, hint, "matmul")


def _elementwise(prog: Program, A: sympy.Matrix, B: sympy.Matrix, op, symmetric_result: bool,
                 hint: str, what: str) -> sympy.Matrix:
    _need_matrix(A, what)
    _need_matrix(B, what)
    if _shape(A) != _shape(B):
        raise ShapeError(f"{what}: A has shape {_shape(A)} but B has shape {_shape(B)}")
    return _build(prog, A.rows, A.cols, lambda i, j: op(A[i, j], B[i, j]), symmetric_result,
                  hint, what)


def add(prog: Program, A: sympy.Matrix, B: sympy.Matrix, *, symmetric_result: bool = False,
        hint: str = "t") -> sympy.Matrix:
    """``A + B``."""
    return _elementwise(prog, A, B, lambda a, b: a + b, symmetric_result, hint, "add")


def sub(prog: Program, A: sympy.Matrix, B: sympy.Matrix, *, symmetric_result: bool = False,
        hint: str = "t") -> sympy.Matrix:
    """``A - B``."""
    return _elementwise(prog, A, B, lambda a, b: a - b, symmetric_result, hint, "sub")


def scale(prog: Program, A: sympy.Matrix, c: sympy.Expr, *, symmetric_result: bool = False,
          hint: str = "t") -> sympy.Matrix:
    """``c A`` for a scalar atom or number ``c``."""
    _need_matrix(A, "scale")
    c = sympy.sympify(c)
    return _build(prog, A.rows, A.cols, lambda i, j: c * A[i, j], symmetric_result, hint,
                  "scale")


def transpose(A: sympy.Matrix) -> sympy.Matrix:
    """``A^T`` (no operations)."""
    return _need_matrix(A, "transpose").T


class PivotMessage(str):
    """The message of a pivot check (``S is not positive definite: pivot 2 of its LDL^T
    factorisation is not positive``) that remembers its parts: ``axis`` says what the
    factorised matrix's rows are (``"states"``, ``"measurements"``; None: not said), so
    the program of one block of a model can name the pivot by its row in the whole model
    (:meth:`renumbered`, used by :mod:`derive.filters.blockwise`)."""

    matrix: str
    pivot: int
    factorisation: str
    axis: str | None

    def __new__(cls, matrix: str, pivot: int, factorisation: str, axis: str | None = None):
        text = (f"{matrix} is not positive definite: pivot {pivot} of its {factorisation} "
                "factorisation is not positive")
        message = super().__new__(cls, text)
        message.matrix, message.pivot = matrix, pivot
        message.factorisation, message.axis = factorisation, axis
        return message

    def __getnewargs__(self) -> tuple:   # pickled by its parts (derive.background)
        return self.matrix, self.pivot, self.factorisation, self.axis

    def renumbered(self, rows: dict[str, Sequence[int]]) -> PivotMessage:
        """The same message with the pivot numbered by ``rows[axis]`` (row i of the
        factorised matrix is row ``rows[axis][i]`` of the whole); unchanged without an
        axis."""
        if self.axis is None:
            return self
        return PivotMessage(self.matrix, rows[self.axis][self.pivot], self.factorisation,
                            self.axis)


def _ldl(prog: Program, S: sympy.Matrix, name: str, axis: str | None = None):
    """Unit lower ``L``, pivots ``D`` and their reciprocals (one division each)."""
    m = _need_square(S, name, "ldl")
    L = sympy.eye(m)
    E = sympy.zeros(m, m)  # E[i, j] = L[i, j] * D[j], the numerators
    D: list[sympy.Expr] = []
    Dinv: list[sympy.Expr] = []
    for j in range(m):
        d = _stage(prog, S[j, j] - dot((E[j, k], L[j, k]) for k in range(j)), "d")
        prog.require_positive(d, PivotMessage(name, j, "LDL^T", axis))
        D.append(d)
        Dinv.append(_stage(prog, 1 / d, "dinv"))
        for i in range(j + 1, m):
            E[i, j] = _stage(prog, S[i, j] - dot((E[i, k], L[j, k]) for k in range(j)))
            L[i, j] = _stage(prog, E[i, j] * Dinv[j], "l")
    return L, D, Dinv


def ldl(prog: Program, S: sympy.Matrix, *, name: str = "S") -> tuple[sympy.Matrix, sympy.Matrix]:
    """``S = L D L^T`` of a symmetric positive-definite ``S`` (its lower triangle is read).

    Returns the unit lower-triangular ``L`` and the diagonal ``D``; each pivot is
    checked at runtime (``name`` appears in the failure message).
    """
    L, D, _ = _ldl(prog, S, name)
    return L, sympy.diag(*D)


#: A pivot that divides at most this many entries divides each directly; more share one
#: reciprocal. Two divisions cost fewer flops (2 against 1 + 2) and no more latency than a
#: reciprocal and two multiplications; from three on, the shared reciprocal keeps the
#: divider free (one division, then multiplications that pipeline).
DIRECT_DIVISIONS = 2


def forward_substitute(prog: Program, L: sympy.Matrix, B: sympy.Matrix) -> sympy.Matrix:
    """``L^-1 B`` for unit lower-triangular ``L`` (column by column)."""
    Y = sympy.zeros(L.rows, B.cols)
    for c in range(B.cols):
        for i in range(L.rows):
            Y[i, c] = _stage(prog, B[i, c] - dot((L[i, k], Y[k, c]) for k in range(i)))
    return Y


def ldl_forward(prog: Program, S: sympy.Matrix, B: sympy.Matrix, *,
                name: str = "S", axis: str | None = None
                ) -> tuple[sympy.Matrix, sympy.Matrix, sympy.Matrix]:
    """``(L, Y, Z)``: ``S = L D L^T``, ``Y = L^-1 B`` (forward substitution) and
    ``Z = D^-1 Y``, the first two stages of :func:`spd_solve`. Then ``S^-1 B = L^-T Z``
    and ``B^T S^-1 B = Z^T Y``, which needs no back substitution (a Kalman gain's
    ``P H^T S^-1 H P`` from ``B = H P``).

    Per pivot, the entries it divides are divided directly when there are at most
    `DIRECT_DIVISIONS` of them (m = 1 with a 2-column B: two divisions), else one
    reciprocal is shared by all of them (m = 1: exactly one ``1/S``).  ``axis``: what
    ``S``'s rows are (see :class:`PivotMessage`).
    """
    L, _, Y, Z = ldl_forward_pivots(prog, S, B, name=name, axis=axis)
    return L, Y, Z


def ldl_forward_pivots(prog: Program, S: sympy.Matrix, B: sympy.Matrix, *,
                       name: str = "S", axis: str | None = None
                       ) -> tuple[sympy.Matrix, Pivots, sympy.Matrix, sympy.Matrix]:
    """:func:`ldl_forward` with the pivots of ``S = L D L^T``: ``(L, pivots, Y, Z)``
    (``log det S`` is the sum of the logs of ``pivots.D``)."""
    m = _need_square(S, name, "spd_solve")
    _need_matrix(B, "spd_solve")
    if B.rows != m:
        raise ShapeError(f"spd_solve: {name} has shape {_shape(S)} but B has shape {_shape(B)}")
    L, D, Dinv = _ldl(prog, S, name, axis)
    Y = forward_substitute(prog, L, B)
    Z = sympy.zeros(m, B.cols)
    live = []
    for i in range(m):
        direct = sum(1 for c in range(B.cols) if Y[i, c] != 0) <= DIRECT_DIVISIONS
        for c in range(B.cols):
            Z[i, c] = _stage(prog, Y[i, c] / D[i] if direct else Y[i, c] * Dinv[i])
        live.append(not direct or any(L[k, i] != 0 for k in range(i + 1, m)))
    return L, Pivots(tuple(D), tuple(r if used else None for r, used in zip(Dinv, live))), Y, Z


@dataclass(frozen=True)
class Pivots:
    """The pivots ``D`` of an LDL^T factorisation and their reciprocals ``Dinv``, None
    where the factorisation's statements do not use one (a caller then divides by the
    pivot rather than form its reciprocal for one product)."""

    D: tuple[sympy.Expr, ...]
    Dinv: tuple[sympy.Expr | None, ...]


def spd_solve(prog: Program, S: sympy.Matrix, B: sympy.Matrix, *,
              name: str = "S", axis: str | None = None) -> sympy.Matrix:
    """``S^-1 B`` for symmetric positive-definite ``S`` via LDL^T: forward, diagonal
    (:func:`ldl_forward`), back; ``axis``: what ``S``'s rows are (see
    :class:`PivotMessage`)."""
    return spd_solve_pivots(prog, S, B, name=name, axis=axis)[0]


def spd_solve_pivots(prog: Program, S: sympy.Matrix, B: sympy.Matrix, *,
                     name: str = "S", axis: str | None = None
                     ) -> tuple[sympy.Matrix, sympy.Matrix, Pivots]:
    """:func:`spd_solve` with the factors of ``S = L D L^T`` it solved with:
    ``(S^-1 B, L, pivots)``."""
    L, pivots, _, Z = ldl_forward_pivots(prog, S, B, name=name, axis=axis)
    m = L.rows
    X = sympy.zeros(m, B.cols)
    for c in range(B.cols):
        for i in reversed(range(m)):
            X[i, c] = _stage(prog, Z[i, c] - dot((L[k, i], X[k, c]) for k in range(i + 1, m)))
    return X, L, pivots


def spd_inverse(prog: Program, S: sympy.Matrix, *, name: str = "S",
                axis: str | None = None) -> sympy.Matrix:
    """``S^-1`` (symmetric) of a symmetric positive-definite ``S``: ``W^T D^-1 W``, ``W = L^-1``;
    ``axis``: what ``S``'s rows are (see :class:`PivotMessage`)."""
    m = _need_square(S, name, "spd_inverse")
    L, _, Dinv = _ldl(prog, S, name, axis)
    W = sympy.eye(m)
    for j in range(m):
        for i in range(j + 1, m):
            W[i, j] = _stage(prog, -dot((L[i, k], W[k, j]) for k in range(j, i)))
    V = sympy.zeros(m, m)  # V[k, j] = W[k, j] / D[k]
    for k in range(m):
        for j in range(k + 1):
            V[k, j] = _stage(prog, W[k, j] * Dinv[k])
    return _build(prog, m, m,
                  lambda i, j: dot((W[k, i], V[k, j]) for k in range(max(i, j), m)),
                  True, "t", "spd_inverse")


def cholesky(prog: Program, S: sympy.Matrix, *, name: str = "S") -> sympy.Matrix:
    """Lower-triangular ``L`` with ``L L^T = S`` (lower triangle of ``S`` read).

    Each radicand is checked at runtime before its square root; one division per column.
    """
    m = _need_square(S, name, "cholesky")
    L = sympy.zeros(m, m)
    for j in range(m):
        r = _stage(prog, S[j, j] - _dot([L[j, k] ** 2 for k in range(j)]), "r")
        prog.require_positive(r, f"{name} is not positive definite: pivot {j} of its "
                                 "Cholesky factorisation is not positive")
        L[j, j] = _stage(prog, sympy.sqrt(r), "l")
        inv = _stage(prog, 1 / L[j, j], "linv")
        for i in range(j + 1, m):
            numerator = S[i, j] - dot((L[i, k], L[j, k]) for k in range(j))
            L[i, j] = _stage(prog, numerator * inv)
    return L


def lu_inverse(prog: Program, A: sympy.Matrix, *, name: str = "A") -> sympy.Matrix:
    """``A^-1`` of a general square ``A``: unpivoted Doolittle LU, then ``L^-1`` and back
    substitution.  A structurally zero pivot raises MatrixPropertyError; numerically the
    leading principal minors of ``A`` must be nonzero (no runtime check)."""
    n = _need_square(A, name, "lu_inverse")
    L = sympy.eye(n)
    U = sympy.zeros(n, n)
    Uinv: list[sympy.Expr] = []
    for i in range(n):
        for j in range(i, n):
            U[i, j] = _stage(prog, A[i, j] - dot((L[i, k], U[k, j]) for k in range(i)), "u")
        if U[i, i] == 0:
            raise MatrixPropertyError(f"lu_inverse: {name} is structurally singular "
                                      f"(pivot {i} of its LU factorisation is exactly zero)")
        Uinv.append(_stage(prog, 1 / U[i, i], "uinv"))
        for j in range(i + 1, n):
            numerator = A[j, i] - dot((L[j, k], U[k, i]) for k in range(i))
            L[j, i] = _stage(prog, numerator * Uinv[i], "l")
    Y = sympy.eye(n)  # L^-1, unit lower triangular
    for j in range(n):
        for i in range(j + 1, n):
            Y[i, j] = _stage(prog, -dot((L[i, k], Y[k, j]) for k in range(j, i)))
    X = sympy.zeros(n, n)
    for c in range(n):
        for i in reversed(range(n)):
            numerator = Y[i, c] - dot((U[i, k], X[k, c]) for k in range(i + 1, n))
            X[i, c] = _stage(prog, numerator * Uinv[i])
    return X
