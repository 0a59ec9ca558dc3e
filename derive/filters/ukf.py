"""The unscented Kalman filter for any NonlinearModel, as straight-line programs.

Weights, the scaled form of Wan and van der Merwe (as derive.reference.sigma_weights):
``c = alpha² (n + kappa)``, ``Wm0 = (c - n)/c``, ``Wc0 = Wm0 + 1 - alpha² + beta``,
``Wi = 1/(2c)``; options ``alpha``, ``beta``, ``kappa`` (defaults 1, 0, 3 - n: the paper's
plain UKF with n + kappa = 3, so W0 = kappa/(n + kappa) < 0 for n > 3).

Sigma points of (x, P): ``X0 = x``, ``X_i = x + sqrt(c) L_i``, ``X_n+i = x - sqrt(c) L_i``
with ``L`` the unrolled lower Cholesky factor of P; each pivot is checked at run time, so
an indefinite P (a negative W0 can make it so) gives a non-zero C status and a Python
NumericalError, never silent garbage.

Spreads in difference form (:mod:`derive.filters.difference`): the program never forms
``X_i`` nor subtracts two values of g's size. With ``δ_i = ±sqrt(c) L_i`` it computes
``g(x)`` once and ``D_i = g(x + δ_i) - g(x)`` per sigma point from g's expression tree,
in which the large terms cancel exactly before anything is rounded (a pseudorange of
2e7 m, float32 spacing 2 m, against spreads of metres); then, since ``D_0 = 0`` and
``Wm0 + 2n Wi = 1``, ``Σ Wm g(X_i) = g(x) + dbar`` with ``dbar = Wi Σ D_i``, and the
spreads ``g(X_i) - mean`` are ``-dbar`` (i = 0) and ``D_i - dbar``.

predict: for an affine f (F free of the state) the unscented transform is exact, and the
program computes it as ``f(x)``, ``F P F^T + Q``; otherwise the sigma points of (x, P)
pass through f in difference form: ``x⁻ = f(x) + dbar``,
``P⁻ = Σ Wc (f(X_i) - x⁻)(·)^T + Q`` over those spreads.
f may use the inputs u(k) (the row given with z(k), as the EKF), without noise on them;
a state-dependent Q is evaluated at x(k-1/k-1), R at x⁻. An angle measurement's
deviations D_i (from h(x⁻), the sigma point X_0) and its innovation are wrapped to
(-pi, pi], so its mean is h(x⁻) plus the weighted mean of the wrapped deviations.
update: sigma points redrawn from (x⁻, P⁻), through h in difference form:
``ŷ = h(x⁻) + dbar``, ``Pvv = Σ Wc (Y_i - ŷ)(·)^T + R``,
``Pxy = Σ Wc (X_i - x⁻)(Y_i - ŷ)^T``, which is ``Wi sqrt(c) L (D_1..n - D_n+1..2n)^T``
since ``X_i - x⁻ = ±sqrt(c) L_i``; ``K = Pxy Pvv⁻¹`` (LDL^T solve),
``x = x⁻ + K ((z - h(x⁻)) - dbar)``, ``P = P⁻ - K Pxy^T`` (``= P⁻ - K Pvv K^T``).
Programs step, predict, update1 as for the EKF
(:func:`derive.filters.nonlinear.nonlinear_programs`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import sympy

from .. import reference as numpy_reference
from .. import staging
from ..errors import OptionError
from ..monomials import sum_of
from ..options import UnscentedOptions
from ..statements import substitute
from .difference import DifferenceForm, difference_form, unmoved_turn
from .kf import CONDITIONING
from .nonlinear import (
    NOTE_C,
    NOTE_PY,
    angle_facts,
    check_nonlinear,
    noise_fact,
    nonlinear_programs,
    stage_linearisation,
    state_jacobian,
    state_mapping,
    step_inputs,
    wrapped,
)
from .spec import FilterSpec
from .unit import make_unit


@dataclass(frozen=True)
class Weights:
    """Exact sigma-point weights and the scale ``c = n + lambda``."""

    n: int
    alpha: sympy.Rational
    beta: sympy.Rational
    kappa: sympy.Rational

    @property
    def c(self) -> sympy.Expr:
        return self.alpha ** 2 * (self.n + self.kappa)

    @property
    def wm0(self) -> sympy.Expr:
        return (self.c - self.n) / self.c

    @property
    def wc0(self) -> sympy.Expr:
        return self.wm0 + 1 - self.alpha ** 2 + self.beta

    @property
    def wi(self) -> sympy.Expr:
        return 1 / (2 * self.c)

    def fact(self) -> str:
        return (f"sigma points: alpha = {self.alpha}, beta = {self.beta}, kappa = {self.kappa}, "
                f"n + lambda = {self.c}; weights Wm0 = {self.wm0}, Wc0 = {self.wc0}, "
                f"Wi = {self.wi} (i = 1..{2 * self.n})")


def _exact(value: float) -> sympy.Rational:
    """The decimal the user wrote (the double's shortest repr) as an exact rational."""
    return sympy.Rational(repr(float(value)))


def _double(value: sympy.Expr) -> float:
    """``value`` as a double (inf when too large for one)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def weights(n: int, options: UnscentedOptions) -> Weights:
    """Weights from the validated ``options`` (kappa None: 3 - n); refused when
    alpha²(n + kappa) <= 0 or a weight is not a finite double."""
    kappa = sympy.Integer(3 - n) if options.kappa is None else _exact(options.kappa)
    w = Weights(n, _exact(options.alpha), _exact(options.beta), kappa)
    given = (f"n = {n}, alpha = {options.alpha!r}, beta = {options.beta!r}, "
             f"kappa = {_double(kappa)!r}")
    if w.c <= 0:
        raise OptionError(f"UKF needs alpha²(n + kappa) > 0, got {_double(w.c)!r} ({given})")
    values = {"n + lambda": w.c, "Wm0": w.wm0, "Wc0": w.wc0, "Wi": w.wi}
    bad = {k: _double(v) for k, v in values.items()
           if not math.isfinite(_double(v)) or (_double(v) == 0) != (v == 0)}
    if bad:
        raise OptionError("UKF weights are not finite, non-zero doubles: "
                          + ", ".join(f"{k} = {v!r}" for k, v in bad.items()) + f" ({given})")
    return w


def _is_affine(model) -> bool:
    states = set(model.state_symbols)
    jac = model.subs(model.F_jacobian)
    return not any(e.free_symbols & states for e in jac)


def sigma_offsets(prog, P: sympy.Matrix, w: Weights) -> sympy.Matrix:
    """``sqrt(c) L`` with ``L L^T = P`` (unrolled Cholesky, pivots checked at run time)."""
    L = staging.cholesky(prog, P, name="the sigma-point covariance P (a negative weight W0 "
                                       "can make it indefinite)")
    return staging.scale(prog, L, sympy.sqrt(w.c))


def _differences(model, values) -> DifferenceForm:
    return difference_form(list(values), model.state_symbols)


def stage_values(prog, form: DifferenceForm, mapping: Mapping) -> tuple[sympy.Matrix, dict]:
    """g(x) staged once (``mapping``: the model's symbols -> program atoms), and the
    mapping extended by the base symbols the differences read."""
    subs = dict(mapping)
    for sym, expr in form.base:
        subs[sym] = prog.let(substitute(expr, subs), "at_x")
    return sympy.Matrix([prog.let(substitute(v, subs), "at_x") for v in form.values]), subs


def stage_differences(prog, form: DifferenceForm, subs: dict,
                      delta: Sequence[sympy.Expr]) -> sympy.Matrix:
    """D = g(x + delta) - g(x) staged for one sigma-point offset ``delta`` (``subs``:
    from :func:`stage_values`)."""
    subs = {**subs, **dict(zip(form.deltas, delta))}
    for sym, expr in form.steps:
        subs[sym] = _signed_let(prog, unmoved_turn(form, sym, substitute(expr, subs)))
    return sympy.Matrix([_signed_let(prog, substitute(d, subs)) for d in form.differences])


def _signed_let(prog, expr: sympy.Expr) -> sympy.Expr:
    """A difference staged as staging stages any entry: one whose terms are all negative
    (a minus sigma point's ``-δ``) staged positive and returned negated, so the sign folds
    into the sums that use it instead of costing a negation."""
    return staging.stage(prog, expr, "diff")


def sigma_spreads(prog, form: DifferenceForm, subs: dict, offsets: sympy.Matrix
                  ) -> list[sympy.Matrix]:
    """D_i = g(x ± offsets_i) - g(x) for the 2n sigma points after X_0 = x, in the order
    X_1..X_n (+), X_n+1..X_2n (-): the sigma points themselves are never formed."""
    n = offsets.cols
    plus = [stage_differences(prog, form, subs, list(offsets[:, j])) for j in range(n)]
    minus = [stage_differences(prog, form, subs, [-e for e in offsets[:, j]])
             for j in range(n)]
    return plus + minus


def _mean_and_spreads(prog, values: sympy.Matrix, D: list[sympy.Matrix], w: Weights):
    """(the mean offset dbar = Wi Σ D_i, the spreads Y_i - mean of all 2n + 1 points):
    Σ Wm Y_i = g(x) + dbar since Wm0 + 2n Wi = 1 and D_0 = 0; the spreads are
    -dbar (X_0) and D_i - dbar."""
    rows = values.rows
    dbar = sympy.Matrix([prog.let(w.wi * prog.let(sum_of(d[r, 0] for d in D), "sum"), "mean")
                         for r in range(rows)])
    return dbar, [-dbar] + [staging.sub(prog, d, dbar) for d in D]


def _weighted_covariance(prog, D: list[sympy.Matrix], w: Weights, add) -> sympy.Matrix:
    """``Wc0 D0 D0^T + Wi Σ_{i>0} D_i D_i^T + add`` (symmetric, upper triangle staged)."""
    k = D[0].rows
    out = sympy.zeros(k, k)
    for a in range(k):
        for b in range(a, k):
            inner = prog.let(staging.dot((d[a, 0], d[b, 0]) for d in D[1:]), "cov")
            out[a, b] = out[b, a] = prog.let(
                w.wc0 * D[0][a, 0] * D[0][b, 0] + w.wi * inner + add[a, b], "cov")
    return out


def ukf_predict_stage(model, w: Weights):
    """Exact linear propagation for an affine f, else the unscented transform through f
    in difference form: x⁻ = f(x) + dbar, spreads f(X_i) - x⁻ = D_i - dbar."""
    lin = state_jacobian(model)
    affine = _is_affine(model)
    form = None if affine else _differences(model, model.subs(model.f))

    def predict(prog, mapping, x, P):
        at_x = {**mapping, **state_mapping(model, x)}
        Q = sympy.Matrix(model.subs(model.Q)).xreplace(at_x)
        if affine:
            values, F = stage_linearisation(prog, lin, at_x, "f")
            FP = staging.matmul(prog, F, P)
            Pp = staging.add(prog, staging.matmul(prog, FP, F.T, symmetric_result=True), Q,
                             symmetric_result=True)
            return values, Pp
        values, subs = stage_values(prog, form, at_x)
        D = sigma_spreads(prog, form, subs, sigma_offsets(prog, P, w))
        dbar, spreads = _mean_and_spreads(prog, values, D, w)
        return staging.add(prog, values, dbar), _weighted_covariance(prog, spreads, w, Q)

    return predict


def ukf_update_stage(model, w: Weights):
    """Sigma points of (x⁻, P⁻) through h in difference form; Pvv, Pxy, the gain and the
    update."""
    cache: dict[tuple, DifferenceForm] = {}

    def update(prog, mapping, meas, x, P, z):
        key = tuple(sympy.srepr(e) for e in meas.h)
        if key not in cache:
            cache[key] = _differences(model, meas.h)
        form = cache[key]
        n = x.rows
        offsets = sigma_offsets(prog, P, w)
        at_x = {**mapping, **state_mapping(model, x)}
        h_x, subs = stage_values(prog, form, at_x)
        D = [wrapped(prog, d, meas.angles) for d in sigma_spreads(prog, form, subs, offsets)]
        dbar, spreads = _mean_and_spreads(prog, h_x, D, w)
        R = meas.R.xreplace(at_x)
        Pvv = _weighted_covariance(prog, spreads, w, R)
        k = h_x.rows
        E = sympy.Matrix(n, k, lambda j, b: prog.let(D[j][b, 0] - D[n + j][b, 0], "dy"))
        Pxy = staging.scale(prog, staging.matmul(prog, offsets, E), w.wi)
        K = staging.transpose(staging.spd_solve(prog, Pvv, staging.transpose(Pxy), name="Pvv"))
        innovation = wrapped(prog, staging.sub(prog, staging.sub(prog, z, h_x), dbar),
                             meas.angles)
        x_new = staging.add(prog, x, staging.matmul(prog, K, innovation))
        KPxy = staging.matmul(prog, K, staging.transpose(Pxy), symmetric_result=True)
        P_new = staging.sub(prog, P, KPxy, symmetric_result=True)
        return x_new, P_new, innovation, Pvv

    return update


def spreads_fact(model, affine: bool) -> str:
    """The header's line on how the spreads are computed, naming any node of h (or of a
    non-affine f) whose difference falls back to g(a') - g(a)."""
    functions = {"h": model.subs(model.h)} if affine else \
        {"f": model.subs(model.f), "h": model.subs(model.h)}
    fallbacks = [f"{name}: {node}" for name, values in functions.items()
                 for node in _differences(model, values).fallbacks]
    text = (f"spreads: {' and '.join(functions)} in difference form, "
            f"{'/'.join(functions)}(x + d_i) - {'/'.join(functions)}(x) derived node by node "
            "so that the large terms cancel before rounding; the sigma points x + d_i are "
            "never formed")
    if fallbacks:
        text += ("; no rule for " + ", ".join(fallbacks)
                 + ", whose differences are g(a + D[a]) - g(a) (they cancel)")
    return text


def applies(model) -> str | None:
    """The UKF takes inputs in f without noise on them: a model with Qu is refused (the
    unscented transform would carry u's noise as states)."""
    if model.f_inputs and any(e != 0 for e in model.subs(model.Qu)):
        return (f"filter 'ukf' does not take noise Qu on the inputs of f (model "
                f"{model.name!r}); use the ekf, which maps it through df/du")
    return None


def derive_unit(model, spec, options):
    """The UKF unit: programs step, predict, update1 (see the module docstring)."""
    check_nonlinear(model, spec.name)
    w = weights(model.n, options)
    programs, facts = nonlinear_programs(model, ukf_predict_stage(model, w),
                                         ukf_update_stage(model, w), options,
                                         spec.title)
    unit = make_unit(model, spec, programs, options, step_inputs=step_inputs(model))
    affine = _is_affine(model)
    predict = ("predict: f is affine, so the unscented transform is exact: f(x), F P F^T + Q"
               if affine else "predict: sigma points of (x, P) through f")
    noise = noise_fact(model, "x(k-1/k-1), u(k)", "x(k/k-1) (the mean), u(k)")
    angles = [line + ", and so are the sigma points' deviations from h(x) (the point "
              "X_0 = x): their mean is h(x) plus the weighted mean of those deviations, the "
              "spreads the deviations minus that mean" for line in angle_facts(model)]
    return replace(unit, facts=tuple(unit.facts) + (w.fact(), predict,
                                                    spreads_fact(model, affine), *facts,
                                                    *angles, *noise),
                   options={**unit.options, "alpha": float(w.alpha), "beta": float(w.beta),
                            "kappa": float(w.kappa)})


def reference(model, data, options):
    """derive.reference.ukf on ``data`` = (scenario, numeric functions) with the options'
    alpha, beta, kappa: (xs, Ps); an identity f is passed as None."""
    scenario, fns = data
    identity = list(model.subs(model.f)) == list(model.state_symbols)
    res = numpy_reference.ukf(None if identity else fns["f"], fns["h"], fns["Q"], fns["R"],
                              scenario.x0, scenario.P0, scenario.zs, alpha=options.alpha,
                              beta=options.beta, kappa=options.kappa,
                              inputs=list(scenario.us), skip_nan=False,
                              angles=model.angle_rows(), f_inputs=bool(model.f_inputs),
                              m=model.m)
    return res.xs, res.Ps


SPECS = (FilterSpec(
    "ukf", "unscented Kalman filter", "nonlinear", "timevarying", derive_unit, reference,
    options=UnscentedOptions, covariance=True, inputs=True, extra_programs=("predict", "update1"),
    # the KF's: Pvv (S) by the LDL^T solve, P - K Pvv K^T; the Cholesky factor of P only
    # spreads the sigma points: its backward error is a perturbation of P bounded by P's
    # diagonal (Higham Thm 10.3), which L counts (no condition number)
    conditioning=CONDITIONING,
    applies=applies, listing=110,
    about={"python": "Run the unscented Kalman filter: sigma points through h." + NOTE_PY,
           "c": "Run the unscented Kalman filter over steps steps; Ps may be NULL." + NOTE_C}),)

__all__ = ["SPECS", "Weights", "derive_unit", "sigma_offsets", "sigma_spreads", "stage_differences",
           "stage_values", "ukf_predict_stage", "ukf_update_stage", "weights"]
