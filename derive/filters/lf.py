"""The Lainiotis filter (SPEC §3), one step.

Constants (folded to numbers when the model has no free symbols, otherwise staged
in the step since they depend on the runtime parameters):
    A = [H GQG^T H^T + R]^-1,  Kn = GQG^T H^T A,  Km = F^T H^T A,
    Pn = GQG^T - Kn H GQG^T,  Fn = F - Kn H F,  On = F^T H^T A H F.
Per step, with M = [I + P On]^-1 (an unrolled LU inverse):
    x_new = Kn z + Fn M (P Km z + x),   P_new = Pn + Fn M P Fn^T.
"""

from __future__ import annotations

import sympy

from .. import staging
from ..program import Program
from .kf import time_varying_program


def lf_constants(prog: Program, mats):
    F, H, R, W = mats["F"], mats["H"], mats["R"], mats["GQGt"]
    WHt = staging.matmul(prog, W, H.T)
    S = staging.add(prog, staging.matmul(prog, H, WHt, symmetric_result=True), R,
                    symmetric_result=True)
    A = staging.spd_inverse(prog, S)
    Kn = staging.matmul(prog, WHt, A)
    HF = staging.matmul(prog, H, F)
    Km = staging.matmul(prog, staging.transpose(HF), A)
    Pn = staging.sub(prog, W, staging.matmul(prog, Kn, staging.transpose(WHt),
                                             symmetric_result=True), symmetric_result=True)
    Fn = staging.sub(prog, F, staging.matmul(prog, Kn, HF))
    On = staging.matmul(prog, Km, HF, symmetric_result=True)
    return {"Kn": Kn, "Km": Km, "Pn": Pn, "Fn": Fn, "On": On}


def lf_update(prog: Program, mats, x, P, z):
    """Stage one LF step; returns (x_new, P_new) as matrices of atoms."""
    c = lf_constants(prog, mats)
    n = x.rows
    I_POn = staging.add(prog, sympy.eye(n), staging.matmul(prog, P, c["On"]))
    FnM = staging.matmul(prog, c["Fn"], staging.lu_inverse(prog, I_POn))
    inner = staging.add(prog, staging.matmul(prog, P, staging.matmul(prog, c["Km"], z)), x)
    x_new = staging.add(prog, staging.matmul(prog, c["Kn"], z),
                        staging.matmul(prog, FnM, inner))
    FnMP = staging.matmul(prog, FnM, P)
    P_new = staging.add(prog, c["Pn"],
                        staging.matmul(prog, FnMP, staging.transpose(c["Fn"]),
                                       symmetric_result=True), symmetric_result=True)
    return x_new, P_new


def derive_unit(model, name, options):
    from .unit import make_unit

    step = time_varying_program(model, lf_update, {**options, "title": "Lainiotis filter"})
    return make_unit(model, name, {"step": step}, options)
