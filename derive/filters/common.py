"""What every linear filter derivation shares: ports, bound model matrices, P's pattern."""

from __future__ import annotations

import sympy

from ..program import Port, Program


def parameter_port(model) -> list[Port]:
    """The trailing ``p`` port when the model has free parameters (none otherwise)."""
    if not model.parameters:
        return []
    return [Port("p", (len(model.parameters),),
                 doc="free parameters: " + ", ".join(p.name for p in model.parameters))]


def time_varying_ports(model) -> tuple[list[Port], list[Port]]:
    n, m = model.n, model.m
    inputs = [Port("x", (n,), doc="x(k/k)"),
              Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric"),
              Port("z", (m,), doc="z(k+1)")]
    outputs = [Port("x_new", (n,), doc="x(k+1/k+1)"),
               Port("P_new", (n, n), symmetric=True, doc="P(k+1/k+1), row-major")]
    return inputs + parameter_port(model), outputs


def bound_matrices(model, prog: Program) -> dict[str, sympy.Matrix]:
    """F, G, H, Q, R, GQGt with values substituted and free symbols bound to ``p``."""
    binding = prog.bind("p", model.parameters) if model.parameters else {}
    out = {}
    for k in ("F", "G", "H", "Q", "R", "GQGt"):
        out[k] = sympy.Matrix(model.matrix(k)).xreplace(binding)
    return out


def masked(mat: sympy.Matrix, pattern) -> sympy.Matrix:
    """``mat`` with the entries outside ``pattern`` (a boolean n x n) set to zero."""
    return sympy.Matrix(mat.rows, mat.cols,
                        lambda i, j: mat[i, j] if pattern[i][j] else sympy.Integer(0))
