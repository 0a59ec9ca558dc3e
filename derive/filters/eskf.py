"""The error-state (multiplicative) extended Kalman filter, for models with manifold states.

A model that declares a unit quaternion or an angle (derive.manifolds) keeps its nominal
state x in the storage space (n numbers) and its covariance P in the tangent space
(n_tangent x n_tangent: a quaternion's error is a rotation vector δθ of 3). One step:

    predict   x(k/k-1) = π(f(x, u))          π: quaternions renormalised, angles wrapped
              P(k/k-1) = Fδ P Fδ^T + Fuδ Qu Fuδ^T + Q
    update    δx = K (z - h(x(k/k-1))),  K = P Hδ^T (Hδ P Hδ^T + R)^-1
              x(k/k) = x(k/k-1) ⊞ δx,  P(k/k) = P - K Hδ P   [then G P G^T: option reset]

with the Jacobians of the error dynamics at zero error, derived by sympy. An angle
measurement's innovation z - h is wrapped to (-π, π] (derive.filters.nonlinear.wrapped);
an R that depends on the state or the inputs is evaluated at x(k/k-1), as h is:

    Fδ = M(f(x, u)) ∂f/∂x N(x),   Fuδ = M(f(x, u)) ∂f/∂u,   Hδ = ∂h/∂x N(x)

N(x) = ∂(x ⊞ δ)/∂δ at δ = 0 and M(y) = ∂(y' ⊟ y)/∂y' at y' = y (derive.manifolds). The
nominal quaternion has unit norm (it is renormalised after every prediction and
injection), so every entry that is polynomial in a quaternion is also reduced modulo its
unit-norm relation q0² + q1² + q2² + q3² = 1 (a polynomial division by that relation),
and the reduced form is kept where it has fewer operations: a local quaternion's block of
Fδ under a first-order f, q ⊗ [1, ω dt/2], reduces to the rotation R(Ω)^T of the
increment Ω = [1, ω dt/2] over its norm, free of q.

The reset (option ``reset``): the error after the injection is taken about the new
nominal state, ``P <- G P G^T`` with ``G = ∂((x ⊞ (δx + e)) ⊟ (x ⊞ δx))/∂e`` at e = 0,
derived by sympy for the injection's first-order form: a local quaternion's
``(I - [δθ/2]x) / (1 + |δθ|²/4)``, a global one's ``(I + [δθ/2]x) / (1 + |δθ|²/4)``.

The unit is of the run kind ``sensors``: ``predict`` and one ``update_<sensor>`` per
sensor (one named ``all`` for a model that declares none).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
import sympy

from .. import manifolds as mf
from .. import staging
from ..domains import parameter_domains
from ..options import SharedOptions, option
from ..reference import eskf as eskf_reference
from ..reference import sensors as sensors_reference
from ..reference.sensors import SensorFunctions
from ..symbols import jacobian
from .ekf import ekf_predict_parts, ekf_predict_stage
from .kf import CONDITIONING
from .nonlinear import (
    Linearisation,
    angle_facts,
    check_nonlinear,
    noise_fact,
    nonlinear_programs,
    sensor_measurement,
    stage_linearisation,
    state_mapping,
    wrapped,
)
from .sensors import (
    IMPLICIT_SENSOR,
    gate_thresholds,
    kalman_update,
    numeric_matrix,
    sensor_facts,
    sensor_groups,
    sequential_update,
    unit_norm_fact,
    update_forms,
)
from .spec import FilterSpec
from .unit import make_sensor_unit
from .vector_rows import rows_fact, vector_predict


@dataclass(frozen=True, kw_only=True)
class EskfOptions(SharedOptions):
    """The options of the error-state EKF."""

    reset: bool = option(False, flag="--reset", kind=bool, help=(
        "eskf: after each injection apply the reset Jacobian, P <- G P G^T (the error "
        "taken about the new nominal state; derived by sympy)"))


# -- the unit-norm relation --------------------------------------------------------------


def _quaternion_symbols(model) -> list[tuple[sympy.Symbol, ...]]:
    return [tuple(model.state_symbols[i] for i in stored)
            for m, (stored, _) in zip(model.layout.manifolds, model.layout.slots)
            if m.kind == mf.QUATERNION]


def _reduced(expr: sympy.Expr, quaternions) -> sympy.Expr:
    """``expr`` reduced modulo the unit-norm relation of each quaternion it is polynomial
    in (the remainder of its division by q0² + q1² + q2² + q3² - 1), when that has fewer
    operations; an entry not polynomial in a quaternion is kept as it is."""
    candidate = expr
    for q in quaternions:
        if not set(q) & candidate.free_symbols:
            continue
        if not candidate.is_polynomial(*q):
            return expr
        # over q (q0 first: the remainder replaces q0² by 1 - q1² - q2² - q3²), the other
        # symbols in the coefficients, which stay grouped by q's monomials
        relation = sympy.Poly(sum(s ** 2 for s in q) - 1, *q)
        candidate = sympy.Poly(candidate, *q).rem(relation).as_expr()
    if candidate is expr:
        return expr
    return candidate if sympy.count_ops(candidate) < sympy.count_ops(expr) else expr


# -- the error-state Jacobians ---------------------------------------------------------------


def error_dynamics(model) -> Linearisation:
    """f (n values) and [Fδ | Fuδ] (n_tangent x (n_tangent + len(f_inputs))) over shared
    subexpressions (the module docstring)."""
    layout = model.layout
    X = list(model.state_symbols)
    f = [sympy.sympify(e) for e in model.subs(model.f)]
    J = sympy.Matrix(f).jacobian(X + list(model.f_inputs))
    A, scale = mf.lift_jacobian(layout, f)
    N = mf.retraction_jacobian(layout, X)
    quaternions = _quaternion_symbols(model)
    Fx = A * J[:, :len(X)] * N
    Fu = A * J[:, len(X):]
    whole = Fx.row_join(Fu)
    # a quaternion's rows of M carry 2/|y|²: numerators and |y|² reduced apart
    norms = {t: _reduced(norm2, quaternions) for t, (norm2, _) in scale.items()}
    jac = sympy.Matrix(whole.rows, whole.cols, lambda i, j: _reduced(whole[i, j], quaternions)
                       / norms.get(i, 1))
    return _shared(f, jac)


def measurement_jacobian(model, h: sympy.Matrix) -> Linearisation:
    """h and Hδ = ∂h/∂x N(x) over shared subexpressions."""
    X = list(model.state_symbols)
    values = [sympy.sympify(e) for e in h]
    H = sympy.Matrix(values).jacobian(X) * mf.retraction_jacobian(model.layout, X)
    quaternions = _quaternion_symbols(model)
    return _shared(values, H.applyfunc(lambda e: _reduced(e, quaternions)))


def _shared(values: list[sympy.Expr], jac: sympy.Matrix) -> Linearisation:
    names = sympy.numbered_symbols("_shared", real=True)
    pairs, reduced = sympy.cse(values + list(jac), symbols=names, order="canonical")
    k = len(values)
    return Linearisation(tuple(pairs), tuple(reduced[:k]),
                         sympy.ImmutableMatrix(jac.rows, jac.cols, reduced[k:]))


def reset_jacobian(layout: mf.TangentLayout, delta: list[sympy.Expr]) -> sympy.Matrix:
    """G(δ) = ∂((x ⊞ (δ + e)) ⊟ (x ⊞ δ))/∂e at e = 0 (n_tangent x n_tangent) for the
    injection's first-order form, with the quaternion's unit norm applied: the nominal
    quaternion cancels (L(p*) L(q*) L(q) = L(p*) for |q| = 1), leaving G of δ alone."""
    G = sympy.eye(layout.n_tangent)
    e = sympy.symbols("_e0:3", real=True)
    d = sympy.symbols("_d0:3", real=True)
    for m, (_, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind != mf.QUATERNION:
            continue
        p = [sympy.Integer(1)] + [di / 2 for di in d]
        pe = [sympy.Integer(1)] + [(di + ei) / 2 for di, ei in zip(d, e)]
        # local: 2 vec(p^ * ⊗ pe^), global: 2 vec(pe^ ⊗ p^ *), p^ = p / |p|
        star = mf.conjugate(p)
        product = ([sum(mf.left(star)[r][c] * pe[c] for c in range(4)) for r in range(4)]
                   if m.error == mf.LOCAL else
                   [sum(mf.right(star)[r][c] * pe[c] for c in range(4)) for r in range(4)])
        norm = sympy.sqrt(sum(v ** 2 for v in p)) * sympy.sqrt(sum(v ** 2 for v in pe))
        error = [2 * product[r] / norm for r in (1, 2, 3)]
        at_zero = {ei: 0 for ei in e}
        block = sympy.Matrix(3, 3, [sympy.simplify(sympy.diff(error[r], e[c]).subs(at_zero))
                                    for r in range(3) for c in range(3)])
        block = block.xreplace({di: delta[t] for di, t in zip(d, tangent)})
        for r, tr in enumerate(tangent):
            for c, tc in enumerate(tangent):
                G[tr, tc] = block[r, c]
    return G


# -- the stages --------------------------------------------------------------------------


def eskf_predict_parts(model):
    """``parts(prog, mapping, x) -> (π(f), Fδ, Fuδ Qu Fuδ^T + Q)``: the scalar work of the
    prediction (derive.filters.ekf.ekf_predict_parts with the error-state Jacobians), its
    x projected onto the manifold."""
    parts = ekf_predict_parts(model, error_dynamics(model))

    def projected(prog, mapping, x):
        values, F, Q = parts(prog, mapping, x)
        return _projected(prog, model.layout, values), F, Q

    return projected


def _projected(prog, layout: mf.TangentLayout, values) -> sympy.Matrix:
    """π(values) staged: each quaternion over its norm, each angle wrapped."""
    out = sympy.Matrix(values)
    for m, (stored, _) in zip(layout.manifolds, layout.slots):
        if m.kind == mf.ANGLE:
            out[stored[0]] = prog.let(mf.wrap(out[stored[0]]), "x")
            continue
        norm2 = prog.let(sympy.Add(*[out[i] ** 2 for i in stored]), "norm2")
        inverse = prog.let(1 / sympy.sqrt(norm2), "inorm")
        for i in stored:
            out[i] = prog.let(out[i] * inverse, "x")
    return out


def _injected(prog, layout: mf.TangentLayout, x, delta) -> sympy.Matrix:
    """x ⊞ δ staged (derive.manifolds.boxplus, its norm taken once)."""
    out = sympy.Matrix(x)
    for i, t in layout.euclidean:
        out[i] = prog.let(x[i] + delta[t], "x")
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == mf.ANGLE:
            out[stored[0]] = prog.let(mf.wrap(x[stored[0]] + delta[tangent[0]]), "x")
            continue
        q = [x[i] for i in stored]
        half = [prog.let(delta[t] / 2, "dh") for t in tangent]
        dq = [sympy.Integer(1)] + half
        basis = mf.left(q) if m.error == mf.LOCAL else mf.right(q)
        product = [prog.let(sympy.Add(*[basis[r][c] * dq[c] for c in range(4)]), "qp")
                   for r in range(4)]
        norm2 = prog.let(sympy.Add(*[v ** 2 for v in product]), "norm2")
        inverse = prog.let(1 / sympy.sqrt(norm2), "inorm")
        for i, v in zip(stored, product):
            out[i] = prog.let(v * inverse, "x")
    return out


def eskf_update_stage(model, reset: bool):
    """h and Hδ at x(k/k-1), δx = K ν (batch, LDL^T, or sequential), x ⊞ δx, and with
    ``reset`` P <- G P G^T."""
    cache: dict[tuple, Linearisation] = {}
    layout, nt = model.layout, model.n_tangent

    def update(prog, mapping, meas, x, P, z):
        key = tuple(sympy.srepr(e) for e in meas.h)
        if key not in cache:
            cache[key] = measurement_jacobian(model, meas.h)
        at_x = {**mapping, **state_mapping(model, x)}
        values, H = stage_linearisation(prog, cache[key], at_x, "h")
        R = meas.R.xreplace(at_x)  # a state-dependent R at x(k/k-1), as h
        zero = sympy.zeros(nt, 1)
        innovation = wrapped(prog, staging.sub(prog, z, values), meas.angles)
        if meas.sequential:
            delta, P_new, gated = sequential_update(prog, zero, P, H, R, innovation,
                                                    meas.gate, meas.names)
            variance = None
        else:
            PHt = staging.matmul(prog, P, H.T)
            variance = staging.add(prog, staging.matmul(prog, H, PHt, symmetric_result=True),
                                   R, symmetric_result=True)
            delta, P_new, gated = kalman_update(prog, zero, P, PHt, variance,
                                                lambda: innovation, meas.gate)
        x_new = _injected(prog, layout, x, delta)
        if reset:
            G = staging.let_matrix(prog, reset_jacobian(layout, list(delta)), hint="G")
            GP = staging.matmul(prog, G, P_new)
            P_new = staging.matmul(prog, GP, G.T, symmetric_result=True)
        return (x_new, P_new, innovation, variance) + ((gated,) if gated else ())

    return update


# -- the unit --------------------------------------------------------------------------------


def error_fact(model) -> list[str]:
    """The header lines of the manifold states, the tangent space and the injection."""
    layout = model.layout
    return ["manifold states: " + "; ".join(m.describe() for m in layout.manifolds),
            f"tangent space ({layout.n_tangent}; P, P0, Q are over it): "
            + ", ".join(layout.tangent),
            "error-state Jacobians: F = M(f(x, u)) df/dx N(x), Fu = M(f(x, u)) df/du, "
            "H = dh/dx N(x), N = d(x [+] d)/dd at d = 0, M = d(y' [-] y)/dy' at y' = y; "
            "sympy, reduced modulo each quaternion's unit norm where that has fewer "
            "operations, evaluated with f and h through shared subexpressions",
            "predict: x(k/k-1) = f(x, u) with each quaternion renormalised and each angle "
            "wrapped; update: dx = K nu injected, " + mf.INJECTION]


def derive_unit(model, spec, options):
    """The error-state EKF unit: predict and update_<sensor> (run kind sensors)."""
    check_nonlinear(model, spec.name)
    groups = sensor_groups(model)
    thresholds = gate_thresholds(groups, options)
    forms = update_forms(model, groups, options)
    sensors = {g.name: sensor_measurement(
        model, g, None if thresholds[g.name] is None else thresholds[g.name][1],
        sequential=forms[g.name] == "sequential") for g in groups}
    parts = eskf_predict_parts(model)
    vector = {}
    if (options.rows or model.rows) == "vector":  # the updates stay scalar rows
        vector = {"vector_predict": partial(vector_predict, parts)}
    programs, facts = nonlinear_programs(model, ekf_predict_stage(model, parts),
                                         eskf_update_stage(model, options.reset), options,
                                         spec.title, sensors=sensors, **vector)
    facts = (error_fact(model) + [
        "reset: P <- G P G^T after each injection, G = d((x [+] (dx + e)) [-] (x [+] dx))/de "
        "at e = 0 (sympy)" if options.reset else
        "reset: none (G = I; option reset applies G P G^T)"]
        + angle_facts(model) + noise_fact(model, "x(k-1/k-1), u(k)", "x(k/k-1), u(k)")
        + facts + sensor_facts(model, groups, thresholds, options.start, forms)
        + unit_norm_fact(model) + rows_fact(programs))
    return make_sensor_unit(model, spec, programs, options, groups, thresholds,
                            model.f_inputs, facts)


def reference_predict(model):
    """``predict(x, P, u, p) -> (x(k/k-1), P(k/k-1))`` of the error-state reference at
    numbers (u: all the model's inputs; p: its parameters): the model's sympy ∂f/∂x and
    ∂f/∂u taken into the tangent space by derive.manifolds' numeric N and M."""
    layout = model.layout
    params = list(model.parameters)
    X, U = list(model.state_symbols), list(model.inputs)
    f = numeric_matrix(model, model.f, [X, U, params])
    F = numeric_matrix(model, model.F_jacobian, [X, U, params])
    Fu = numeric_matrix(model, model.Fu_jacobian, [X, U, params])
    Q = numeric_matrix(model, model.Q, [params])
    Qu = numeric_matrix(model, model.Qu, [params])

    def predict(x, P, u, p):
        y = f(x, u, p).ravel()
        M = mf.lift_numeric(layout, y)
        A = M @ F(x, u, p) @ mf.retraction_numeric(layout, x)
        G = M @ Fu(x, u, p)
        return (mf.project_numeric(layout, y),
                A @ P @ A.T + Q(p) + (G @ Qu(p) @ G.T if U else 0.0))

    return predict


def reference_run(model, options, zs: dict, us=None, ps=None, x0=None, P0=None, Rs=None,
                  trace: list | None = None):
    """The error-state reference (derive.reference.sensors.run with an injection and a
    reset) for ``model`` at numbers (p as an argument, one row per step; ``Rs``: the
    per-step R of the sensors whose R is given per call), from x0 and P0 (default: the
    model's): the model's sympy Jacobians ∂f/∂x, ∂f/∂u, ∂h/∂x at numbers, taken into the
    tangent space by derive.manifolds' numeric N and M; injection by its numeric ⊞; the
    reset (option ``reset``) by Solà's G (derive.reference.eskf)."""
    layout = model.layout
    params = list(model.parameters)
    X = list(model.state_symbols)
    predict = reference_predict(model)
    thresholds = gate_thresholds(sensor_groups(model), options)
    names = [u.name for u in model.inputs]
    sensors = []
    for g in sensor_groups(model):
        own = list(g.inputs)
        h = numeric_matrix(model, g.h, [X, own, params])
        H = numeric_matrix(model, jacobian(g.h, model.state_symbols), [X, own, params])
        sensors.append(SensorFunctions(
            g.name, lambda x, u, p, h=h: h(x, u, p).ravel(),
            lambda x, u, p, H=H: H(x, u, p) @ mf.retraction_numeric(layout, x),
            None if g.R_argument else numeric_matrix(model, g.R, [X, own, params]),
            tuple(names.index(u.name) for u in g.inputs),
            None if thresholds[g.name] is None else thresholds[g.name][1],
            model.angle_rows(g.measurements)))

    def reset(dx):
        G = np.eye(layout.n_tangent)
        for m, (_, tangent) in zip(layout.manifolds, layout.slots):
            if m.kind == mf.QUATERNION:
                G[np.ix_(tangent, tangent)] = eskf_reference.quaternion_reset(
                    dx[list(tangent)], local=m.error == mf.LOCAL)
        return G

    return sensors_reference.run(
        predict, sensors,
        np.array(model.x0.tolist(), dtype=float).ravel() if x0 is None else x0,
        np.array(model.P0.tolist(), dtype=float) if P0 is None else P0, zs, us, ps,
        update_first=options.get("start", "predict") == "update",
        unit_norm=[[model.states.index(s) for s in group] for group in model.unit_norm],
        Rs=Rs, trace=trace, domains=parameter_domains(model.parameters),
        inject=lambda x, dx: mf.boxplus_numeric(layout, x, dx),
        reset=reset if options.get("reset", False) else None)


def reference(model, data, options):
    """The reference on a nonlinear scenario (its measurements as the one sensor of a
    model that declares none): (xs, Ps)."""
    scenario, _ = data
    res = reference_run(model, options, {IMPLICIT_SENSOR: scenario.zs}, scenario.us, None,
                        scenario.x0, scenario.P0)
    return res.xs, res.Ps


SPECS = (FilterSpec(
    "eskf", "error-state extended Kalman filter", "nonlinear", "sensors", derive_unit,
    reference, options=EskfOptions, covariance=True, inputs=True, sensors=True, start=True,
    manifolds=True, vector_rows=True, sensors_reference=reference_run,
    conditioning=CONDITIONING, listing=105,
    about={"python": "Run the error-state EKF: predict the nominal state, update its error "
                     "in the tangent space and inject it.",
           "c": "Run the error-state EKF over steps steps; Ps may be NULL."}),)

__all__ = ["SPECS", "EskfOptions", "derive_unit", "error_dynamics", "measurement_jacobian",
           "reference_predict", "reset_jacobian"]
