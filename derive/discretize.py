"""Discretisation of a continuous linear model (SSPRED): F = exp(Phi dt), Van Loan Qd.

Van Loan (1978): with ``M = [[-Phi, W], [0, Phi^T]] dt`` and ``W = G Qc G^T``,
``exp(M) = [[., E12], [0, E22]]``, ``F = E22^T`` and ``Qd = F E12``; this equals
``integral_0^dt exp(Phi s) W exp(Phi^T s) ds``.

Three methods, tried in this order, each with an effort bound checked before the
expensive step (sympy's matrix exponential and simplification have no bound of their own:
a numeric damped oscillator took a minute, a numeric 4x4 more than five):

- ``exact-nilpotent``: ``Phi`` nilpotent (the papers' CV and CA models): ``M`` is nilpotent
  too, and ``exp(M)`` is its finite Taylor series, exact and symbolic in every parameter.
- ``exact-sympy``: ``Phi`` triangular with at most `MAX_EXACT_STATES` states, or a ``Phi``
  of two states with a symbol that has no value and eigenvalues free of square roots of
  symbols, and at most `MAX_EXACT_SYMBOLIC_EIGENVALUES` symbolic eigenvalues: sympy's
  exact exponential,
  simplified only while the unsimplified result has at most `MAX_EXACT_OPERATIONS`
  operations.
- ``numeric-expm``: every symbol of ``Phi`` and ``dt`` has a value: ``scipy.linalg.expm`` of
  the Van Loan block in double precision. Entries that are structurally zero (no path in
  the graph of ``Phi``) are exact zeros. A symbol without a value in ``G Qc G^T`` stays
  symbolic: ``Qd`` is linear in it, so each entry of ``W`` gets its own exponential.

Anything else (a symbolic ``Phi`` beyond those bounds) is a `DiscretizationError` saying
which bound was hit and how to get a model (give the symbols values, or discretise
outside derive and write a ``[discrete]`` model).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import sympy

from .errors import ModelError

MAX_EXACT_STATES = 3
"""Largest triangular ``Phi`` exponentiated exactly by sympy (non-nilpotent)."""
MAX_EXACT_SYMBOLIC_EIGENVALUES = 2
"""Most distinct eigenvalues of ``Phi`` with symbols in an exact (non-nilpotent) exponential."""
MAX_EXACT_OPERATIONS = 600
"""Largest unsimplified exact ``exp(M)`` (sympy ``count_ops``) that is simplified and kept."""
MAX_NILPOTENT_OPERATIONS = 20_000
"""Largest nilpotent-series result (``count_ops`` of the Taylor terms) that is kept."""

METHODS = {
    "exact-nilpotent": "exact (Phi nilpotent: finite Taylor series of the Van Loan matrix)",
    "exact-sympy": "exact (sympy matrix exponential of the Van Loan matrix)",
    "numeric-expm": "numeric (scipy.linalg.expm of the Van Loan matrix, double precision)",
}
"""Method name -> the sentence stated in the generated header."""


class DiscretizationError(ModelError):
    """A continuous model that cannot be discretised within the effort bounds."""


class Discretization(NamedTuple):
    F: sympy.ImmutableMatrix
    Qd: sympy.ImmutableMatrix
    method: str  # a key of METHODS


def _simplify(mat: sympy.MatrixBase) -> sympy.ImmutableMatrix:
    return sympy.ImmutableMatrix(mat.applyfunc(lambda e: sympy.factor_terms(sympy.simplify(e))))


def _van_loan(Phi: sympy.MatrixBase, W: sympy.MatrixBase) -> sympy.Matrix:
    n = Phi.rows
    M = sympy.zeros(2 * n, 2 * n)
    M[:n, :n] = -Phi
    M[:n, n:] = W
    M[n:, n:] = Phi.T
    return M


def discretize(Phi: sympy.MatrixBase, G: sympy.MatrixBase, Qc: sympy.MatrixBase,
               dt: sympy.Expr, values: dict | None = None) -> Discretization:
    """``(F, Qd, method)`` for ``dx/dt = Phi x + G w``, ``E[w w^T] = Qc delta``, step ``dt``.

    ``values`` (symbol name -> number) lets a ``Phi`` that is not exponentiated exactly be
    exponentiated numerically; symbols are kept wherever the method allows.
    """
    Phi = sympy.Matrix(Phi)
    W = sympy.Matrix(G) * sympy.Matrix(Qc) * sympy.Matrix(G).T
    n = Phi.rows
    if _is_nilpotent(Phi):
        return _nilpotent(Phi, W, dt)
    given = values or {}
    symbols = Phi.free_symbols | W.free_symbols | sympy.sympify(dt).free_symbols
    substitution = {s: sympy.nsimplify(given[s.name], rational=True)
                    for s in symbols if s.name in given}   # by name: any assumptions
    numeric_Phi = Phi.xreplace(substitution)
    numeric_dt = sympy.sympify(dt).xreplace(substitution)
    free = sorted({s.name for s in numeric_Phi.free_symbols | numeric_dt.free_symbols})
    exact_reason = _exact_bound(Phi, numeric=not free)
    if exact_reason is None:
        result = _exact(Phi, W, dt)
        if result is not None:
            return result
        exact_reason = (f"its exact exponential has more than {MAX_EXACT_OPERATIONS} "
                        "operations before simplification")
    if free:
        raise DiscretizationError(
            f"cannot discretise the {n}x{n} continuous model: Phi is not nilpotent and "
            f"{exact_reason}, and a numeric exponential needs values for {', '.join(free)}; "
            "give them values, or discretise it yourself and write a [discrete] model")
    return _numeric(numeric_Phi, W.xreplace(substitution), numeric_dt)


# -- exact methods ------------------------------------------------------------------------


def _is_nilpotent(Phi: sympy.Matrix) -> bool:
    """Whether ``Phi**n == 0`` exactly; only tried where it is cheap to decide: a numeric
    ``Phi`` or a strictly triangular one (structurally nilpotent)."""
    n = Phi.rows
    if all(Phi[i, j] == 0 for i in range(n) for j in range(n) if i >= j) or \
            all(Phi[i, j] == 0 for i in range(n) for j in range(n) if i <= j):
        return True
    if Phi.free_symbols:
        return False
    power = sympy.eye(n)
    for _ in range(n):
        power = power * Phi
        if power.is_zero_matrix:
            return True
    return False


def _nilpotent(Phi: sympy.Matrix, W: sympy.Matrix, dt: sympy.Expr) -> Discretization:
    """``exp(M dt)`` as its finite Taylor series (``M**(2n) = 0`` when ``Phi**n = 0``)."""
    n = Phi.rows
    M = _van_loan(Phi, W) * dt
    term = sympy.eye(2 * n)
    E = sympy.eye(2 * n)
    operations = 0
    for k in range(1, 2 * n):
        term = (term * M / k).applyfunc(sympy.expand)
        if term.is_zero_matrix:
            break
        operations += sympy.count_ops(term)
        if operations > MAX_NILPOTENT_OPERATIONS:
            raise DiscretizationError(
                f"cannot discretise the {n}x{n} continuous model: the Taylor series of its "
                f"Van Loan matrix has more than {MAX_NILPOTENT_OPERATIONS} operations")
        E = E + term
    return _finish(E, n, "exact-nilpotent")


def _exact_bound(Phi: sympy.Matrix, numeric: bool) -> str | None:
    """None if sympy's exact exponential is tried, else why not. ``numeric``: every symbol
    of Phi and dt has a value (so the numeric exponential is available). sympy's time
    grows with the symbolic eigenvalues (three take seconds, four a quarter of a minute,
    a square root of symbols minutes), so those are bounded before it starts."""
    n = Phi.rows
    if n > MAX_EXACT_STATES:
        return f"it has {n} states, more than {MAX_EXACT_STATES} for an exact exponential"
    if Phi.is_upper or Phi.is_lower:
        eigenvalues = set(Phi.diagonal())
    elif n == 2 and not numeric:
        trace, determinant = Phi.trace(), Phi.det()
        discriminant = sympy.factor(trace**2 - 4 * determinant)
        root = sympy.sqrt(discriminant)
        if any(power.exp.is_Rational and not power.exp.is_Integer and power.base.free_symbols
               for power in root.atoms(sympy.Pow)):
            return (f"its eigenvalues need the square root of {discriminant} (an exact "
                    "exponential is tried for explicit eigenvalues)")
        eigenvalues = {(trace + root) / 2, (trace - root) / 2}
    else:
        return ("it is not triangular (an exact exponential is tried for a triangular Phi "
                f"of at most {MAX_EXACT_STATES} states, or a symbolic Phi of 2)")
    symbolic = [value for value in eigenvalues if value.free_symbols]
    if len(symbolic) > MAX_EXACT_SYMBOLIC_EIGENVALUES:
        return (f"it has {len(symbolic)} distinct symbolic eigenvalues, more than "
                f"{MAX_EXACT_SYMBOLIC_EIGENVALUES} for an exact exponential")
    return None


def _exact(Phi: sympy.Matrix, W: sympy.Matrix, dt: sympy.Expr) -> Discretization | None:
    """sympy's exponential, or None when its result is too large to simplify."""
    n = Phi.rows
    try:
        E = (_van_loan(Phi, W) * dt).exp()
    except Exception as exc:  # sympy raises many kinds here
        raise DiscretizationError(f"sympy cannot exponentiate Phi*dt exactly: {exc}") from exc
    if sympy.count_ops(E) > MAX_EXACT_OPERATIONS:
        return None
    return _finish(E, n, "exact-sympy")


def _finish(E: sympy.Matrix, n: int, method: str) -> Discretization:
    F = _simplify(E[n:, n:].T)
    Qd = _simplify(F * E[:n, n:])
    if any(sympy.simplify(e) != 0 for e in Qd - Qd.T):
        Qd = _simplify((Qd + Qd.T) / 2)
    if any(e.has(sympy.I) for e in list(F) + list(Qd)):
        F = _simplify(F.applyfunc(lambda e: sympy.re(sympy.expand_complex(e))))
        Qd = _simplify(Qd.applyfunc(lambda e: sympy.re(sympy.expand_complex(e))))
    return Discretization(F, Qd, method)


# -- numeric method -----------------------------------------------------------------------


def _to_float(expr: sympy.Expr, what: str) -> float:
    value = complex(sympy.N(expr, 17))
    if value.imag != 0 or not np.isfinite(value.real):
        raise DiscretizationError(f"{what} = {expr} is not a finite real number")
    return value.real


def _reach(Phi: sympy.Matrix) -> np.ndarray:
    """reach[i, j]: state j influences state i through Phi (a path j -> i, or i == j); where
    it is False, exp(Phi t)[i, j] is exactly zero."""
    n = Phi.rows
    reach = np.eye(n, dtype=bool) | np.array([[Phi[i, j] != 0 for j in range(n)]
                                               for i in range(n)])
    for _ in range(max(1, n.bit_length())):
        reach = reach | ((reach.astype(np.int64) @ reach.astype(np.int64)) > 0)
    return reach


def _exact_matrix(values: np.ndarray, nonzero: np.ndarray) -> sympy.Matrix:
    """The doubles of ``values`` as exact rationals, with exact zeros outside ``nonzero``."""
    if not np.isfinite(values).all():
        raise DiscretizationError("exp(M dt) of the Van Loan matrix M is not finite in "
                                  "double precision (Phi*dt is too large)")
    return sympy.Matrix(values.shape[0], values.shape[1],
                        lambda i, j: sympy.Rational(float(values[i, j]))
                        if nonzero[i, j] and values[i, j] != 0 else sympy.Integer(0))


def _numeric(Phi: sympy.Matrix, W: sympy.Matrix, dt: sympy.Expr) -> Discretization:
    import scipy.linalg  # here, not at the top: every CLI start-up loads this module

    n = Phi.rows
    step = _to_float(dt, "dt")
    A = np.array([[_to_float(Phi[i, j], f"Phi[{i}][{j}]") for j in range(n)]
                  for i in range(n)])
    reach = _reach(Phi)
    F_num = scipy.linalg.expm(A * step)
    F = _exact_matrix(F_num, reach)
    # Qd is linear in W: one Van Loan exponential per nonzero entry of W's upper triangle,
    # so a symbol without a value in W stays a symbol.
    Qd = sympy.zeros(n, n)
    for (row, col), weight in _unit_weights(W).items():
        basis = np.zeros((n, n))
        basis[row, col] = basis[col, row] = 1.0
        M = np.zeros((2 * n, 2 * n))
        M[:n, :n] = -A
        M[:n, n:] = basis
        M[n:, n:] = A.T
        E = scipy.linalg.expm(M * step)
        block = F_num @ E[:n, n:]
        reached = np.outer(reach[:, row], reach[:, col])
        Qd += weight * _exact_matrix((block + block.T) / 2, reached | reached.T)
    return Discretization(sympy.ImmutableMatrix(F),
                          sympy.ImmutableMatrix(Qd.applyfunc(sympy.expand)), "numeric-expm")


def _unit_weights(W: sympy.Matrix) -> dict[tuple[int, int], sympy.Expr]:
    """W = sum weight * (e_k e_l^T + e_l e_k^T, or e_k e_k^T): the symmetric unit
    decomposition over the upper triangle."""
    n = W.rows
    weights = {}
    for k in range(n):
        for j in range(k, n):
            if W[k, j] != 0:
                weights[(k, j)] = W[k, j]
    return weights
