"""The extended Kalman filter for any NonlinearModel, as straight-line programs.

    x(k/k-1) = f(x),  P(k/k-1) = F P F^T + Q,        F = ∂f/∂x at x(k-1/k-1)
    S = H P(k/k-1) H^T + R,  K = P(k/k-1) H^T S^-1,  H = ∂h/∂x at x(k/k-1) and u(k)
    x(k/k) = x(k/k-1) + K (z - h(x(k/k-1), u(k))),  P(k/k) = P(k/k-1) - K (P(k/k-1) H^T)^T

A Q that depends on the state is evaluated at x(k-1/k-1) (where F is), an R that does at
x(k/k-1) (where H is first), both with u(k). An angle measurement's innovation is wrapped
to (-pi, pi] (:func:`derive.filters.nonlinear.wrap_angle`). With the option
``iterations`` = N the update is the iterated EKF's (Bell and Cathey): x_0 = x(k/k-1), and
N times ``x_(i+1) = x(k/k-1) + K_i (z - h(x_i) - H_i (x(k/k-1) - x_i))`` with h, H and K_i
taken at x_i (R at x(k/k-1)); x(k/k) is the last, P(k/k) = P(k/k-1) - K_N (P H_N^T)^T.

This module holds the EKF's predict and update stages and its unit. F and H come from
:func:`derive.filters.nonlinear.linearise` (sympy Jacobians evaluated with f and h through
shared subexpressions); the programs step, predict and update1 are the frame shared with
the UKF (:func:`derive.filters.nonlinear.nonlinear_programs`).
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import sympy

from .. import reference as numpy_reference
from .. import staging
from ..errors import OptionError, VerificationError
from ..options import ExtendedOptions
from ..reference.likelihood import innovations_loglik
from ..sensitivity import with_gradient
from .kf import CONDITIONING
from .nonlinear import (
    NOTE_C,
    NOTE_PY,
    Linearisation,
    Predict,
    Update,
    angle_facts,
    check_nonlinear,
    linearise,
    noise_fact,
    nonlinear_programs,
    sensor_measurement,
    stage_linearisation,
    state_jacobian,
    state_mapping,
    step_inputs,
    wrapped,
)
from .sensors import (
    IMPLICIT_SENSOR,
    gate_thresholds,
    kalman_update,
    renormalised,
    sensor_facts,
    sensor_groups,
    sequential_update,
    unit_norm_fact,
    unit_norm_noise,
    update_forms,
    uses_sensor_run,
)
from .sensors import reference_run as sensors_reference
from .spec import FilterSpec
from .unit import make_sensor_unit, make_unit
from .vector_rows import rows_fact, vector_predict, vector_update

JACOBIAN_FACT = ("Jacobians: sympy, polynomial entries as derived, others simplified, "
                 "evaluated with f and h through shared subexpressions")


def ekf_predict_parts(model, lin: Linearisation | None = None):
    """``parts(prog, mapping, x) -> (f, F, Q)``: f(x, u) and F = ∂f/∂x staged at x, and
    the process noise Q, with inputs in f and noise Qu on them Q(x, u) = Fu Qu Fu^T + Q,
    Fu = ∂f/∂u at x(k-1/k-1), u(k): the scalar work of the prediction. ``lin``: f and
    [F | Fu] (default :func:`state_jacobian`'s; the error-state EKF gives its own, over
    the tangent space: F is as wide as it is tall)."""
    own = lin is None
    lin = state_jacobian(model) if lin is None else lin
    n = lin.jacobian.rows
    used = [model.inputs.index(u) for u in model.f_inputs]
    Qu = sympy.Matrix(model.subs(model.Qu)).extract(used, used)

    invariant = unit_norm_noise(model) if own else {}

    def parts(prog, mapping, x):
        at_x = {**mapping, **state_mapping(model, x)}
        if invariant:  # where the invariant is used, it holds: the groups renormalised
            normalised = renormalised(prog, model, list(x))
            at_x.update(zip(model.state_symbols, normalised))
        Q = sympy.Matrix(model.subs(model.Q)).xreplace(at_x)
        values, FFu = stage_linearisation(prog, lin, at_x, "f")
        F = FFu[:, :n]
        if any(e != 0 for e in Qu):
            Fu = FFu[:, n:]
            FuQu = staging.matmul(prog, Fu, Qu.xreplace(mapping))
            mapped = sympy.Matrix(staging.matmul(prog, FuQu, Fu.T, symmetric_result=True))
            for (i, j), entry in invariant.items():
                mapped[i, j] = mapped[j, i] = prog.let(entry.xreplace(at_x), "qu")
            Q = staging.add(prog, mapped, Q, symmetric_result=True)
        return values, F, Q

    return parts


def ekf_predict_stage(model, parts=None) -> Predict:
    """x(k/k-1) = f(x, u), P(k/k-1) = F P F^T + Q (F = I folds to P + Q); with inputs in
    f and noise Qu on them, Q(x, u) = Fu Qu Fu^T + Q, Fu = ∂f/∂u at x(k-1/k-1), u(k).
    ``parts``: :func:`ekf_predict_parts` (default: of the model's f and its Jacobians)."""
    parts = ekf_predict_parts(model) if parts is None else parts

    def predict(prog, mapping, x, P):
        values, F, Q = parts(prog, mapping, x)
        FP = staging.matmul(prog, F, P)
        Pp = staging.add(prog, staging.matmul(prog, FP, F.T, symmetric_result=True), Q,
                         symmetric_result=True)
        return values, Pp

    return predict


def ekf_update_parts(model):
    """``parts(prog, mapping, meas, x) -> (h, H, R)``: h and H = ∂h/∂x staged at x
    (sharing h's work), and R at x: the scalar work of an update."""
    cache: dict[tuple, Linearisation] = {}

    def parts(prog, mapping, meas, x):
        key = tuple(sympy.srepr(e) for e in meas.h)
        if key not in cache:
            cache[key] = linearise(meas.h, model.state_symbols)
        at_x = {**mapping, **state_mapping(model, x)}
        values, H = stage_linearisation(prog, cache[key], at_x, "h")
        return values, H, meas.R.xreplace(at_x)

    return parts


def ekf_update_stage(model, iterations: int = 0) -> Update:
    """H at x(k/k-1) sharing h's work, S = H P H^T + R, K = P H^T S^-1 (LDL^T solve); or,
    for a sequential sensor, one scalar update per measurement (h and H at x(k/k-1)).
    ``iterations``: the iterated EKF's relinearisations (the module docstring)."""
    parts = ekf_update_parts(model)

    def update(prog, mapping, meas, x, P, z, loglik=False):
        values, H, R = parts(prog, mapping, meas, x)
        if meas.sequential and loglik:
            raise OptionError("option 'loglik' is not taken with sequential updates")
        if meas.sequential:
            innovation = wrapped(prog, staging.sub(prog, z, values), meas.angles)
            x_new, P_new, gated = sequential_update(prog, x, P, H, R, innovation, meas.gate,
                                                    meas.names)
            return (x_new, P_new, innovation, None) + ((gated,) if gated else ())
        at = x
        for _ in range(iterations + 1):
            if at is not x:  # relinearised at the last estimate; R stays at x(k/k-1)
                values, H, _R = parts(prog, mapping, meas, at)
            PHt = staging.matmul(prog, P, H.T)
            S = staging.add(prog, staging.matmul(prog, H, PHt, symmetric_result=True), R,
                            symmetric_result=True)
            staged = []

            def innovation(at=at, values=values, H=H, staged=staged):
                nu = wrapped(prog, staging.sub(prog, z, values), meas.angles)
                if at is not x:  # - H_i (x(k/k-1) - x_i)
                    nu = staging.sub(prog, nu, staging.matmul(
                        prog, H, staging.sub(prog, x, at)))
                staged.append(nu)
                return nu

            x_new, P_new, gated, *ll = kalman_update(prog, x, P, PHt, S, innovation,
                                                     meas.gate, loglik)
            at = x_new
        return (x_new, P_new, staged[0], S) + ((gated,) if gated else ()) + tuple(ll)

    return update


def derive_unit(model, spec, options):
    """The EKF unit: programs step, predict, update1 (see the module docstring); with
    several sensors, gating or update-first: predict and update_<sensor> (the run kind
    sensors, derive.filters.sensors)."""
    check_nonlinear(model, spec.name)
    iterations = options.iterations
    if (options.loglik or options.gradient) and (uses_sensor_run(model, options)
                                                 or iterations):
        raise OptionError("option 'loglik' is not taken with several sensors, gating, "
                          "update-first (the run kind sensors) or iterations")
    if uses_sensor_run(model, options) or model.unit_norm:
        if model.state_noise:
            raise OptionError(f"model {model.name!r}: a Q or R that depends on the state or "
                              "the inputs is evaluated by the plain EKF run only, not with "
                              "gating, update-first or unit-norm renormalisation")
    if uses_sensor_run(model, options):
        groups = sensor_groups(model)
        thresholds = gate_thresholds(groups, options)
        forms = update_forms(model, groups, options)
        sensors = {g.name: sensor_measurement(
            model, g, None if thresholds[g.name] is None else thresholds[g.name][1],
            sequential=forms[g.name] == "sequential") for g in groups}
        if iterations and any(m.sequential for m in sensors.values()):
            raise OptionError("option iterations: the iterated update relinearises a batch "
                              "update; sensor " + next(n for n, m in sensors.items()
                                                       if m.sequential)
                              + " is updated sequentially (--update batch)")
        programs, facts = nonlinear_programs(model, ekf_predict_stage(model),
                                             ekf_update_stage(model, iterations), options,
                                             spec.title, sensors=sensors,
                                             **_vector_rows(model, options))
        facts = ([JACOBIAN_FACT, *facts, *_facts(model, iterations)]
                 + sensor_facts(model, groups, thresholds, options.start, forms)
                 + unit_norm_fact(model, invariant=True) + rows_fact(programs))
        return make_sensor_unit(model, spec, programs, options, groups, thresholds,
                                model.f_inputs, facts)
    programs, facts = nonlinear_programs(model, ekf_predict_stage(model),
                                         ekf_update_stage(model, iterations), options,
                                         spec.title, **_vector_rows(model, options))
    carried = None
    if options.gradient:  # dx, dP carried beside x, P; entered as zero (derive.sensitivity)
        programs, carried = with_gradient(model, programs)
    unit = make_unit(model, spec, programs, options, step_inputs=step_inputs(model),
                     carried=carried)
    return _with_facts(unit, [JACOBIAN_FACT, *facts, *_facts(model, iterations),
                              *unit_norm_fact(model, invariant=True), *rows_fact(programs)])


def _facts(model, iterations: int) -> list[str]:
    """The header's lines on angles, a state-dependent Q or R and the iterated update."""
    out = angle_facts(model) + noise_fact(model, "x(k-1/k-1), u(k)", "x(k/k-1), u(k)")
    if iterations:
        out.append(f"iterated EKF update: h relinearised {iterations} time"
                   f"{'s' if iterations > 1 else ''} at the updated estimate, x_(i+1) = "
                   "x(k/k-1) + K_i (z - h(x_i) - H_i (x(k/k-1) - x_i)); P from the last "
                   "linearisation")
    return out


def _vector_rows(model, options) -> dict:
    """The builders of the predict and the sequential updates of vector rows, when the
    option ``rows`` (or the model, when the option is not given) asks for them
    (derive.filters.vector_rows)."""
    if (options.rows or model.rows) != "vector":
        return {}
    return {"vector_predict": partial(vector_predict, ekf_predict_parts(model)),
            "vector_update": partial(vector_update, ekf_update_parts(model))}


def _with_facts(unit, facts: list[str]):
    return replace(unit, facts=tuple(unit.facts) + tuple(facts))


def reference(model, data, options):
    """derive.reference.ekf on ``data`` = (scenario, numeric functions): (xs, Ps); an
    identity f is passed as None; angles, a state-dependent Q or R and the iterations as
    the unit's."""
    scenario, fns = data
    if model.unit_norm:  # renormalised after every update: the reference that does so
        res = sensors_reference(model, options, {IMPLICIT_SENSOR: scenario.zs}, scenario.us,
                                None, scenario.x0, scenario.P0)
        return res.xs, res.Ps
    res = _reference_result(model, scenario, fns, options)
    return res.xs, res.Ps


def _reference_result(model, scenario, fns, options):
    """derive.reference.ekf's NonlinearResult on the scenario; an identity f as None;
    angles, a state-dependent Q or R and the iterations as the unit's."""
    identity = list(model.subs(model.f)) == list(model.state_symbols)
    f, F = (None, None) if identity else (fns["f"], fns["F"])
    process = {"Fu_jac": fns["Fu"], "Qu": fns["Qu"]} if model.f_inputs else {}
    return numpy_reference.ekf(f, F, fns["h"], fns["H"], fns["Q"], fns["R"], scenario.x0,
                               scenario.P0, scenario.zs, inputs=list(scenario.us),
                               skip_nan=False, angles=model.angle_rows(),
                               iterations=options.iterations, m=model.m, **process)


def loglik_reference(model, data, options):
    """(each step's log-likelihood of the reference EKF's recorded innovations, its scale),
    ``data`` as :func:`reference` takes it (a model whose x is renormalised has none)."""
    scenario, fns = data
    if model.unit_norm:
        raise VerificationError(f"no reference log-likelihood for {model.name!r}, whose "
                                "state is renormalised after every update")
    res = _reference_result(model, scenario, fns, options)
    return innovations_loglik(res.innovations, res.innovation_covariances, scenario.zs)


SPECS = (FilterSpec(
    "ekf", "extended Kalman filter", "nonlinear", "timevarying", derive_unit, reference,
    options=ExtendedOptions, covariance=True, inputs=True, sensors=True, start=True,
    vector_rows=True,
    loglik=loglik_reference,
    extra_programs=("predict", "update1"),
    conditioning=CONDITIONING,  # the KF's: S solved, the update's subtraction
    listing=100,
    about={"python": "Run the extended Kalman filter: h linearised at each prediction."
                     + NOTE_PY,
           "c": "Run the extended Kalman filter over steps steps; Ps may be NULL." + NOTE_C}),)

__all__ = ["SPECS", "derive_unit", "ekf_predict_parts", "ekf_predict_stage",
           "ekf_update_stage"]
