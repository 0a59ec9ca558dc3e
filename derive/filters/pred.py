"""Steady-state N-step prediction (SSPRED §4): x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k).

A_N = F^N (I - K H) F^-(N-1), B_N = F^N K (offline), and the start x(N/0) = F^N x0
is a second generated function ``init``. Option ``horizon``: N (default 1, at most
derive.horizon.MAX_HORIZON).
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import horizon, riccati
from ..options import PredictionOptions
from ..program import Port, Program
from .steady import affine_program, baked


def derive_unit(model, name, options: PredictionOptions):
    from .unit import make_unit

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
    init.set_output("x_new", [sympy.expand(e) for e in baked(FN) * init.matrix("x0")])
    return make_unit(model, name, {"step": step, "init": init.optimize()}, options,
                     horizon=N, constants={"A_N": pc.A_N, "B_N": pc.B_N, "N": N})
