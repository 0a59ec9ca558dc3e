"""The Lainiotis filter, one step.

Constants (folded to numbers when the model has no free symbols, otherwise staged
in the step since they depend on the runtime parameters):
    A = [H GQG^T H^T + R]^-1,  Kn = GQG^T H^T A,  Km = F^T H^T A,
    Pn = GQG^T - Kn H GQG^T,  Fn = F - Kn H F,  On = F^T H^T A H F.
Per step, with M = [I + P On]^-1 (an unrolled LU inverse):
    x_new = Kn z + Fn M (P Km z + x),   P_new = Pn + Fn M P Fn^T.

With ``missing=True`` a NaN in z[i] marks measurement i absent: the constants are those
of the model with row i of H and z and row and column i of R dropped, so they depend on
which measurements are present and are computed in the step (masked as in
:mod:`derive.filters.common`; no longer folded, hence much dearer than the plain LF).
"""

from __future__ import annotations

import sympy

from .. import reference as numpy_reference
from .. import staging
from ..program import Program
from .common import (
    MISSING_FACT,
    mask_columns,
    mask_symmetric,
    mask_vector,
    with_fact,
)
from .kf import time_varying_program
from .spec import LAINIOTIS, NOMINAL, Conditioned, FilterSpec
from .unit import make_unit


def lf_constants(prog: Program, mats, z=None):
    """The LF constants; with ``z`` given, those of the measurements present in ``z``."""
    F, H, R, W = mats["F"], mats["H"], mats["R"], mats["GQGt"]
    WHt = staging.matmul(prog, W, H.T)
    S = staging.add(prog, staging.matmul(prog, H, WHt, symmetric_result=True), R,
                    symmetric_result=True)
    if z is not None:
        S, WHt = mask_symmetric(prog, S, z), mask_columns(prog, WHt, z)
    A = staging.spd_inverse(prog, S, axis="measurements")
    Kn = staging.matmul(prog, WHt, A)
    HF = staging.matmul(prog, H, F)
    HFt = staging.transpose(HF) if z is None else mask_columns(prog, staging.transpose(HF), z)
    Km = staging.matmul(prog, HFt, A)
    Pn = staging.sub(prog, W, staging.matmul(prog, Kn, staging.transpose(WHt),
                                             symmetric_result=True), symmetric_result=True)
    Fn = staging.sub(prog, F, staging.matmul(prog, Kn, HF))
    On = staging.matmul(prog, Km, staging.transpose(HFt), symmetric_result=True)
    return {"Kn": Kn, "Km": Km, "Pn": Pn, "Fn": Fn, "On": On}


def lf_update(prog: Program, mats, x, P, z, missing: bool = False):
    """Stage one LF step; returns (x_new, P_new) as matrices of atoms.

    ``missing``: NaN entries of z are absent measurements (skipped)."""
    c = lf_constants(prog, mats, z if missing else None)
    if missing:
        z = mask_vector(prog, z, z)
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


def derive_unit(model, spec, options):
    missing = options.missing

    def update(prog, mats, x, P, z):
        return lf_update(prog, mats, x, P, z, missing=missing)

    step = time_varying_program(model, update, spec.title, options.P0_pattern)
    unit = make_unit(model, spec, {"step": step}, options)
    return with_fact(unit, MISSING_FACT) if missing else unit


def reference(model, zs, options):
    """derive.reference.lf from the model's x0 and P0: (xs, Ps)."""
    num = model.numeric()
    return numpy_reference.lf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)


CONDITIONING = (Conditioned(NOMINAL, "ldl"), Conditioned(LAINIOTIS, "lu"))
"""What the LF's step factorises: A's matrix (folded offline unless it depends on the
present measurements or on free symbols) and I + P On (the unrolled LU inverse)."""

SPECS = (FilterSpec(
    "lf", "Lainiotis filter", "linear", "timevarying", derive_unit, reference,
    covariance=True, missing=True, run_tracks=True, blockwise=True, conditioning=CONDITIONING,
    listing=20,
    about={"python": "Run the Lainiotis filter: the partitioned update with constants "
                     "precomputed offline.",
           "c": "Run the Lainiotis filter over steps steps; Ps may be NULL."}),)
