"""The Kalman filter, one step, staged for the straight-line program.

    x(k+1/k) = F x,  P(k+1/k) = F P F^T + G Q G^T,  S = H P(k+1/k) H^T + R,
    K = P(k+1/k) H^T S^-1 (an unrolled LDL^T solve, never an inverse),
    x_new = x(k+1/k) + K (z - H x(k+1/k)),  P_new = P(k+1/k) - K (P(k+1/k) H^T)^T
    (or Joseph's form (I-KH) P (I-KH)^T + K R K^T with ``joseph=True``).
Only the upper triangle of each symmetric matrix is computed.

With ``missing=True`` a NaN in z(k+1)[i] marks measurement i absent: S, P H^T and the
innovation are masked (:func:`derive.filters.common.mask_symmetric`), so K's column i
is zero and the update is exactly the one with row i of H, z and row and column i of R
dropped, for correlated R too.  The masks are selects: no flop.
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import reference as numpy_reference
from .. import staging
from ..errors import OptionError
from ..options import KalmanOptions
from ..program import Port, Program
from ..sensitivity import with_gradient
from . import pattern as pat
from .blockwise import blockwise_step
from .common import (
    JOSEPH_FACT,
    MISSING_FACT,
    bound_matrices,
    gaussian_loglik,
    input_port,
    linear_step_inputs,
    loglik_port,
    mask_columns,
    mask_symmetric,
    mask_vector,
    masked_covariance,
    parameter_port,
    time_varying_ports,
    with_fact,
)
from .sensors import (
    gate_thresholds,
    kalman_update,
    program_name,
    sensor_facts,
    sensor_groups,
    sequential_update,
    update_forms,
    uses_sensor_run,
)
from .spec import INNOVATION, UPDATE, Conditioned, FilterSpec
from .unit import make_sensor_unit, make_unit


def prior(prog: Program, F, W, H, R, x, P):
    """Stage the prediction and the innovation covariance, in the papers' order.

    Returns ``x(k+1/k) = F x``, ``P(k+1/k) = (F P) F^T + W`` (upper triangle),
    ``P(k+1/k) H^T`` and ``S = H (P(k+1/k) H^T) + R`` (upper triangle).
    """
    xp = staging.matmul(prog, F, x)
    FP = staging.matmul(prog, F, P)
    Pp = staging.add(prog, staging.matmul(prog, FP, F.T, symmetric_result=True), W,
                     symmetric_result=True)
    PHt = staging.matmul(prog, Pp, H.T)
    S = staging.add(prog, staging.matmul(prog, H, PHt, symmetric_result=True), R,
                    symmetric_result=True)
    return xp, Pp, PHt, S


def kf_update(prog: Program, mats, x, P, z, joseph: bool = False, missing: bool = False,
              u=None, loglik: bool = False):
    """Stage one KF step; returns (x_new, P_new) as matrices of atoms, and with ``loglik``
    (x_new, P_new, ll): ll the log-likelihood of the innovation from the LDL^T factors the
    gain is solved with (:func:`derive.filters.common.gaussian_loglik`).

    ``missing``: NaN entries of z are absent measurements (skipped).  ``u``: the step's
    inputs (the model's ``inputs``): x(k+1/k) = F x + B u, innovation z - H x(k+1/k) - D u.
    """
    F, H, R, W = mats["F"], mats["H"], mats["R"], mats["GQGt"]
    xp, Pp, PHt, S = prior(prog, F, W, H, R, x, P)
    if u is not None:
        xp = staging.add(prog, xp, staging.matmul(prog, mats["B"], u))
    if missing:
        S, PHt = mask_symmetric(prog, S, z), mask_columns(prog, PHt, z)
    Kt, L, pivots = staging.spd_solve_pivots(prog, S, staging.transpose(PHt),
                                             axis="measurements")
    K = staging.transpose(Kt)
    predicted_z = staging.matmul(prog, H, xp)
    if u is not None:
        predicted_z = staging.add(prog, predicted_z, staging.matmul(prog, mats["D"], u))
    innovation = staging.sub(prog, z, predicted_z)
    if missing:
        innovation = mask_vector(prog, innovation, z)
    x_new = staging.add(prog, xp, staging.matmul(prog, K, innovation))
    extra = ()
    if loglik:
        whitened = staging.forward_substitute(prog, L, innovation)
        extra = (gaussian_loglik(prog, pivots, whitened, z if missing else None),)
    if not joseph:
        KPHt = staging.matmul(prog, K, staging.transpose(PHt), symmetric_result=True)
        P_new = staging.sub(prog, Pp, KPHt, symmetric_result=True)
        return (x_new, P_new) + extra
    n = F.rows
    IKH = staging.sub(prog, sympy.eye(n), staging.matmul(prog, K, H))
    A = staging.matmul(prog, staging.matmul(prog, IKH, Pp), staging.transpose(IKH),
                       symmetric_result=True)
    B = staging.matmul(prog, staging.matmul(prog, K, R), staging.transpose(K),
                       symmetric_result=True)
    return (x_new, staging.add(prog, A, B, symmetric_result=True)) + extra


def time_varying_program(model, update, title: str, P0_pattern: str | None,
                         loglik: bool = False) -> Program:
    """Build ``step`` of the filter ``title`` from ``update(prog, mats, x, P, z)``
    (``update(prog, mats, x, P, z, u)`` for a model with inputs), which returns
    ``(x_new, P_new)``, or with ``loglik`` ``(x_new, P_new, ll)``: the step's output ``ll``.

    P's pattern is the closure of P0's declared pattern (option ``P0_pattern``; None:
    the model's) under ``update``; entries outside it are neither read nor computed.
    A model of independent blocks is derived block by block, each distinct block once
    (:mod:`derive.filters.blockwise`), unless the step sums a log-likelihood over them.
    """
    declared_name = P0_pattern or model.P0_pattern

    def derive_block(block_model):
        return _time_varying_step(block_model, update, title, declared_name, loglik)

    assembled = None if loglik else blockwise_step(model, declared_name, derive_block)
    if assembled is not None:
        return assembled[0]
    return derive_block(model)[0]


def _time_varying_step(model, update, title: str, declared_name: str, loglik: bool = False):
    """(the optimised step of ``model``, derived whole, and P's closed pattern)."""
    inputs, outputs = time_varying_ports(model)
    outputs += [loglik_port()] if loglik else []

    def build(pattern):
        prog = Program("step", inputs, outputs,
                       doc=f"one step of the {title}")
        mats = bound_matrices(model, prog)
        P = masked_covariance(prog, pattern, declared_name)
        u = [prog.matrix("u")] if input_port(model) else []
        return (prog,) + tuple(update(prog, mats, prog.matrix("x"), P, prog.matrix("z"), *u))

    def step_pattern(pattern):
        return pat.of_matrix(build(pattern)[2])

    closed = pat.closure(step_pattern, pat.declared(model, declared_name))
    prog, x_new, P_new, *ll = build(closed)
    prog.set_output("x_new", list(x_new))
    prog.set_output("P_new", list(P_new))
    if ll:
        prog.set_output("ll", [ll[0]])
    return prog.optimize(), closed


def sensor_programs(model, groups, thresholds, title: str, P0_pattern: str | None,
                    forms: dict[str, str] | None = None) -> dict[str, Program]:
    """``predict(x, P[, u][, p])`` (x(k+1/k) = F x + B u, P(k+1/k) = F P F^T + G Q G^T) and
    one ``update_<sensor>(x, P, z[, u][, p])`` per sensor (its H, R and D u), gated where
    ``thresholds`` say, sequential where ``forms`` say (default: batch); P's pattern is
    the closure of P0's declared pattern under all."""
    forms = forms or {g.name: "batch" for g in groups}
    n = model.n
    p_port = parameter_port(model)

    def build(name, group, pattern):
        if group is None:
            u = ([Port("u", (model.n_inputs,), doc="u(k): x(k+1) = F x(k) + B u(k); "
                        + ", ".join(s.name for s in model.inputs))] if model.inputs else [])
            inputs = [Port("x", (n,), doc="x(k/k)"),
                      Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric")]
            outputs = [Port("x_new", (n,), doc="x(k+1/k)"),
                       Port("P_new", (n, n), symmetric=True, doc="P(k+1/k), row-major")]
            prog = Program(name, inputs + u + p_port, outputs, doc=f"Predict only: "
                           f"x(k+1/k) and P(k+1/k) of the {title}.")
        else:
            gate = thresholds[group.name]
            u = ([Port("u", (len(group.inputs),), doc="its inputs " + ", ".join(
                s.name for s in group.inputs))] if group.inputs else [])
            inputs = [Port("x", (n,), doc="x before the update (x(k/k-1))"),
                      Port("P", (n, n), symmetric=True, doc="its covariance, symmetric"),
                      Port("z", (group.m,), doc=", ".join(group.measurements))]
            if group.R_argument:
                inputs.append(Port("R", (group.m, group.m), symmetric=True,
                                   doc="its noise covariance R, given per call, symmetric"))
            outputs = [Port("x_new", (n,), doc="x after the update"),
                       Port("P_new", (n, n), symmetric=True, doc="its covariance, row-major")]
            if gate is not None:
                outputs += [Port("nis", (1,), doc="normalised innovation squared"),
                            Port("applied", (1,), doc="1 when applied, else 0")]
            prog = Program(name, inputs + u + p_port, outputs, doc=f"The {title} update "
                           f"with the measurements of sensor {group.name!r}.")
        binding = prog.bind("p", model.parameters) if model.parameters else {}
        x, P = prog.matrix("x"), masked_covariance(prog, pattern, declared)
        extra = ()
        if group is None:
            mats = bound_matrices(model, prog)
            x_new = staging.matmul(prog, mats["F"], x)
            if model.inputs:
                x_new = staging.add(prog, x_new, staging.matmul(prog, mats["B"],
                                                                prog.matrix("u")))
            FP = staging.matmul(prog, mats["F"], P)
            P_new = staging.add(prog, staging.matmul(prog, FP, mats["F"].T,
                                                     symmetric_result=True),
                                mats["GQGt"], symmetric_result=True)
        else:
            H = sympy.Matrix(model.subs(group.H)).xreplace(binding)
            if group.R_argument:  # the port's upper triangle
                given = prog.matrix("R")
                R = sympy.Matrix(group.m, group.m,
                                 lambda i, j: given[min(i, j), max(i, j)])
            else:
                R = sympy.Matrix(model.subs(group.R)).xreplace(binding)
            z = prog.matrix("z")

            def innovation():
                predicted = staging.matmul(prog, H, x)
                if group.inputs:
                    D = sympy.Matrix(model.subs(group.D)).xreplace(binding)
                    predicted = staging.add(prog, predicted,
                                            staging.matmul(prog, D, prog.matrix("u")))
                return staging.sub(prog, z, predicted)

            gate = None if thresholds[group.name] is None else thresholds[group.name][1]
            if forms[group.name] == "sequential":
                x_new, P_new, extra = sequential_update(prog, x, P, H, R, innovation(), gate,
                                                        group.measurements)
            else:
                PHt = staging.matmul(prog, P, H.T)
                S = staging.add(prog, staging.matmul(prog, H, PHt, symmetric_result=True), R,
                                symmetric_result=True)
                x_new, P_new, extra = kalman_update(prog, x, P, PHt, S, innovation, gate)
        return prog, x_new, P_new, extra

    specs = {"predict": None} | {program_name(g.name): g for g in groups}

    def grow(pattern):
        out = pattern
        for name, group in specs.items():
            out = pat.union(out, pat.of_matrix(build(name, group, pattern)[2]))
        return out

    declared = P0_pattern or model.P0_pattern
    closed = pat.closure(grow, pat.declared(model, declared))
    programs = {}
    for name, group in specs.items():
        prog, x_new, P_new, extra = build(name, group, closed)
        prog.set_output("x_new", list(x_new))
        prog.set_output("P_new", list(P_new))
        if extra:
            prog.set_output("nis", [extra[0]])
            prog.set_output("applied", [extra[1]])
        programs[name] = prog.optimize()
    return programs


def derive_sensor_unit(model, spec, options):
    """The KF of the run kind ``sensors`` (derive.filters.sensors)."""
    for key in ("joseph", "missing", "loglik"):
        if options.get(key):
            raise OptionError(f"option {key!r} is not taken with several sensors, gating, "
                              "sequential updates or update-first (the run kind sensors: a "
                              "row of NaN skips a sensor's update)")
    groups = sensor_groups(model)
    thresholds = gate_thresholds(groups, options)
    forms = update_forms(model, groups, options)
    programs = sensor_programs(model, groups, thresholds, spec.title, options.P0_pattern,
                               forms)
    facts = sensor_facts(model, groups, thresholds, options.start, forms)
    return make_sensor_unit(model, spec, programs, options, groups, thresholds,
                            model.inputs, facts)


def derive_unit(model, spec, options):
    if uses_sensor_run(model, options):
        return derive_sensor_unit(model, spec, options)
    joseph, missing = options.joseph, options.missing
    gradient = options.gradient
    loglik = options.loglik or gradient

    def update(prog, mats, x, P, z, u=None):
        return kf_update(prog, mats, x, P, z, joseph=joseph, missing=missing, u=u,
                         loglik=loglik)

    step = time_varying_program(model, update, spec.title, options.P0_pattern, loglik)
    programs, carried = {"step": step}, None
    if gradient:  # dx, dP carried beside x, P; entered as zero (derive.sensitivity)
        programs, carried = with_gradient(model, programs)
    unit = make_unit(model, spec, programs, options,
                     step_inputs=linear_step_inputs(model), carried=carried)
    if input_port(model):
        unit = with_fact(unit, INPUTS_FACT)
    if joseph:
        unit = with_fact(unit, JOSEPH_FACT)
    return with_fact(unit, MISSING_FACT) if missing else unit


def reference(model, zs, options):
    """derive.reference.kf from the model's x0 and P0: (xs, Ps); ``zs`` is the
    measurements, or for a model with inputs a run with ``zs`` and ``us``."""
    num = model.numeric()
    if model.inputs:
        return numpy_reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs.zs,
                                  B=num.B, D=num.D, us=zs.us)
    return numpy_reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)


def loglik_reference(model, zs, options):
    """(each step's log-likelihood of the innovation, its scale), from derive.reference.kf
    (``zs`` as :func:`reference` takes it; a NaN measurement absent; update-first with
    start=update)."""
    num = model.numeric()
    us = zs.us if model.inputs else None
    data = zs.zs if model.inputs else zs
    lls, scales = np.empty(len(data)), np.empty(len(data))

    def run(x0, P0, rows, inputs_rows, at=0):
        inputs = {} if inputs_rows is None else {"B": num.B, "D": num.D, "us": inputs_rows}
        return numpy_reference.kf(num.F, num.G, num.H, num.Q, num.R, x0, P0, rows,
                                  lls=lls[at:], ll_scales=scales[at:], **inputs)

    if options.get("start", "predict") != "update":
        run(num.x0, num.P0, data, us)
        return lls, scales
    # update-first: step 0's from x0, P0 without a prediction, then the filter from there
    numpy_reference.update_first(lambda x0, P0, rows, inputs_rows: run(x0, P0, rows,
                                                                       inputs_rows, 1),
                                 num.H, num.R, num.x0, num.P0, data, D=num.D if us is not None
                                 else None, us=us, lls=lls[:1], ll_scales=scales[:1])
    return lls, scales


INPUTS_FACT = ("per-step input u (run: one row per step, with the same row of z): "
               "x(k+1) = F x(k) + B u(k), z(k+1) = H x(k+1) + D u(k) + v")


CONDITIONING = (Conditioned(INNOVATION, "ldl"), Conditioned(UPDATE, "cancel"))
"""What the KF's step factorises and cancels: S, by the LDL^T solve for the gain (never
P), and the update's subtraction P(k/k-1) - K S K^T."""

SPECS = (FilterSpec(
    "kf", "Kalman filter", "linear", "timevarying", derive_unit, reference,
    options=KalmanOptions, covariance=True, missing=True, loglik=loglik_reference,
    run_tracks=True,
    inputs=True,
    sensors=True, start=True, blockwise=True, conditioning=CONDITIONING, listing=10,
    about={"python": "Run the Kalman filter: predict with F, then update with the gain "
                     "K = P H^T S^-1.",
           "c": "Run the Kalman filter over steps steps; Ps may be NULL."}),)
