"""The information-form Kalman filter of MDKF (SPEC §3, case m >= n), u = 0.

    P(k+1/k) = F P F^T + G Q G^T
    P_new^-1 = P(k+1/k)^-1 + H^T R^-1 H          (two unrolled LDL^T inverses)
    K = P_new H^T R^-1,  x_new = F x + K (z - H F x)
"""

from __future__ import annotations

from .. import staging
from .kf import time_varying_program


def ikf_update(prog, mats, x, P, z):
    F, H, R, W = mats["F"], mats["H"], mats["R"], mats["GQGt"]
    xp = staging.matmul(prog, F, x)
    Pp = staging.add(prog, staging.matmul(prog, staging.matmul(prog, F, P), F.T,
                                          symmetric_result=True), W, symmetric_result=True)
    HtRinv = staging.transpose(staging.spd_solve(prog, R, H))  # H^T R^-1 (constant)
    info = staging.add(prog, staging.spd_inverse(prog, Pp),
                       staging.matmul(prog, HtRinv, H, symmetric_result=True),
                       symmetric_result=True)
    P_new = staging.spd_inverse(prog, info)
    K = staging.matmul(prog, P_new, HtRinv)
    innovation = staging.sub(prog, z, staging.matmul(prog, H, xp))
    x_new = staging.add(prog, xp, staging.matmul(prog, K, innovation))
    return x_new, P_new


def derive_unit(model, name, options):
    from .unit import make_unit

    step = time_varying_program(model, ikf_update,
                                {**options, "title": "information-form Kalman filter",
                                 "P0_pattern": options.get("P0_pattern")})
    return make_unit(model, name, {"step": step}, options)
