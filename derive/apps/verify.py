"""Verification: generated Python and C against the NumPy reference, on simulated data.

For each filter the generated code is written to a scratch directory, the Python
module imported and the C compiled with the strict flags through cffi, and both
are run over ``steps`` simulated measurements. The error measure is normwise per
step, ``max_k ||gen_k - ref_k||_inf / max(||ref_k||_inf, floor)`` for x(k) and for P(k)
(:func:`relative_error`): a component computed from much larger ones (the acceleration
of the CA model from positions of 1e6 m) is judged at the scale of the numbers it is
computed from; floor = min(1, the lower median of the non-zero ||ref_k||_inf) keeps a
step near zero from being divided by its own noise while an array of small numbers
(P ~ 1e-20) is still judged at its own size (:func:`error_floor`). The bar is 1e-12 for
linear filters.

Nonlinear filters (EKF, UKF) run on :func:`nonlinear_scenario`: for a model whose inputs
are one satellite position per measurement and whose state is [x, y, z, b], the GNSS
scenario of derive.apps.simulate (moving satellites, so the per-step inputs change); for a
model whose f uses inputs, a run of its own f and h driven by seeded inputs (uniform in
[-1, 1], perturbed by noise of covariance Qu); for a model without inputs, a run of its own
f and h. Their bar is 1e-10, or the reference's own
rounding floor times :data:`FLOOR_MARGIN` where that is larger: the floor is the largest
change of the reference's output when every value of h is perturbed by one rounding
(relative 2^-53, two seeded runs). For the GNSS UKF it is about 3e-10: pseudoranges are
~2e7 m while their spread over the sigma points is metres, so one rounding of h (~4e-9 m)
moves P by ~1e-9 relative per step; two correct implementations that round differently
cannot agree better. The EKF's floor is ~1e-15.

With ``precision="float"`` (``derive verify --precision float``) the C is float32: it is
given the data rounded to float32 and compared with the same float64 reference, within the
tolerance derived for it by derive.apps.float_tolerance (c u32 L G kappa, from the
generated step, the model's closed loop and its conditioning), which each line prints; the
Python stays double and keeps its double bar. A unit of the run kind sensors gets the same,
its L through predict and every update, its G and kappa from its reference run's trace
(derive.apps.float_tolerance.sensors_conditioning).

A nonlinear model also gets an independent witness for the Jacobians the EKF is generated
from (:func:`jacobian_witness`): derive's sympy Jacobians of f and h against CasADi's
automatic differentiation of the same f and h at :data:`WITNESS_POINTS` random points, bar
:data:`WITNESS_TOLERANCE`. It needs the ``casadi`` extra; without it the witness is
reported as skipped, with the reason.
"""

from __future__ import annotations

import functools
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import ModelError, SymbolError, VerificationError
from ..filters import kind
from ..filters.sensors import reference_run as sensors_reference
from ..filters.sensors import sensor_groups, uses_sensor_run
from ..generation import command_unit
from ..options import validate
from ..pipeline import load_generated
from ..precision import DOUBLE
from ..runs.unit import RUN_KINDS, Unit
from .casadi_bridge import JacobianCheck, check_jacobians, unavailable
from .float_tolerance import (
    FloatTolerance,
    PropagatedTolerance,
    ReferenceRun,
    error_floor,
    float_tolerance,
    in_double,
    sensors_conditioning,
)
from .simulate import gnss_scenario, simulate_linear, simulate_sensors

LINEAR_TOLERANCE = 1e-12
NONLINEAR_TOLERANCE = 1e-10
FLOOR_MARGIN = 4.0
WITNESS_POINTS = 100
WITNESS_TOLERANCE = 1e-12


def within_tolerance(error: float, tolerance: float,
                     bound: FloatTolerance | PropagatedTolerance | None) -> bool:
    """How `derive verify` judges a run: a finite error within the tolerance, and for
    float32 a bound below 1 (else float32 cannot carry the filter)."""
    meaningful = bound is None or bound.meaningful
    return bool(meaningful and np.isfinite(error) and error <= tolerance)


@dataclass(frozen=True)
class Verification:
    model: str
    filter: str
    lang: str
    steps: int
    error: float
    tolerance: float
    bound: FloatTolerance | PropagatedTolerance | None = None

    @property
    def passed(self) -> bool:
        return within_tolerance(self.error, self.tolerance, self.bound)

    def line(self) -> str:
        mark = "ok  " if self.passed else "FAIL"
        in_float = self.bound is not None and self.bound.precision_name == "float32"
        lang = f"{self.lang} f32" if in_float else self.lang
        text = (f"{mark} {self.model:18s} {self.filter:7s} {lang:6s} {self.steps:5d} steps"
                f"  max rel err {self.error:9.2e} <= {self.tolerance:.1e}")
        if self.bound is not None:
            text += f"  ({self.bound.text()}"
            text += (")" if self.bound.meaningful
                     else f"; >= 1: {self.bound.precision_name} cannot carry it)")
        return text


@dataclass(frozen=True)
class JacobianWitness:
    """CasADi's automatic differentiation as a witness for a nonlinear model's Jacobians:
    the comparison (``check``), or why it was skipped (``skipped``)."""

    model: str
    check: JacobianCheck | None
    skipped: str | None = None
    tolerance: float = WITNESS_TOLERANCE

    @property
    def passed(self) -> bool:
        return self.check is not None and bool(self.check.worst <= self.tolerance)

    def line(self) -> str:
        if self.check is None:
            return f"skip {self.model:18s} F, H    casadi  witness skipped: {self.skipped}"
        mark = "ok  " if self.passed else "FAIL"
        return (f"{mark} {self.model:18s} F, H    casadi {self.check.points:5d} points"
                f" max rel diff {self.check.worst:9.2e} <= {self.tolerance:.1e}"
                f" (sympy Jacobians vs CasADi AD)")


def jacobian_witness(model, points: int = WITNESS_POINTS, seed: int = 0
                     ) -> JacobianWitness | None:
    """The CasADi witness for ``model``'s Jacobians (None for a linear model: it has none).

    Skipped, with the reason, when casadi is not installed, when an expression of the
    model has no CasADi counterpart, or when too few random points are in its domain."""
    if model.kind != "nonlinear":
        return None
    reason = unavailable()
    if reason is not None:
        return JacobianWitness(model.name, None, reason)
    try:
        return JacobianWitness(model.name, check_jacobians(model, points, seed))
    except ModelError as exc:
        return JacobianWitness(model.name, None, str(exc))


def relative_error(a, b) -> float:
    """``max_k ||a_k - b_k||_inf / max(||b_k||_inf, floor)`` over the steps k (the first
    axis), b the reference, floor = :func:`error_floor` of the step sizes ``||b_k||_inf``.
    A step without difference counts 0 (also against an all-zero reference); a difference
    against an all-zero reference is infinite; NaN anywhere gives NaN."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise VerificationError(f"shape {a.shape} differs from the reference's {b.shape}")
    if a.size == 0:
        return 0.0
    steps = a.shape[0]
    diff = np.abs(a - b).reshape(steps, -1).max(axis=1)
    sizes = np.abs(b).reshape(steps, -1).max(axis=1)
    scale = np.maximum(sizes, error_floor(sizes))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(diff == 0, 0.0, diff / scale)
    return float(np.max(ratio))


@dataclass(frozen=True)
class NonlinearScenario:
    """Measurements zs (steps, m), inputs us (steps, len(model.inputs)), truth
    (steps + 1, n), and the filter start x0, P0."""

    zs: np.ndarray
    us: np.ndarray
    truth: np.ndarray
    x0: np.ndarray
    P0: np.ndarray


def nonlinear_scenario(model, steps: int = 500, seed: int = 7) -> NonlinearScenario:
    """A seeded run for a nonlinear model (see the module docstring)."""
    fns = model.numeric_functions()
    rng = np.random.default_rng(seed + 1)
    n, m = model.n, model.m
    if model.f_inputs:
        return _input_driven_scenario(model, fns, rng, steps)
    if model.inputs:
        if len(model.inputs) != 3 * m or n != 4 or m < 4:
            raise VerificationError(
                f"no verification scenario for model {model.name!r}: its inputs must be one "
                f"satellite position (3 numbers) per measurement, at least 4 measurements, "
                f"and its state [x, y, z, b]; got {len(model.inputs)} inputs, m = {m}, n = {n}")
        elev = [80.0, 35.0, 45.0, 55.0, 20.0, 65.0, 30.0, 15.0][:m] + [40.0] * max(0, m - 8)
        azim = [(30.0 + 360.0 * i / m + 17.0 * (i % 2)) % 360.0 for i in range(m)]
        sc = gnss_scenario(steps, seed, elevations_deg=elev, azimuths_deg=azim, moving=True)
        us = sc.satellites.reshape(steps, 3 * m)
        truth, x0, P0 = sc.truth, sc.x0, sc.P0
    else:
        us = np.zeros((steps, 0))
        x0 = np.asarray(model.x0.tolist(), dtype=float).ravel()
        P0 = np.asarray(model.P0.tolist(), dtype=float)
        w = _draws(rng, fns["Q"], steps, n)
        truth = np.empty((steps + 1, n))
        truth[0] = x0 + rng.multivariate_normal(np.zeros(n), P0, method="eigh")
        for k in range(steps):
            truth[k + 1] = fns["f"](truth[k]) + w(k, truth[k], us[k])
    v = _draws(rng, fns["R"], steps, m)
    zs = np.array([fns["h"](truth[k + 1], us[k]) + v(k, truth[k + 1], us[k])
                   for k in range(steps)])
    return NonlinearScenario(zs, us, truth, np.asarray(x0, float), np.asarray(P0, float))


def _input_driven_scenario(model, fns, rng, steps: int) -> NonlinearScenario:
    """A model whose f uses inputs: us uniform in [-1, 1] (seeded); the truth is driven by
    the inputs plus noise of covariance Qu, and by process noise of covariance Q."""
    n, m = model.n, model.m
    n_u = len(model.inputs)
    us = rng.uniform(-1.0, 1.0, (steps, n_u))
    u_noise = rng.multivariate_normal(np.zeros(n_u), fns["Qu"], size=steps, method="eigh")
    w = _draws(rng, fns["Q"], steps, n)
    x0 = np.asarray(model.x0.tolist(), dtype=float).ravel()
    P0 = np.asarray(model.P0.tolist(), dtype=float)
    truth = np.empty((steps + 1, n))
    truth[0] = x0 + rng.multivariate_normal(np.zeros(n), P0, method="eigh")
    for k in range(steps):  # row k of us drives the step into k + 1 (measured by zs[k])
        truth[k + 1] = fns["f"](truth[k], us[k] + u_noise[k]) + w(k, truth[k], us[k])
    v = _draws(rng, fns["R"], steps, m)
    zs = np.array([fns["h"](truth[k + 1], us[k]) + v(k, truth[k + 1], us[k])
                   for k in range(steps)])
    return NonlinearScenario(zs, us, truth, x0, P0)


def _draws(rng, covariance, steps: int, size: int):
    """``draw(k, x, u)``: step k's noise of ``covariance``: drawn at once when it is a
    matrix, else (a state-dependent Q or R, a callable ``(x, u)``) a standard normal
    draw per step scaled by the covariance's symmetric square root at x, u."""
    if not callable(covariance):
        noise = rng.multivariate_normal(np.zeros(size), covariance, size=steps,
                                        method="eigh")
        return lambda k, x, u: noise[k]
    standard = rng.standard_normal((steps, size))

    def draw(k, x, u):
        values, vectors = np.linalg.eigh(np.asarray(covariance(x, u), dtype=float))
        return vectors @ (np.sqrt(np.clip(values, 0.0, None)) * standard[k])
    return draw


def nonlinear_reference(model, name: str, scenario: NonlinearScenario, options: dict,
                        rounding_seed: int | None = None):
    """The filter's NumPy reference (its spec's) on ``scenario``.

    ``rounding_seed``: perturb every value of h by one rounding (relative uniform in
    ±2^-53, seeded), to measure the reference's rounding floor."""
    options = validate(name, options)
    fns = model.numeric_functions()
    if rounding_seed is not None:
        rng, h_exact = np.random.default_rng(rounding_seed), fns["h"]

        def h_rounded(x, u=()):
            y = h_exact(x, u)
            return y * (1.0 + rng.uniform(-1.0, 1.0, y.shape) * 2.0 ** -53)

        fns = {**fns, "h": h_rounded}
    return kind(name).reference(model, (scenario, fns), options)


def rounding_floor(model, name: str, scenario: NonlinearScenario, options: dict,
                   xs_ref, Ps_ref) -> float:
    """Largest relative change (x or P) of the reference under one rounding of h."""
    floor = 0.0
    for seed in (1, 2):
        xs, Ps = nonlinear_reference(model, name, scenario, options, rounding_seed=seed)
        floor = max(floor, relative_error(xs, xs_ref), relative_error(Ps, Ps_ref))
    return floor


def reference_run(model, name: str, zs, options: dict, scenario: NonlinearScenario | None = None):
    """The NumPy reference output for filter ``name``: (xs, Ps or None).

    Nonlinear filters need the ``scenario`` (its zs are used; ``zs`` is ignored)."""
    options = validate(name, options)
    if kind(name).model_kind == "nonlinear":
        if scenario is None:
            raise VerificationError(f"filter {name!r} needs a NonlinearScenario")
        return nonlinear_reference(model, name, scenario, options)
    return kind(name).reference(model, zs, options)


def generated_run(module, name: str, zs, model, lang: str,
                  scenario: NonlinearScenario | None = None, with_lls: bool = False,
                  p=None):
    """Run a generated filter (Python module or C FilterModule) from the model's x0, P0
    (nonlinear filters: the scenario's zs, us, x0 and P0); every input is given in the
    module's dtype (a float32 kernel's: each value rounded once to float), the outputs are
    returned as float64: (xs, Ps or None), and with ``with_lls`` (a filter generated with
    the option loglik) the per-step log-likelihoods third (and with the option gradient
    their gradients fourth); ``p``: the free parameters' row,
    for every step (a model verified at its parameters' examples)."""
    dtype = getattr(module, "dtype", np.float64)
    rows = {} if p is None else {"p": np.asarray(p, dtype=dtype)}

    def given(*arrays):
        return [np.asarray(a, dtype=dtype) for a in arrays]

    spec = kind(name)
    if spec.model_kind == "nonlinear":
        args = [scenario.zs] + ([scenario.us] if model.inputs else [])
        out = module.run(*given(*args, scenario.x0, scenario.P0), **rows)
        steps = len(scenario.zs)
    else:
        num = model.numeric()
        # run's arguments after the measurements (and inputs): what its run kind starts from
        start = {"x0": num.x0, "P0": num.P0}
        data = [zs.zs, zs.us] if model.inputs else [zs]
        out = module.run(*given(*data, *(start[name]
                                         for name, _ in RUN_KINDS[spec.run_kind].start)), **rows)
        steps = len(data[0])
    if not isinstance(out, tuple):
        return np.asarray(out, dtype=float), None
    nt = model.n_tangent
    xs, Ps = (np.asarray(out[0], dtype=float),
              np.asarray(out[1], dtype=float).reshape(steps, nt, nt))
    # with the option gradient the per-step gradients (dlls) follow the lls
    return (xs, Ps, *(np.asarray(o, dtype=float) for o in out[2:])) if with_lls else (xs, Ps)


class InputRun(NamedTuple):
    """What a linear filter with inputs is verified on: zs (steps, m) and the inputs us
    (steps, n_u), row k with zs[k]."""

    zs: np.ndarray
    us: np.ndarray


def linear_run(model, steps: int, seed: int):
    """The measurements a linear filter is verified on: zs (steps, m), or for a model with
    inputs an InputRun (zs and its inputs us, uniform in [-1, 1])."""
    num = model.numeric()
    if not model.inputs:
        return simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs
    us = np.random.default_rng(seed + 1).uniform(-1.0, 1.0, (steps, model.n_inputs))
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed,
                          B=num.B, D=num.D, us=us)
    return InputRun(run.zs, us)


@dataclass(frozen=True)
class SensorsCase:
    """What a unit of the run kind sensors is verified on: the
    :func:`derive.apps.simulate.simulate_sensors` run (``groups``: its sensors), ``ps``
    (one row per step of the free parameters' examples; None without parameters), the
    reference (derive.reference.sensors), the bar (1e-12 linear, 1e-10 nonlinear) and, for
    float32 C, its bound (derive.apps.float_tolerance); ``trace``: the reference run's
    trace, which the bounds read the model's conditioning from; ``implicit``: the model
    declares no sensor (its one sensor's run array is ``z``)."""

    groups: tuple
    run: object
    ps: np.ndarray | None
    reference: object
    tolerance: float
    bound: FloatTolerance | PropagatedTolerance | None
    trace: tuple = ()
    implicit: bool = False

    def conditioning(self, model):
        """The conditioning of ``model``'s reference run (derive.apps.float_tolerance)."""
        return sensors_conditioning(model, list(self.trace))

    def arguments(self) -> dict[str, np.ndarray]:
        """run's arguments by their C names, in run's order: z_<sensor> (and R_<sensor>
        where R is given per call; ``z`` for the implicit sensor of a model that declares
        none), u, x0, P0, p."""
        args = {}
        for g in self.groups:
            args["z" if self.implicit else f"z_{g.name}"] = self.run.zs[g.name]
            if g.R_argument:
                args[f"R_{g.name}"] = self.run.Rs[g.name]
        if self.run.us.shape[1]:
            args["u"] = self.run.us
        args.update(x0=self.run.x0, P0=self.run.P0)
        if self.ps is not None:
            args["p"] = self.ps
        return args


def sensors_case(model, name: str, steps: int, seed: int, options, unit: Unit | None = None,
                 float_c: bool = True, values: dict | None = None) -> SensorsCase:
    """The :class:`SensorsCase` of filter ``name`` of ``model`` (a unit of the run kind
    sensors). Free parameters take ``values`` over the model's examples
    (:func:`parameter_values`);
    with the option ``precision`` "float" and ``float_c``, the bound of the float32 C
    (``unit``: derived again when not given)."""
    params = parameter_values(model, values)
    groups = tuple(sensor_groups(model))
    run = simulate_sensors(model, groups, steps, seed, params)
    ps = (np.tile([params[p.name] for p in model.parameters], (steps, 1))
          if model.parameters else None)
    trace: list = []
    reference_of = kind(name).sensors_reference or sensors_reference
    ref = reference_of(model, options, run.zs, run.us, ps, run.x0, run.P0, run.Rs,
                            trace=trace)
    tolerance = LINEAR_TOLERANCE if model.kind == "linear" else NONLINEAR_TOLERANCE
    bound = None
    if options.precision != DOUBLE.name and float_c:
        unit = unit if unit is not None else command_unit(model, name, options)
        bound = float_tolerance(model, unit, steps, sensors_conditioning(model, trace))
    return SensorsCase(groups, run, ps, ref, tolerance, bound, tuple(trace),
                       implicit=not model.sensors)


def verify_sensor_modules(model, name: str, modules: dict, steps: int, seed: int,
                          options, unit: Unit | None = None,
                          values: dict | None = None) -> list[Verification]:
    """A unit of the run kind sensors (several sensors, gating or update-first) on its
    :func:`sensors_case` (sensors at their periods, NaN rows between; free parameters at
    their examples, one p row per step), against derive.reference.sensors; bar: 1e-12
    (linear), 1e-10 (nonlinear). With the option ``precision`` "float" the C module is
    float32, given the data rounded to float32 and held to the tolerance
    derive.apps.float_tolerance derives from the unit's programs and the reference run's
    trace (``unit``: derived again when not given)."""
    case = sensors_case(model, name, steps, seed, options, unit, float_c="c" in modules,
                        values=values)
    ref = case.reference
    out = []
    for lang, module in modules.items():
        dtype = getattr(module, "dtype", np.float64)
        result = module.run(*[np.asarray(a, dtype=dtype) for a in case.arguments().values()])
        xs = np.asarray(result[0], dtype=float)
        Ps = np.asarray(result[1], dtype=float).reshape(steps, model.n_tangent, model.n_tangent)
        err = max(relative_error(xs, ref.xs), relative_error(Ps, ref.Ps))
        if lang == "c" and case.bound is not None:
            out.append(Verification(model.name, name, lang, steps, err, case.bound.value,
                                    case.bound))
        elif model.kind == "linear" and not within_tolerance(err, case.tolerance, None):
            unit = unit if unit is not None else command_unit(model, name, options)
            bound = in_double(float_tolerance(model, unit, steps, case.conditioning(model)))
            out.append(beyond_bar(model.name, name, lang, steps, err, bound))
        else:
            out.append(Verification(model.name, name, lang, steps, err, case.tolerance))
    return out


def conditioning_run(model, zs, scenario: NonlinearScenario | None, xs_ref, Ps_ref
                     ) -> ReferenceRun:
    """The run the float32 tolerance reads the model's conditioning from: the KF's
    reference run on the same measurements for a linear model (every linear filter's P
    follows it), the filter's own reference for a nonlinear one; from x0, P0 as run."""
    if scenario is not None:
        return ReferenceRun(np.asarray(xs_ref), np.asarray(Ps_ref), scenario.us,
                            scenario.x0, scenario.P0)
    xs, Ps = kind("kf").reference(model, zs, validate("kf", {}))
    num = model.numeric()
    return ReferenceRun(np.asarray(xs), np.asarray(Ps), None, num.x0, num.P0)


def parameter_values(model, values: dict | None = None) -> dict[str, float]:
    """The values derive verify runs ``model``'s free parameters at: ``values`` (``derive
    verify --values NAME=V``) over the model's examples (``dt = { example = 0.01 }``);
    SymbolError (bad input: exit 2) naming the parameters that have neither."""
    given = {**model.examples, **(values or {})}
    free = [q.name for q in model.parameters]
    unknown = [nm for nm in values or {} if nm not in free]
    if unknown:
        raise SymbolError(f"--values names {unknown[0]!r}, which is not a free "
                                f"parameter of model {model.name!r} (free: {free})")
    missing = [nm for nm in free if nm not in given]
    if missing:
        raise SymbolError(
            f"verify needs a value for each free parameter of model {model.name!r}; none "
            f"for {missing} (give each an example, e.g. {missing[0]} = {{ example = ... }} "
            f"in [parameters], or examples= in Python, or --values {missing[0]}=V)")
    return {nm: float(given[nm]) for nm in free}


def verify_modules(model, name: str, modules: dict, steps: int = 1000, seed: int = 7,
                   options: dict | None = None, unit: Unit | None = None,
                   values: dict | None = None) -> list[Verification]:
    """Compare already built generated filters ({lang: module}) with the reference.

    Free parameters run at ``values`` over the model's examples (:func:`parameter_values`):
    the reference and the simulation use the model at those values, the generated filters
    take them as ``p``.

    The scenario, reference run, tolerance and error measure of `derive verify`. With the
    option ``precision`` "float" the C module is float32 and is held to the tolerance
    derive.apps.float_tolerance derives (``unit``: the filter's unit, derived again when
    not given).
    """
    opts = validate(name, options)
    if kind(name).sensors and uses_sensor_run(model, opts):
        return verify_sensor_modules(model, name, modules, steps, seed, opts, unit, values)
    p = None
    free_model = model
    if model.parameters:  # simulated and referenced at the values; the filters take them as p
        given = parameter_values(model, values)
        p = [given[q.name] for q in model.parameters]
        model = model.at_values(given)
    scenario = None
    if kind(name).model_kind == "nonlinear":
        scenario = nonlinear_scenario(model, steps, seed)
        zs, tolerance = scenario.zs, NONLINEAR_TOLERANCE
    else:
        zs = linear_run(model, steps, seed)
        tolerance = LINEAR_TOLERANCE
    xs_ref, Ps_ref = reference_run(model, name, zs, opts, scenario)
    # the option loglik: run's lls against the family's reference of the log-likelihood
    loglik = opts.get("loglik") or opts.get("gradient")
    lls_ref = (kind(name).loglik(model, zs if scenario is None else (
        scenario, model.numeric_functions()), opts) if loglik else None)
    # the option gradient: the sum of run's dlls against central differences of the
    # reference's log-likelihood in each parameter
    dll_ref = (reference_gradient(free_model, name, given, zs, scenario, opts)
               if opts.get("gradient") else None)
    if scenario is not None:
        floor = rounding_floor(model, name, scenario, opts, xs_ref, Ps_ref)
        tolerance = max(tolerance, FLOOR_MARGIN * floor)
    bound = None
    if opts.precision != DOUBLE.name and "c" in modules:
        unit = unit if unit is not None else command_unit(model, name, opts)
        bound = float_tolerance(model, unit, steps,
                                conditioning_run(model, zs, scenario, xs_ref, Ps_ref))
    @functools.cache   # derived once, and only when an error exceeds the bar
    def double_bound() -> FloatTolerance:
        built = unit if unit is not None else command_unit(model, name, opts)
        return in_double(float_tolerance(
            model, built, steps, conditioning_run(model, zs, scenario, xs_ref, Ps_ref)))

    out: list[Verification] = []
    for lang, module in modules.items():
        xs, Ps, *lls = generated_run(module, name, zs, model, lang, scenario,
                                     lls_ref is not None, p)
        err = relative_error(xs, xs_ref)
        if Ps_ref is not None and Ps is not None:
            err = max(err, relative_error(Ps, Ps_ref))
        if lls:  # each step's error relative to its scale (loglik_scale)
            ll_ref, scales = lls_ref
            with np.errstate(divide="ignore", invalid="ignore"):
                diff = np.abs(lls[0] - ll_ref)
                err = max(err, float(np.max(np.where(diff == 0, 0.0, diff / scales))))
        if dll_ref is not None:
            gradient_error = float(np.max(np.abs(np.sum(lls[1], axis=0) - dll_ref))
                                   / np.max(np.abs(dll_ref)))
            out.append(Verification(model.name, name, f"{lang} dll", steps, gradient_error,
                                    GRADIENT_TOLERANCE))
        if lang == "c" and bound is not None:
            out.append(Verification(model.name, name, lang, steps, err, bound.value, bound))
        elif scenario is None and not within_tolerance(err, tolerance, None):
            out.append(beyond_bar(model.name, name, lang, steps, err, double_bound()))
        else:
            out.append(Verification(model.name, name, lang, steps, err, tolerance))
    return out


GRADIENT_TOLERANCE = 1e-6
"""The option gradient: the run's summed dlls against central differences of the
reference's log-likelihood, the largest difference relative to the largest entry (the
differences' own error, Richardson-extrapolated, is far below)."""


def reference_gradient(model, name: str, values: dict, zs, scenario, opts) -> np.ndarray:
    """d/dp of the reference's log-likelihood of ``zs`` (the model with free parameters at
    ``values`` moved one at a time by +-h and +-h/2, h = 1e-3 |p_j|), by central
    differences extrapolated (Richardson, error O(h^4))."""
    def total(at: dict) -> float:
        valued = model.at_values(at)
        data = zs if scenario is None else (scenario, valued.numeric_functions())
        return float(np.sum(kind(name).loglik(valued, data, opts)[0]))

    out = []
    for q in model.parameters:
        def central(h, q=q):
            up, down = dict(values), dict(values)
            up[q.name], down[q.name] = values[q.name] + h, values[q.name] - h
            return (total(up) - total(down)) / (2 * h)

        h = 1e-3 * max(abs(values[q.name]), 1e-3)
        out.append((4 * central(h / 2) - central(h)) / 3)
    return np.array(out)


def beyond_bar(model: str, name: str, lang: str, steps: int, error: float,
               bound: FloatTolerance) -> Verification:
    """A linear double filter's verification when its error exceeds the 1e-12 bar: held
    to the double bound instead where the model's conditioning puts that above 1e-12 (two
    correct double implementations of an ill-conditioned model differ by up to it), the
    line printing the bound and what its kappa is made of; else to 1e-12 as always.
    The bound is derived from the model and the reference run, never from the error; it
    is derived only here because it cannot change a verdict below 1e-12."""
    if bound.value <= LINEAR_TOLERANCE:
        return Verification(model, name, lang, steps, error, LINEAR_TOLERANCE)
    return Verification(model, name, lang, steps, error, bound.value, bound)


def verify_filter(model, name: str, steps: int = 1000, seed: int = 7, langs=("python", "c"),
                  options: dict | None = None, workdir: str | Path | None = None,
                  values: dict | None = None) -> list[Verification]:
    """Generate, build and run filter ``name``; compare with the reference (free
    parameters at ``values`` over the model's examples: :func:`parameter_values`)."""
    if model.parameters:
        parameter_values(model, values)  # refused before anything is generated
    opts = validate(name, options)
    only = set(langs)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        generated = load_generated(model, name, opts, only.pop() if len(only) == 1 else "all",
                                   tmp)
    modules = {lang: generated.module(lang) for lang in langs}
    return verify_modules(model, name, modules, steps, seed, opts, generated.unit, values)


__all__ = ["FLOOR_MARGIN", "NONLINEAR_TOLERANCE", "WITNESS_POINTS", "WITNESS_TOLERANCE",
           "InputRun", "JacobianWitness", "NonlinearScenario", "SensorsCase", "Verification",
           "conditioning_run", "jacobian_witness", "linear_run",
           "nonlinear_reference",
           "nonlinear_scenario", "parameter_values", "relative_error", "rounding_floor",
           "sensors_case",
           "verify_filter", "verify_modules"]
