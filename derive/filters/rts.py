"""The Rauch-Tung-Striebel fixed-interval smoother (linear models), staged as two programs.

``step`` (the forward pass): one Kalman filter step (:func:`derive.filters.kf.kf_update`,
the KF's own staging, ``missing`` included) that also outputs the prediction it made:

    x, P, z, [p]  ->  x_new = x(k+1/k+1), P_new = P(k+1/k+1),
                      x_pred = x(k+1/k),  P_pred = P(k+1/k)

``backward``: one smoothing step; it does not see z, so missing measurements only shape the
forward pass:

    x = x(k/k), P = P(k/k), x_pred = x(k+1/k), P_pred = P(k+1/k),
    x_smooth_next = x(k+1/N), P_smooth_next = P(k+1/N), [p]
      ->  x_smooth = x(k/N) = x + C (x_smooth_next - x_pred),
          P_smooth = P(k/N) = P + C (P_smooth_next - P_pred) C^T,

with C^T = P_pred^-1 (F P) solved by an unrolled LDL^T of P_pred (one pivot check each,
never an inverse), so C = P F^T P_pred^-1.  Symmetric results are computed as upper
triangles.  P(k/k) has the KF's pattern: the closure of P0's declared pattern under the
KF step; P(k+1/k) has the pattern the forward program gives it there; P(k/N) has the
closure of the KF's pattern under the backward step (for the catalog models both closures
are the KF's pattern).  Entries outside are not read; the symmetric inputs are checked to
be zero there (upper triangle), as the KF checks P.

Indexing (derive.reference.smoother): x(0/0) = x0, P(0/0) = P0, z(k) = z[k-1] for
k = 1..N, and the run returns xs[k-1] = x(k/N), Ps[k-1] = P(k/N), k = 1..N.

The run ``MODEL_rts_run(steps, z, x0, P0, xs, Ps, work)`` (the run kind "smoother",
derive.runs.unit.RUN_KINDS, its loop built by derive.runs.kinds.smoother).  Generated C marks the
ports ``restrict``; every call below reads and writes disjoint rows, so nothing is copied.

work (doubles, caller-provided in C; Python allocates its own): one row per step k = 1..N,
row k - 1 = [x(k/k) (n), P(k/k) (n*n), x(k/k-1) (n), P(k/k-1) (n*n)], the step's outputs
x_new, P_new, x_pred, P_pred in that order (the kind's ``work`` entry):

    size = steps * (2 n + 2 n*n)  (stated in the header's interface line).

Loop order:

1. forward, k = 1..N: ``step(x_in, P_in, z[k-1], [p[k-1]]) -> row k - 1`` with
   (x_in, P_in) = (x0, P0) for k = 1, else the x(k-1/k-1), P(k-1/k-1) of row k - 2.  A
   failed check stops the run (its status);
2. xs[N-1], Ps[N-1] = x(N/N), P(N/N) from row N - 1: the smoothed are the filtered there;
3. backward, k = N-1 down to 1: ``backward(x(k/k), P(k/k) of row k - 1, x(k+1/k),
   P(k+1/k) of row k, xs[k], Ps[k], [p[k]]) -> xs[k-1], Ps[k-1]`` (p[k]: the row whose F
   predicted x(k+1/k)).

Row 1's prediction (P(1/0)) is written and never read back: P(1/0) is singular for the
catalog's P0 = 0, so x(0/N) of the x0 before the first prediction is not part of the run.
With the option start="update" (update-first, pykalman's convention) row 0 of the forward
pass is x0, P0 updated with z[0] by the program ``update`` (derive.filters.unit), and the
run returns xs[k] = x(k/N) for k = 0..N-1, xs[0] = x(0/N) as pykalman's smooth does.
"""

from __future__ import annotations

import sympy

from .. import staging
from ..errors import FilterError
from ..options import SharedOptions
from ..program import Port, Program
from ..reference.linear import kf as reference_kf
from ..reference.smoother import rts as reference_rts
from . import pattern as pat
from .common import (
    MISSING_FACT,
    bound_matrices,
    input_port,
    linear_step_inputs,
    masked,
    masked_covariance,
    parameter_port,
    pattern_message,
    time_varying_ports,
    with_fact,
)
from .kf import CONDITIONING as KF_CONDITIONING
from .kf import kf_update, prior
from .spec import NEXT_PRIOR, Conditioned, FilterSpec
from .unit import make_unit

NAME = "rts"
TITLE = "Rauch-Tung-Striebel smoother"
MODEL_KIND = "linear"
RUN_KIND = "smoother"
OPTIONS = SharedOptions
REFERENCE = reference_rts

PRIOR_NAME = "P(k+1/k)"
"""How the pivot checks of the backward solve name the matrix they factorise."""


def _forward_build(model, pattern, declared: str, missing: bool,
                   doc: str = f"one forward (Kalman filter) step of the {TITLE}"):
    """The forward program with P masked to ``pattern``; returns it with its four
    results."""
    inputs, outputs = time_varying_ports(model)
    n = model.n
    outputs = outputs + [Port("x_pred", (n,), doc="x(k+1/k)"),
                         Port("P_pred", (n, n), symmetric=True, doc="P(k+1/k), row-major")]
    prog = Program("step", inputs, outputs,
                   doc=doc)
    mats = bound_matrices(model, prog)
    x, z = prog.matrix("x"), prog.matrix("z")
    u = prog.matrix("u") if input_port(model) else None
    P = masked_covariance(prog, pattern, declared)
    x_pred, P_pred, _, _ = prior(prog, mats["F"], mats["GQGt"], mats["H"], mats["R"], x, P)
    if u is not None:  # x(k+1/k) = F x + B u(k), as the update's own prediction
        x_pred = staging.add(prog, x_pred, staging.matmul(prog, mats["B"], u))
    x_new, P_new = kf_update(prog, mats, x, P, z, missing=missing, u=u)
    return prog, (x_new, P_new, x_pred, P_pred)


def _checked(prog: Program, port: str, pattern, declared: str) -> sympy.Matrix:
    """The symmetric input ``port`` with entries outside ``pattern`` structurally zero and
    checked to be zero at runtime (upper triangle), as the KF's ``P``."""
    mat = prog.matrix(port)
    message = port + pattern_message(pattern, declared).removeprefix("P")
    for i in range(mat.rows):
        for j in range(i, mat.cols):
            if not pattern[i][j]:
                prog.require_zero(prog.element(port, i, j), message)
    return masked(mat, pattern)


def _backward_build(model, filtered, predicted, smoothed, declared: str):
    """The backward program with P, P_pred and P_smooth_next masked to the three patterns."""
    n = model.n
    inputs = [Port("x", (n,), doc="x(k/k)"),
              Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric"),
              Port("x_pred", (n,), doc="x(k+1/k)"),
              Port("P_pred", (n, n), symmetric=True, doc="P(k+1/k), row-major, symmetric"),
              Port("x_smooth_next", (n,), doc="x(k+1/N)"),
              Port("P_smooth_next", (n, n), symmetric=True,
                   doc="P(k+1/N), row-major, symmetric")]
    outputs = [Port("x_smooth", (n,), doc="x(k/N)"),
               Port("P_smooth", (n, n), symmetric=True, doc="P(k/N), row-major")]
    prog = Program("backward", inputs + parameter_port(model), outputs,
                   doc=f"one backward step of the {TITLE}")
    F = bound_matrices(model, prog)["F"]
    x, x_pred, x_next = (prog.matrix(name) for name in ("x", "x_pred", "x_smooth_next"))
    P = _checked(prog, "P", filtered, declared)
    P_pred = _checked(prog, "P_pred", predicted, declared)
    P_next = _checked(prog, "P_smooth_next", smoothed, declared)
    gain_t = staging.spd_solve(prog, P_pred, staging.matmul(prog, F, P), name=PRIOR_NAME)
    gain = staging.transpose(gain_t)                          # C = P F^T P(k+1/k)^-1
    x_gap = staging.sub(prog, x_next, x_pred)
    x_smooth = staging.add(prog, x, staging.matmul(prog, gain, x_gap))
    P_gap = staging.sub(prog, P_next, P_pred, symmetric_result=True)
    spread = staging.matmul(prog, staging.matmul(prog, gain, P_gap), gain_t,
                            symmetric_result=True)
    P_smooth = staging.add(prog, P, spread, symmetric_result=True)
    return prog, (x_smooth, P_smooth)


def _forward(model, options: SharedOptions, *doc: str):
    """The forward program, its outputs set, P(k/k)'s pattern (the closure of P0's under
    the step) and P(k+1/k)'s."""
    declared = options.P0_pattern or model.P0_pattern
    missing = options.missing
    filtered = pat.closure(
        lambda p: pat.of_matrix(_forward_build(model, p, declared, missing, *doc)[1][1]),
        pat.declared(model, declared))
    forward, values = _forward_build(model, filtered, declared, missing, *doc)
    for name, value in zip(("x_new", "P_new", "x_pred", "P_pred"), values):
        forward.set_output(name, list(value))
    return forward, filtered, pat.of_matrix(values[3])


def rts_programs(model, options: SharedOptions) -> dict[str, Program]:
    """``{"step": forward, "backward": ...}``, optimised, for the linear ``model``."""
    if model.kind != "linear":
        raise FilterError(f"filter 'rts' needs a linear model; {model.name!r} is {model.kind}")
    declared = options.P0_pattern or model.P0_pattern
    forward, filtered, predicted = _forward(model, options)
    smoothed = pat.closure(
        lambda p: pat.of_matrix(_backward_build(model, filtered, predicted, p, declared)[1][1]),
        filtered)
    backward, (x_smooth, P_smooth) = _backward_build(model, filtered, predicted, smoothed,
                                                     declared)
    backward.set_output("x_smooth", list(x_smooth))
    backward.set_output("P_smooth", list(P_smooth))
    return {"step": forward.optimize(), "backward": backward.optimize()}


def work_fact(n: int) -> str:
    """The header line stating the size of C run's work array."""
    return (f"work: steps * {2 * n + 2 * n * n} doubles, steps * (2 n + 2 n^2) (C: "
            "caller-provided, one row per step: x(k/k), P(k/k), x(k/k-1), P(k/k-1); "
            "no allocation)")


def derive_unit(model, spec, options: SharedOptions):
    """The smoother's unit: the forward ``step`` and the ``backward`` program."""
    unit = make_unit(model, spec, rts_programs(model, options), options,
                     step_inputs=linear_step_inputs(model))
    unit = with_fact(unit, work_fact(model.n))
    return with_fact(unit, MISSING_FACT) if options.missing else unit


def reference(model, zs, options):
    """derive.reference.smoother.rts from the model's x0 and P0 (NaN: absent, with
    ``missing``; update-first with start=update): (xs, Ps)."""
    num = model.numeric()
    start = options.get("start", "predict")
    if model.inputs:  # zs: a run with zs and the inputs us
        return reference_rts(num, zs.zs, num.x0, num.P0, skip_nan=options.missing, us=zs.us,
                             start=start)
    return reference_rts(num, zs, num.x0, num.P0, skip_nan=options.missing, start=start)


def derive_predictions(model, spec, options: SharedOptions):
    """The unit of the Kalman filter with its one-step predictions: the forward ``step``
    alone, run by the kind ``filter_predict`` (it stores x_new, P_new and x_pred, P_pred)."""
    forward = _forward(model, options, f"one step of the {spec.title}")[0]
    unit = make_unit(model, spec, {"step": forward.optimize()}, options)
    return with_fact(unit, MISSING_FACT) if options.missing else unit


def reference_predictions(model, zs, options):
    """derive.reference.linear.kf from the model's x0 and P0: (xs, Ps), the filtered
    estimates (the predictions: derive.reference.linear.predictions)."""
    num = model.numeric()
    return reference_kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs,
                        skip_nan=options.missing)


SPECS = (FilterSpec(
    "kfp", "predicting Kalman filter", MODEL_KIND, "filter_predict",
    derive_predictions, reference_predictions, options=OPTIONS, covariance=True, missing=True,
    listing=96, conditioning=KF_CONDITIONING,
    about={"python": "Run the predicting Kalman filter; returns the filtered (xs, Ps) and "
                     "the one-step prediction each step made, x(k/k-1) and P(k/k-1) "
                     "(x_preds, P_preds).",
           "c": "Run the predicting Kalman filter over steps steps: x(k/k), "
                "P(k/k) into xs, Ps and x(k/k-1), P(k/k-1) into x_preds, P_preds (Ps and "
                "P_preds may be NULL)."}), FilterSpec(
    NAME, TITLE, MODEL_KIND, RUN_KIND, derive_unit, reference, options=OPTIONS,
    covariance=True, missing=True, inputs=True, start=True, listing=95,
    # the forward KF's S; the backward gain's LDL^T solve with P(k+1/k)
    conditioning=KF_CONDITIONING + (Conditioned(NEXT_PRIOR, "ldl"),),
    about={"python": "Run the Rauch-Tung-Striebel smoother: a Kalman filter forward, then "
                     "x(k/N) = x(k/k) + C [x(k+1/N) - x(k+1/k)] backward; returns the "
                     "smoothed (xs, Ps).",
           "c": "Run the Rauch-Tung-Striebel smoother over steps steps: forward into work, "
                "then backward into xs and Ps (both required)."}),)
