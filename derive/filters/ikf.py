"""The information-form Kalman filter of MDKF (case m >= n), u = 0.

    P(k+1/k) = F P F^T + G Q G^T
    P_new^-1 = P(k+1/k)^-1 + H^T R^-1 H          (two unrolled LDL^T inverses)
    K = P_new H^T R^-1,  x_new = F x + K (z - H F x)

With ``missing=True`` a NaN in z[i] marks measurement i absent: H^T R^-1 becomes that of
the present measurements, H_p^T R_pp^-1 (columns of absent ones zero).  For a
structurally diagonal R that is the constant H^T R^-1 with columns masked (no flop);
otherwise R is masked (:func:`derive.filters.common.mask_symmetric`) and solved in the
step.
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import reference as numpy_reference
from .. import staging
from ..expression_lowering import IfPresent
from .common import (
    MISSING_FACT,
    mask_columns,
    mask_symmetric,
    mask_vector,
    with_fact,
)
from .kf import time_varying_program
from .spec import NOISE, POSTERIOR, UPDATE, Conditioned, FilterSpec
from .unit import make_unit


def _is_diagonal(M: sympy.Matrix) -> bool:
    return all(M[i, j] == 0 for i in range(M.rows) for j in range(M.cols) if i != j)


def ikf_update(prog, mats, x, P, z, missing: bool = False, prior: str = "the predicted P"):
    """Stage one information-form step; ``missing``: NaN entries of z are skipped."""
    F, H, R, W = mats["F"], mats["H"], mats["R"], mats["GQGt"]
    xp = staging.matmul(prog, F, x)
    Pp = staging.add(prog, staging.matmul(prog, staging.matmul(prog, F, P), F.T,
                                          symmetric_result=True), W, symmetric_result=True)
    if not missing:
        # H^T R^-1 (constant)
        HtRinv = staging.transpose(staging.spd_solve(prog, R, H, name="R",
                                                     axis="measurements"))
    elif _is_diagonal(R):
        HtRinv = mask_columns(prog, staging.transpose(
            staging.spd_solve(prog, R, H, name="R", axis="measurements")), z)
    else:
        H_present = staging.let_matrix(
            prog, sympy.Matrix(H.rows, H.cols, lambda i, j: IfPresent(z[i], H[i, j], 0)),
            hint="present")
        HtRinv = staging.transpose(staging.spd_solve(prog, mask_symmetric(prog, R, z),
                                                     H_present, name="R",
                                                     axis="measurements"))
    info = staging.add(prog, staging.spd_inverse(prog, Pp, name=prior,
                                                 axis="states"),
                       staging.matmul(prog, HtRinv, H, symmetric_result=True),
                       symmetric_result=True)
    P_new = staging.spd_inverse(prog, info, name="the information matrix", axis="states")
    K = staging.matmul(prog, P_new, HtRinv)
    innovation = staging.sub(prog, z, staging.matmul(prog, H, xp))
    if missing:
        innovation = mask_vector(prog, innovation, z)
    x_new = staging.add(prog, xp, staging.matmul(prog, K, innovation))
    return x_new, P_new


def derive_unit(model, spec, options):
    missing = options.missing
    # the update-first step's stand-in model inverts P0 where the step inverts P(k+1/k)
    prior = getattr(model, "prior_covariance", "the predicted P")

    def update(prog, mats, x, P, z):
        return ikf_update(prog, mats, x, P, z, missing=missing, prior=prior)

    step = time_varying_program(model, update, spec.title, options.P0_pattern)
    unit = make_unit(model, spec, {"step": step}, options)
    return with_fact(unit, MISSING_FACT) if missing else unit


def reference(model, zs, options):
    """derive.reference.ikf from the model's x0 and P0 (update-first with start=update):
    (xs, Ps)."""
    num = model.numeric()
    if options.get("start", "predict") == "update":
        return numpy_reference.update_first(
            lambda x0, P0, rest, _: numpy_reference.ikf(num.F, num.G, num.H, num.Q, num.R,
                                                        x0, P0, rest),
            num.H, num.R, num.x0, num.P0, zs)
    return numpy_reference.ikf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)


def applies(model) -> str | None:
    """The information form inverts P(k+1/k): G Q G^T must be positive definite."""
    if model.parameters:
        return None
    W = np.array(model.matrix("GQGt").evalf(17).tolist(), dtype=float)
    if np.linalg.eigvalsh(W).min() <= 1e-12 * max(1.0, np.abs(W).max()):
        return (f"the information form needs G Q G^T positive definite (P(k+1/k) is "
                f"inverted); model {model.name!r} has a singular G Q G^T")
    return None


SPECS = (FilterSpec(
    "ikf", "information-form Kalman filter", "linear", "timevarying", derive_unit, reference,
    covariance=True, missing=True, run_tracks=True, start=True, blockwise=True,
    applies=applies, listing=40,
    # H^T R^-1 by an LDL^T solve; P(k+1/k) inverted (its residual reaches P_new scaled by
    # P(k+1/k), as an update's operands), and the information P_new^-1 inverted
    conditioning=(Conditioned(NOISE, "ldl"), Conditioned(UPDATE, "cancel"),
                  Conditioned(POSTERIOR, "ldl")),
    about={"python": "Run the information-form Kalman filter.",
           "c": "Run the information-form Kalman filter over steps steps; Ps may be NULL."}),)
