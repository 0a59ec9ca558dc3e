"""Exact discretisation of a continuous linear model (SPEC §1): F = exp(Phi dt), Van Loan Qd."""

from __future__ import annotations

import sympy

from .errors import ModelError


def _simplify(mat: sympy.MatrixBase) -> sympy.ImmutableMatrix:
    return sympy.ImmutableMatrix(mat.applyfunc(lambda e: sympy.factor_terms(sympy.simplify(e))))


def discretize(Phi: sympy.MatrixBase, G: sympy.MatrixBase, Qc: sympy.MatrixBase,
               dt: sympy.Expr) -> tuple[sympy.ImmutableMatrix, sympy.ImmutableMatrix]:
    """Return ``(F, Qd)`` for ``dx/dt = Phi x + G w``, ``E[w w^T] = Qc delta``, step ``dt``.

    Van Loan (1978): with ``M = [[-Phi, G Qc G^T], [0, Phi^T]] dt``,
    ``exp(M) = [[., E12], [0, E22]]``, ``F = E22^T`` and ``Qd = F E12``; this equals
    ``integral_0^dt exp(Phi s) G Qc G^T exp(Phi^T s) ds`` exactly.
    """
    n = Phi.rows
    W = G * Qc * G.T
    M = sympy.zeros(2 * n, 2 * n)
    M[:n, :n] = -Phi
    M[:n, n:] = W
    M[n:, n:] = Phi.T
    try:
        E = (M * dt).exp()
    except Exception as exc:  # sympy raises many kinds here
        raise ModelError(f"sympy cannot exponentiate Phi*dt exactly: {exc}") from exc
    F = _simplify(E[n:, n:].T)
    Qd = _simplify(F * E[:n, n:])
    if any(sympy.simplify(e) != 0 for e in Qd - Qd.T):
        Qd = _simplify((Qd + Qd.T) / 2)
    if any(e.has(sympy.I) for e in list(F) + list(Qd)):
        F = _simplify(F.applyfunc(lambda e: sympy.re(sympy.expand_complex(e))))
        Qd = _simplify(Qd.applyfunc(lambda e: sympy.re(sympy.expand_complex(e))))
    return F, Qd
