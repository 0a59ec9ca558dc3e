"""Steady-state filters (SPEC §4): SSKF, SSLF and their join, x_new = A x + B z.

A and B are solved offline (derive.riccati, doubling after the detectability and
stabilisability checks) and baked into the code as exact binary values of the
doubles, printed with full round-trip precision. The join JSSKLF averages the two
filters' constants offline: (A_KF + A_LF)/2, (B_KF + B_LF)/2, so its on-line cost is
the SSKF's.
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import riccati
from ..program import Port, Program


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


def affine_program(n: int, m: int, A, B, doc: str, out_doc: str, in_doc: str) -> Program:
    """``x_new = A x + B z`` with constant A (n x n) and B (n x m)."""
    prog = Program("step", [Port("x", (n,), doc=in_doc), Port("z", (m,), doc="z(k+1)")],
                   [Port("x_new", (n,), doc=out_doc)], doc=doc)
    x, z = prog.matrix("x"), prog.matrix("z")
    Ax = baked(A) * x
    Bz = baked(B) * z
    prog.set_output("x_new", [sympy.expand(e) for e in (Ax + Bz)])
    return prog.optimize()


def derive_unit(model, name, options):
    from .unit import make_unit

    A, B = steady_gains(model, name)
    step = affine_program(model.n, model.m, A, B, f"one step of the {name.upper()}",
                          "x(k+1/k+1)", "x(k/k)")
    return make_unit(model, name, {"step": step}, options,
                     constants={"A": A, "B": B})


__all__ = ["affine_program", "baked", "derive_unit", "exact", "steady_gains"]
