"""What the filters that take several sensors share: the sensors of a unit, the gating
threshold, the gain-and-update stage with optional innovation gating, and the unit's
header facts.

A unit of the run kind ``sensors`` has ``predict(x, P[, u][, p])`` and one
``update_<sensor>(x, P, z[, u][, p])`` per sensor (its own h or H, R and inputs). A model
declaring two or more sensors gets this unit; a model with one sensor (or none declared)
gets it when an option asks for it (``gate``, ``gate_sensors`` or ``start="update"``),
with its one sensor named as declared, or ``all`` (every measurement) when none is.

Gating (opt-in): ``nis = nu^T S^-1 nu`` from the LDL^T factorisation that gives the gain
(one more right-hand side), compared with the chi-square quantile of the sensor's number
of measurements at the option's probability, computed at generation; the update is
applied only when ``nis <= threshold`` (a NaN NIS is not), by selects on the gain and the
solved innovation (one comparison each, no flop). The program returns ``nis`` and
``applied`` (1 or 0).

Sequential updates (option ``update="sequential"``, or ``Sensor.update``): a sensor whose R
is diagonal (or constant: decorrelated at generation) is fused one scalar measurement at a time
(:func:`sequential_update`, what PX4's ekf2 does), equal in exact arithmetic to the batch
update, NIS included; gating then selects between the updated and the prior x and P.
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np
import sympy

from .. import manifolds, staging
from ..domains import parameter_domains
from ..errors import OptionError
from ..expression_lowering import IfAtMost
from ..guards import numpy_selects
from ..model import SensorGroup, sequential_problem
from ..program import Program
from ..reference import sensors as reference
from ..symbols import jacobian
from .common import gaussian_loglik

IMPLICIT_SENSOR = "all"
"""The name of the one sensor of a model that declares none (all its measurements)."""


def sensor_groups(model) -> tuple[SensorGroup, ...]:
    """The model's sensors; one named :data:`IMPLICIT_SENSOR` when it declares none."""
    if model.sensors:
        return model.sensors
    if model.kind == "linear":
        return (SensorGroup(IMPLICIT_SENSOR, tuple(model.measurements), (0, model.m),
                            tuple(model.inputs), model.R, H=model.H, D=model.D),)
    return (SensorGroup(IMPLICIT_SENSOR, tuple(model.measurements), (0, model.m),
                        tuple(u for u in model.inputs if u in model.h.free_symbols), model.R,
                        h=model.h),)


def uses_sensor_run(model, options) -> bool:
    """Whether the unit is of the run kind ``sensors``: two or more sensors, a sensor whose
    R is given per call or updated sequentially, manifold states (the error-state EKF's
    unit is always of this kind), or gating, update-first or sequential updates asked
    for."""
    return (len(model.sensors) >= 2 or bool(getattr(model, "manifolds", ()))
            or any(g.R_argument for g in model.sensors)
            or options.get("update") == "sequential"
            or any(g.update == "sequential" for g in model.sensors)
            or options.get("gate") is not None
            or options.get("gate_sensors") is not None
            or options.get("start", "predict") != "predict")


def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square quantile with ``dof`` degrees of freedom at ``probability``."""
    # scipy.stats takes about half a second to import; only gated units need it
    from scipy.stats import chi2

    return float(chi2.ppf(probability, dof))


def gate_thresholds(groups, options) -> dict[str, tuple[float, float] | None]:
    """``{sensor: (probability, threshold) or None}`` from the options ``gate`` (every
    sensor) and ``gate_sensors`` (``"name=PROB,..."``, per sensor, overriding)."""
    probability = {g.name: options.get("gate") for g in groups}
    text = options.get("gate_sensors")
    if text:
        named: set[str] = set()
        for pair in text.split(","):
            name, value = pair.split("=", 1)
            if name in named:  # which one would hold is a guess: refused
                raise OptionError(f"option 'gate_sensors' (--gate-sensors) names sensor "
                                  f"{name!r} twice ({text!r})")
            named.add(name)
            if name not in probability:
                raise OptionError(f"option 'gate_sensors' (--gate-sensors) names sensor "
                                  f"{name!r}; the sensors are {', '.join(probability)}")
            try:
                prob = float(value)
            except ValueError:
                prob = float("nan")
            if not 0.0 < prob < 1.0:
                raise OptionError(f"option 'gate_sensors' (--gate-sensors): the probability "
                                  f"of {name!r} must be a number in (0, 1), got {value!r}")
            probability[name] = prob
    out: dict[str, tuple[float, float] | None] = {}
    for g in groups:
        prob = probability[g.name]
        out[g.name] = None if prob is None else (prob, chi2_quantile(prob, g.m))
    return out


def update_forms(model, groups, options) -> dict[str, str]:
    """``{sensor: "batch" or "sequential"}``: the option ``update`` for every sensor when
    given, else each sensor's own (``Sensor.update``); a sequential sensor whose R is given
    per call, or not diagonal and not constant, is refused (OptionError naming the sensor
    and the R entry)."""
    forms = {}
    for g in groups:
        form = options.get("update") or g.update
        if form == "sequential":
            problem = sequential_problem(g.name, model.subs(g.R), g.R_argument)
            if problem:
                raise OptionError(f"option 'update' (--update) sequential: {problem}")
        forms[g.name] = form
    return forms


def kalman_update(prog: Program, x, P, PHt, S, innovation_of, threshold: float | None = None,
                  loglik: bool = False):
    """``K = P H^T S^-1``, ``x + K nu``, ``P - K (P H^T)^T`` (upper triangle) through
    ``S = L D L^T`` without the back substitution: with ``Y = L^-1 (P H^T)^T`` and
    ``Z = D^-1 Y``, ``K (P H^T)^T = Z^T Y`` and ``K nu = Z^T L^-1 nu``. Returns
    ``(x_new, P_new, ())``, or with a ``threshold`` the gated update and ``(nis,
    applied)``: x and P unchanged when ``nis = (L^-1 nu)^T D^-1 (L^-1 nu)`` exceeds it.
    ``innovation_of()`` stages nu (after the gain's factors, in the papers' order, when
    ungated).  ``loglik`` (ungated): ``(x_new, P_new, (), ll)``, ll the log-likelihood of
    nu from the same pivots and ``L^-1 nu`` (derive.filters.common.gaussian_loglik)."""
    n = PHt.rows
    if threshold is None:
        L, pivots, Y, Z = staging.ldl_forward_pivots(prog, S, staging.transpose(PHt),
                                                     name="S")
        weights = staging.forward_substitute(prog, L, innovation_of())  # L^-1 nu
        x_new = staging.add(prog, x, staging.matmul(prog, Z.T, weights))
        ZtY = staging.matmul(prog, Z.T, Y, symmetric_result=True)
        ll = (gaussian_loglik(prog, pivots, weights),) if loglik else ()
        return (x_new, staging.sub(prog, P, ZtY, symmetric_result=True), ()) + ll
    m = PHt.cols
    innovation = innovation_of()
    L, Y, Z = staging.ldl_forward(prog, S, staging.transpose(PHt).row_join(innovation),
                                  name="S")
    weights = Y[:, n]  # L^-1 nu
    nis = prog.let(sympy.Add(*[weights[i] * Z[i, n] for i in range(m)]), "nis")
    bound = sympy.Float(threshold, 17)

    def gated(M):
        return staging.let_matrix(prog, M.applyfunc(lambda e: IfAtMost(nis, bound, e, 0)),
                                  hint="gated")

    applied = prog.let(IfAtMost(nis, bound, sympy.Integer(1), sympy.Integer(0)), "applied")
    x_new = staging.add(prog, x, staging.matmul(prog, Z[:, :n].T, gated(weights)))
    ZtY = staging.matmul(prog, gated(Z[:, :n]).T, Y[:, :n], symmetric_result=True)
    return x_new, staging.sub(prog, P, ZtY, symmetric_result=True), (nis, applied)


def decorrelated(prog: Program, H, R, innovation):
    """``(H, R, nu, correlated)``: a constant R that is not diagonal, R = L D L^T, gives the
    measurements L^-1 z with noise D: H and nu become L^-1 H and L^-1 nu (staged; L^-1 in
    exact rationals) and R becomes D; a diagonal R is returned as it is."""
    m = H.rows
    if not any(R[i, j] != 0 for i in range(m) for j in range(i + 1, m)):
        return H, R, innovation, False
    L, D = sympy.Matrix(R).LDLdecomposition(hermitian=False)
    whiten = L.inv()
    return (staging.matmul(prog, whiten, H, hint="hw"), D,
            staging.matmul(prog, whiten, innovation, hint="nuw"), True)


def sequential_update(prog: Program, x, P, H, R, innovation, threshold: float | None = None,
                      measurements: tuple[str, ...] = ()):
    """The update with ``z``'s m measurements fused one scalar at a time, h and H taken
    once at the prior x (a constant non-diagonal R = L D L^T is decorrelated first, at
    generation: H, nu and R become L^-1 H, L^-1 nu and D; L^-1 is exact rationals, and
    the NIS is unchanged): for i = 1..m, ``c = P H_i^T``, ``s_i = H_i c +
    R_ii`` (checked positive), ``nu~_i = nu_i - H_i (x_cur - x)``, ``k = c / s_i``,
    ``x_cur += k nu~_i``, ``P -= k c^T`` (upper triangle). In exact arithmetic this is
    :func:`kalman_update`: the s_i are the LDL^T pivots of S and the nu~_i the entries of
    ``L^-1 nu``, so ``nis = sum nu~_i^2 / s_i = nu^T S^-1 nu``. Returns ``(x_new, P_new,
    ())``, or with a ``threshold`` the gated update (x and P unchanged when ``nis``
    exceeds it: one select per entry) and ``(nis, applied)``. ``innovation``: nu (m x 1),
    staged by the caller; ``measurements``: their names, for the status messages."""
    n, m = H.cols, H.rows
    H, R, innovation, correlated = decorrelated(prog, H, R, innovation)
    # signs chosen so that every accumulation is a product added (one fma each): the
    # negated reciprocal -1/s_i, the negated gain -k, and back = x - x_cur
    back = sympy.zeros(n, 1)
    current = P
    nis_terms = []
    for i in range(m):
        row = H[i, :]
        c = staging.matmul(prog, current, row.T, hint="c")
        s = prog.let(sympy.Add(*[row[j] * c[j] for j in range(n)]) + R[i, i], "s")
        name = measurements[i] if i < len(measurements) else str(i)
        name += ", decorrelated by R's LDL^T factor" if correlated else ""
        prog.require_positive(s, f"S is not positive definite: the variance s of measurement "
                                 f"{i} ({name}) of the sequential update is not positive")
        whitened = prog.let(innovation[i] + sympy.Add(*[row[j] * back[j] for j in range(n)]),
                            "nu")
        negated = prog.let(-1 / s, "nsinv")  # -1/s_i
        minus_gain = staging.scale(prog, c, negated, hint="k")
        minus_weight = prog.let(whitened * negated, "w")  # -nu~_i / s_i
        back = staging.let_matrix(prog, back + c * minus_weight, hint="dx")
        current = staging.let_matrix(prog, current + minus_gain * c.T, symmetric_result=True)
        if threshold is not None:
            nis_terms.append(whitened * minus_weight)
    x_new = staging.sub(prog, x, back)
    if threshold is None:
        return x_new, current, ()
    nis = prog.let(-prog.let(sympy.Add(*nis_terms), "nnis"), "nis")
    bound = sympy.Float(threshold, 17)
    applied = prog.let(IfAtMost(nis, bound, sympy.Integer(1), sympy.Integer(0)), "applied")

    def gated(new, old, symmetric):
        return staging.let_matrix(prog, sympy.Matrix(new.rows, new.cols, lambda i, j: IfAtMost(
            nis, bound, new[i, j], old[i, j])), symmetric_result=symmetric, hint="gated")
    return gated(x_new, x, False), gated(current, P, True), (nis, applied)


def renormalised(prog: Program, model, x):
    """``x`` with each of the model's unit-norm groups divided by its Euclidean norm
    (one square root and one division per group, then a product per state)."""
    groups = getattr(model, "unit_norm", ())
    if not groups:
        return x
    out = sympy.Matrix(x)
    for group in groups:
        index = [model.states.index(s) for s in group]
        norm2 = prog.let(sympy.Add(*[out[i] ** 2 for i in index]), "norm2")
        inverse = prog.let(1 / sympy.sqrt(norm2), "inorm")
        for i in index:
            out[i] = prog.let(out[i] * inverse, "x")
    return out


@lru_cache(maxsize=16)
def unit_norm_noise(model) -> dict[tuple[int, int], sympy.Expr]:
    """The entries (i, j), i <= j, of the mapped input noise ``Fu Qu Fu^T`` that a
    unit-norm group's invariant ``sum q^2 = 1`` makes cheaper: each entry's polynomial
    reduced modulo ``sum q^2 - 1`` eliminating one of the group's states (each tried),
    kept where it has fewer operations than the entry (sympy ``count_ops``). For a
    quaternion rotating a noise that is the same on three axes, ``C Qa C^T`` is ``Qa``,
    and the quaternion's own block ``(dt^2 sg^2 / 4) (|q|^2 I - q q^T)`` has ``1 - q_i^2``
    on its diagonal. Exact only where the group is unit: the EKF's predict renormalises
    the groups at its start when this is not empty. Cached per model (the generator and
    the header's facts both ask)."""
    out: dict[tuple[int, int], sympy.Expr] = {}
    used = [model.inputs.index(u) for u in model.f_inputs]
    Qu = sympy.Matrix(model.subs(model.Qu)).extract(used, used) if used else None
    if getattr(model, "unit_norm", ()) and Qu is not None and any(e != 0 for e in Qu):
        Fu = sympy.Matrix(model.subs(model.Fu_jacobian)).extract(list(range(model.n)), used)
        rows = [i for i in range(model.n) if any(e != 0 for e in Fu.row(i))]
        gens = sorted(set().union(*(e.free_symbols for e in Fu), *(e.free_symbols for e in Qu)),
                      key=str)
        # polynomials over every symbol (sympy's sparse products, not expand)
        Fp = {(i, k): sympy.Poly(Fu[i, k], *gens) for i in rows for k in range(len(used))}
        Qp = {(a, b): sympy.Poly(Qu[a, b], *gens) for a in range(len(used))
              for b in range(len(used)) if Qu[a, b] != 0}
        for group in model.unit_norm:
            q = [model.state_symbols[model.states.index(name)] for name in group]
            for i in rows:
                for j in (j for j in rows if j >= i):
                    entry = sum((Fp[i, a] * Qp[a, b] * Fp[j, b] for a, b in Qp),
                                sympy.Poly(0, *gens))
                    index = [gens.index(v) for v in q if v in gens]
                    squared = [gens[k] for k in index
                               if any(e[k] >= 2 for e in entry.monoms())]
                    if entry.is_zero or not squared:  # nothing for the invariant to reduce
                        continue
                    best, cost = None, sympy.count_ops(entry.as_expr())
                    for qk in squared:  # modulo qk^2 + (the others' squares) - 1, by qk
                        order = [qk] + [v for v in gens if v != qk]
                        invariant = sympy.Poly(sympy.Add(*[v ** 2 for v in q]) - 1, *order)
                        rest = sympy.Poly(entry.as_expr(), *order).rem(invariant).as_expr()
                        if sympy.count_ops(rest) < cost:
                            best, cost = rest, sympy.count_ops(rest)
                    if best is not None:
                        out[i, j] = sympy.factor_terms(best)
    return out


UNIT_NORM_FACT = "unit-norm groups, renormalised at the end of every update: {groups}"
INVARIANT_FACT = ("invariants used: {invariants} in Q(x, u) = Fu Qu Fu^T, entries {entries} "
                  "(reduced modulo it where that is cheaper); exact: predict renormalises "
                  "the groups at its start, so f, F, Fu and Q are taken at unit groups")


def unit_norm_fact(model, invariant: bool = False) -> list[str]:
    """The header lines naming the model's unit-norm groups and, with ``invariant`` (the
    EKF), the invariants its predict uses (none without)."""
    groups = getattr(model, "unit_norm", ())
    if not groups:
        return []
    out = [UNIT_NORM_FACT.format(groups="; ".join("(" + ", ".join(g) + ")" for g in groups))]
    used = unit_norm_noise(model) if invariant else {}
    if used:
        out.append(INVARIANT_FACT.format(
            invariants=", ".join(" + ".join(f"{s}^2" for s in g) + " = 1" for g in groups),
            entries=", ".join(f"({i}, {j})" for i, j in sorted(used))))
    return out


def sensor_facts(model, groups, thresholds, start: str,
                 forms: dict[str, str] | None = None) -> list[str]:
    """Header lines: the sensors, their update forms and gates, the run's convention."""
    lines = ["sensors (run: predict with u(k), then each sensor's update in this order "
             "when its row k has no NaN): " + "; ".join(
                 f"{g.name} ({', '.join(g.measurements)}"
                 + (f"; inputs {', '.join(u.name for u in g.inputs)}" if g.inputs else "")
                 + ")" for g in groups)]
    for g in groups:
        if forms and forms[g.name] == "sequential":
            diagonal = all(g.R[i, j] == 0 for i in range(g.m) for j in range(i + 1, g.m))
            noise = ("R diagonal" if diagonal else
                     "R = L D L^T not diagonal: L^-1 z fused, its noise D")
            lines.append(f"update of {g.name}: sequential, one scalar update per measurement "
                         f"in the order {', '.join(g.measurements)} ({noise}; h and H at the "
                         "prior x; nis = sum of the whitened innovations squared over their "
                         "variances, the batch update's nu' S^-1 nu)")
        gate = thresholds[g.name]
        if gate is not None:
            lines.append(f"gate of {g.name}: update applied when nis <= {gate[1]!r} (the "
                         f"chi-square quantile for {g.m} degrees of freedom at {gate[0]!r}); "
                         f"update_{g.name} returns nis and applied (1 or 0)")
    lines.append("start: " + ("update-first: step 0 updates x0, P0 with its measurements, "
                              "without a prediction" if start == "update" else
                              "predict-first: every step predicts, then updates"))
    return lines


def program_name(sensor: str) -> str:
    """``update_<sensor>``."""
    return f"update_{sensor}"


SENSOR_PROGRAM = re.compile(r"^update_[A-Za-z][A-Za-z0-9_]*$")




# -- the NumPy reference of a model's sensor unit --------------------------------------------


def numeric_matrix(model, matrix, arguments):
    """``matrix`` (valued symbols substituted) as a NumPy function of ``arguments`` (lists
    of symbols, one list per argument), returning a 2-D array of its shape."""
    lam = sympy.lambdify(arguments, sympy.Matrix(model.subs(matrix)),
                         modules=[numpy_selects(), "numpy"], cse=True)
    shape = matrix.shape

    def call(*values):
        return np.asarray(lam(*[list(np.ravel(v)) for v in values]),
                          dtype=float).reshape(shape)
    return call


def transition_function(model):
    """``F(x, u, p)``: the model's transition matrix (linear: F(p)) or the Jacobian of f
    with respect to x (nonlinear) at numbers, (n, n), u all of the model's inputs; for a
    model with manifold states the error map over the tangent space, M(f(x, u)) ∂f/∂x
    N(x) (n_tangent x n_tangent, derive.manifolds)."""
    params = list(model.parameters)
    if model.kind == "linear":
        F = numeric_matrix(model, model.F, [params])
        return lambda x, u, p: F(p)
    X, U = list(model.state_symbols), list(model.inputs)
    J = numeric_matrix(model, model.F_jacobian, [X, U, params])
    layout = getattr(model, "layout", None)
    if layout is None:
        return J
    f = numeric_matrix(model, model.f, [X, U, params])

    def tangent(x, u, p):
        return (manifolds.lift_numeric(layout, f(x, u, p).ravel()) @ J(x, u, p)
                @ manifolds.retraction_numeric(layout, x))
    return tangent


def reference_functions(model, thresholds):
    """``(predict, [SensorFunctions], unit-norm index groups)`` of ``model`` at numbers,
    with p as an argument (one row per step: dt may vary), for derive.reference.sensors."""
    params = list(model.parameters)
    groups = sensor_groups(model)
    names = [u.name for u in model.inputs]
    sensors = []
    F = transition_function(model)
    if model.kind == "linear":
        B = numeric_matrix(model, model.B, [params])
        W = numeric_matrix(model, model.matrix("GQGt"), [params])

        def predict(x, P, u, p):
            A = F(x, u, p)
            x_new = A @ x + (B(p) @ u if names else 0.0)
            return x_new, A @ P @ A.T + W(p)

        for g in groups:
            H = numeric_matrix(model, g.H, [params])
            D = numeric_matrix(model, g.D, [params])
            R = None if g.R_argument else numeric_matrix(model, g.R, [params])
            sensors.append(reference.SensorFunctions(
                g.name, lambda x, u, p, H=H, D=D: H(p) @ x + (D(p) @ u if u.size else 0.0),
                lambda x, u, p, H=H: H(p), None if R is None else lambda x, u, p, R=R: R(p),
                tuple(names.index(u.name) for u in g.inputs),
                None if thresholds[g.name] is None else thresholds[g.name][1]))
    else:
        X, U = list(model.state_symbols), list(model.inputs)
        f = numeric_matrix(model, model.f, [X, U, params])
        Fu = numeric_matrix(model, model.Fu_jacobian, [X, U, params])
        Q = numeric_matrix(model, model.Q, [params])
        Qu = numeric_matrix(model, model.Qu, [params])

        first = [[model.states.index(s) for s in group] for group in model.unit_norm] \
            if unit_norm_noise(model) else []

        def predict(x, P, u, p):
            x = reference.renormalise(x, first)  # as the EKF's predict, using the invariant
            A, G = F(x, u, p), Fu(x, u, p)
            Qx = Q(p) + (G @ Qu(p) @ G.T if names else 0.0)
            return f(x, u, p).ravel(), A @ P @ A.T + Qx

        for g in groups:
            own = list(g.inputs)
            h = numeric_matrix(model, g.h, [X, own, params])
            H = numeric_matrix(model, jacobian(g.h, model.state_symbols), [X, own, params])
            R = None if g.R_argument else numeric_matrix(model, g.R, [X, own, params])
            sensors.append(reference.SensorFunctions(
                g.name, lambda x, u, p, h=h: h(x, u, p).ravel(), H, R,
                tuple(names.index(u.name) for u in g.inputs),
                None if thresholds[g.name] is None else thresholds[g.name][1],
                model.angle_rows(g.measurements)))
    unit_norm = [[model.states.index(s) for s in group]
                 for group in getattr(model, "unit_norm", ())]
    return predict, sensors, unit_norm


def reference_run(model, options, zs: dict, us=None, ps=None, x0=None, P0=None, Rs=None,
                  trace: list | None = None):
    """derive.reference.sensors.run for ``model`` and the filter ``options`` from x0 and
    P0 (default: the model's); ``ps``: p, one row per step; ``Rs``: the per-step R of the
    sensors whose R is given per call; ``trace``: a list each step's
    derive.reference.sensors.StepTrace is appended to."""
    groups = sensor_groups(model)
    predict, sensors, unit_norm = reference_functions(model, gate_thresholds(groups, options))
    num_x0 = np.array(model.x0.tolist(), dtype=float).ravel() if x0 is None else x0
    num_P0 = np.array(model.P0.tolist(), dtype=float) if P0 is None else P0
    return reference.run(predict, sensors, num_x0, num_P0, zs, us, ps,
                         update_first=options.get("start", "predict") == "update",
                         unit_norm=unit_norm, Rs=Rs, trace=trace,
                         domains=parameter_domains(model.parameters))


__all__ = ["IMPLICIT_SENSOR", "chi2_quantile", "numeric_matrix", "gate_thresholds", "kalman_update",
           "program_name", "reference_functions", "reference_run", "renormalised",
           "sensor_facts", "sensor_groups", "sequential_update", "transition_function",
           "unit_norm_fact", "update_forms", "uses_sensor_run"]
