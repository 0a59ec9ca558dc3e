"""Steady-state filters: SSKF, SSLF and their join, x_new = A x + B z.

A and B are solved offline (derive.riccati, doubling after the detectability and
stabilisability checks) and baked into the code as exact binary values of the
doubles, printed with full round-trip precision. The join JSSKLF averages the two
filters' constants offline: (A_KF + A_LF)/2, (B_KF + B_LF)/2, so its on-line cost is
the SSKF's.
"""

from __future__ import annotations

from fractions import Fraction
from functools import partial

import numpy as np
import sympy

from .. import reference as numpy_reference
from .. import riccati
from ..program import Port, Program
from ..runs.unit import LOOKAHEAD_NEXT
from .spec import FilterSpec
from .unit import make_unit


def exact(value: float) -> sympy.Rational:
    """The double ``value`` as the exact rational it is (no decimal rounding)."""
    num, den = float(value).as_integer_ratio()
    return sympy.Rational(num, den)


def baked(array) -> sympy.Matrix:
    a = np.atleast_2d(np.asarray(array, dtype=float))
    return sympy.Matrix(a.shape[0], a.shape[1], lambda i, j: exact(a[i, j]))


def steady_gains(model, name: str):
    """(A, B) of ``sskf``, ``sslf`` or ``jssklf`` for the model at its values."""
    num = model.numeric()
    args = (num.F, num.G, num.H, num.Q, num.R)
    if name == "sskf":
        s = riccati.kf_steady(*args)
        return s.A, s.B
    if name == "sslf":
        s = riccati.lf_steady(*args)
        return s.A, s.B
    k, lf = riccati.kf_steady(*args), riccati.lf_steady(*args)
    return (k.A + lf.A) / 2, (k.B + lf.B) / 2


SparseRows = list[list[tuple[int, Fraction]]]
"""A matrix by rows, each the (column, exact value) of its non-zero entries in order."""


def sparse_exact(array) -> SparseRows:
    """The doubles of ``array`` as exact fractions, by rows, zeros left out: a
    block-diagonal matrix of k blocks holds k times one block's entries, not n^2."""
    a = np.atleast_2d(np.asarray(array, dtype=float))
    return [[(int(j), Fraction(float(a[i, j]))) for j in np.flatnonzero(a[i])]
            for i in range(a.shape[0])]


def sparse_product(A: SparseRows, B: SparseRows) -> SparseRows:
    """``A B``, exact (the sum of exact products; an entry that cancels to 0 is left out)."""
    out: SparseRows = []
    for row in A:
        acc: dict[int, Fraction] = {}
        for j, a in row:
            for col, b in B[j]:
                acc[col] = acc.get(col, 0) + a * b
        out.append([(col, value) for col, value in sorted(acc.items()) if value])
    return out


def sparse_affine(rows: SparseRows, vector: sympy.Matrix) -> list[sympy.Expr]:
    """``rows * vector`` entry by entry (the products of the exact constants)."""
    return [sympy.Add(*(sympy.Rational(c.numerator, c.denominator) * vector[j]
                        for j, c in row)) for row in rows]


def affine_program(n: int, m: int, A, B, doc: str, out_doc: str, in_doc: str) -> Program:
    """``x_new = A x + B z`` with constant A (n x n) and B (n x m); each entry sums the
    non-zero terms only (the sums of the dense product, with its zero terms left out)."""
    prog = Program("step", [Port("x", (n,), doc=in_doc), Port("z", (m,), doc="z(k+1)")],
                   [Port("x_new", (n,), doc=out_doc)], doc=doc)
    x, z = prog.matrix("x"), prog.matrix("z")
    terms = zip(sparse_affine(sparse_exact(A), x), sparse_affine(sparse_exact(B), z))
    prog.set_output("x_new", [sympy.expand(ax + bz) for ax, bz in terms])
    return prog.optimize()


def two_step_program(n: int, m: int, A, B) -> Program:
    """The two-step map of ``x_new = A x + B z``: x(k+2) = A^2 x(k) + A B z(k) + B z(k+1)
    from ports ``x``, ``z`` (row k) and the next row, with the products of the exact
    baked doubles taken exactly (rounded once when printed); derive.runs.kinds.two_steps."""
    A, B = sparse_exact(A), sparse_exact(B)
    prog = Program("step2", [Port("x", (n,), doc="x(k)"), Port("z", (m,), doc="z(k)"),
                             Port(LOOKAHEAD_NEXT, (m,), doc="z(k+1)")],
                   [Port("x_new", (n,), doc="x(k+2)")],
                   doc="x(k+2) = A^2 x(k) + A B z(k) + B z(k+1)")
    x, z, zn = prog.matrix("x"), prog.matrix("z"), prog.matrix(LOOKAHEAD_NEXT)
    terms = zip(sparse_affine(sparse_product(A, A), x), sparse_affine(sparse_product(A, B), z),
                sparse_affine(B, zn))
    prog.set_output("x_new", [sympy.expand(a + b + c) for a, b, c in terms])
    return prog.optimize()


def derive_unit(model, spec, options):
    A, B = steady_gains(model, spec.name)
    step = affine_program(model.n, model.m, A, B, f"one step of the {spec.name.upper()}",
                          "x(k+1/k+1)", "x(k/k)")
    return make_unit(model, spec, {"step": step}, options, constants={"A": A, "B": B},
                     lookahead=two_step_program(model.n, model.m, A, B))


def reference(model, zs, options, name: str):
    """derive.reference.``name`` (sskf, sslf, jssklf) from the model's x0: (xs, None)."""
    num = model.numeric()
    run = getattr(numpy_reference, name)
    return run(num.F, num.G, num.H, num.Q, num.R, num.x0, zs), None


def _spec(name: str, title: str, about: str, listing: int) -> FilterSpec:
    return FilterSpec(
        name, title, "linear", "steady", derive_unit, partial(reference, name=name),
        steady=True, run_tracks=True, blockwise=True, listing=listing,
        about={"python": f"Run the {title}: {about}.",
               "c": f"Run the {title} over steps steps."})


SPECS = (
    _spec("sskf", "steady-state Kalman filter", "x = A x + B z with constant A, B", 50),
    _spec("sslf", "steady-state Lainiotis filter", "x = A x + B z with constant A, B", 60),
    _spec("jssklf", "joint steady-state Kalman-Lainiotis filter", "the mean of SSKF and SSLF",
          70),
)

__all__ = ["SPECS", "affine_program", "baked", "derive_unit", "exact", "sparse_exact",
           "sparse_affine", "sparse_product", "steady_gains", "two_step_program"]
