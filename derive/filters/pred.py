"""Steady-state N-step prediction (SSPRED §4): x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k).

A_N = F^N (I - K H) F^-(N-1), B_N = F^N K (offline), and the start x(N/0) = F^N x0
is a second generated function ``init``. Option ``horizon``: N (default 1, at most
derive.horizon.MAX_HORIZON).
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import horizon, riccati
from .. import reference as numpy_reference
from ..options import PredictionOptions
from ..program import Port, Program
from .spec import FilterSpec
from .steady import affine_program, sparse_affine, sparse_exact, two_step_program
from .unit import make_unit


def derive_unit(model, spec, options: PredictionOptions):
    N = options.horizon
    num = model.numeric()
    ss = riccati.kf_steady(num.F, num.G, num.H, num.Q, num.R)
    pc = horizon.pred_constants(num.F, ss.K, num.H, N)
    n, m = model.n, model.m
    step = affine_program(n, m, pc.A_N, pc.B_N, f"{N}-step steady-state prediction",
                          f"x(k+{N}/k)", f"x(k+{N - 1}/k-1)")
    init = Program("init", [Port("x0", (n,), doc="x(0/0)")],
                   [Port("x_new", (n,), doc=f"x({N}/0) = F^{N} x(0/0)")], doc="start of the run")
    FN = np.linalg.matrix_power(num.F, N)
    init.set_output("x_new", [sympy.expand(e)
                              for e in sparse_affine(sparse_exact(FN), init.matrix("x0"))])
    return make_unit(model, spec, {"step": step, "init": init.optimize()}, options,
                     horizon=N, lookahead=two_step_program(n, m, pc.A_N, pc.B_N),
                     constants={"A_N": pc.A_N, "B_N": pc.B_N, "N": N})


def reference(model, zs, options):
    """derive.reference.pred over the options' horizon from the model's x0: (xs, None)."""
    num = model.numeric()
    return numpy_reference.pred(num.F, num.G, num.H, num.Q, num.R, num.x0, zs,
                                options.horizon), None


SPECS = (FilterSpec(
    "pred", "steady-state N-step predictor", "linear", "predictor", derive_unit, reference,
    options=PredictionOptions, steady=True, blockwise=True, listing=90,
    about={"python": "Run the predictor from x(N/0) = init(x0): row k is the prediction "
                     "after z[k].",
           "c": "Run the predictor from x(N/0) = init(x0): row k of xs is the prediction "
                "after z[k]."}),)
