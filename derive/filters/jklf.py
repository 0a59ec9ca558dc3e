"""The joint Kalman-Lainiotis filter: KF and LF from the same (x, P), averaged.

Both filters start each step from the joined estimate, so the state stays the
filter's interface (x, P); KF and LF are equal in exact arithmetic, so this is
the papers' JKLF up to rounding.  ``missing=True`` passes NaN-marked absent
measurements to both (see :mod:`derive.filters.kf` and :mod:`derive.filters.lf`).
"""

from __future__ import annotations

from .. import reference as numpy_reference
from .. import staging
from .common import MISSING_FACT, with_fact
from .kf import CONDITIONING as KF_CONDITIONING
from .kf import kf_update, time_varying_program
from .lf import CONDITIONING as LF_CONDITIONING
from .lf import lf_update
from .spec import FilterSpec
from .unit import make_unit


def jklf_update(prog, mats, x, P, z, missing: bool = False):
    xk, Pk = kf_update(prog, mats, x, P, z, missing=missing)
    xl, Pl = lf_update(prog, mats, x, P, z, missing=missing)
    x_new = staging.scale(prog, staging.add(prog, xk, xl), 0.5)
    P_new = staging.scale(prog, staging.add(prog, Pk, Pl, symmetric_result=True), 0.5,
                          symmetric_result=True)
    return x_new, P_new


def derive_unit(model, spec, options):
    missing = options.missing

    def update(prog, mats, x, P, z):
        return jklf_update(prog, mats, x, P, z, missing=missing)

    step = time_varying_program(model, update, spec.title, options.P0_pattern)
    unit = make_unit(model, spec, {"step": step}, options)
    return with_fact(unit, MISSING_FACT) if missing else unit


def reference(model, zs, options):
    """derive.reference.jklf from the model's x0 and P0: (xs, Ps)."""
    num = model.numeric()
    return numpy_reference.jklf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)


SPECS = (FilterSpec(
    "jklf", "joint Kalman-Lainiotis filter", "linear", "timevarying", derive_unit, reference,
    covariance=True, missing=True, run_tracks=True, blockwise=True,
    conditioning=KF_CONDITIONING + LF_CONDITIONING, listing=30,
    about={"python": "Run the joint Kalman-Lainiotis filter: the mean of the KF and LF "
                     "estimates.",
           "c": "Run the joint Kalman-Lainiotis filter over steps steps; Ps may be NULL."}),)
