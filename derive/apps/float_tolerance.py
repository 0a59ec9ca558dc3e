"""The tolerance a float32 filter is verified against, derived from float32's unit
roundoff, the generated step and the conditioning of the model (not typed in).

The error measure is derive.apps.verify's: per step, ``||gen_k - ref_k||_inf /
max(||ref_k||_inf, 1)`` for x(k) and P(k), the largest over the run, against the float64
NumPy reference on the same data. The bound is

    tol = c * u32 * L * G * kappa,      u32 = 2^-24 (FLOAT.unit_roundoff)

* ``L`` (:func:`run_roundings`): the roundings on the longest chain of the step, read
  from its lowered C programs (:func:`rounding_depth`: each add, sub, mul, div, fma, sqrt
  or call rounds once; a temporary passes its depth on; the two-step map instead where
  run takes two steps per pass, if deeper). Where run calls several programs per step in
  sequence (:func:`step_programs`: a unit of the run kind ``sensors`` calls ``predict``
  then each ``update_<sensor>``), the chain runs through all of them and their depths
  add up. Plus those of the other programs run calls
  on the way to a stored result (init, enter, store, the smoother's backward pass), plus
  2: the rounding of the inputs to float (x0, P0, z) and of the baked constants (each
  rounded once from its double). A chain of L roundings
  has relative error at most gamma_L = L u / (1 - L u) (Higham, Accuracy and Stability of
  Numerical Algorithms, Lemma 3.1), so L u32 is the first-order error of one step.
* ``G`` (:func:`error_growth`): how the step's error accumulates along the carried state:
  the error of step k is carried by the closed-loop map A = (I - K H) F, so the error after
  the run is at most sum_j ||A^j||_inf times one step's; A is the steady-state KF's for a
  linear model (derive.riccati; every linear filter of derive converges to it), the EKF
  linearisation at the reference's last state and P for a nonlinear one. 1 for a filter
  that carries no state (the FIR's window).
* ``kappa`` (:func:`condition`): the conditioning of what the step solves or cancels:
  for a filter that carries P, the largest over the run of cond_2 of the innovation
  covariance S = H P(k/k-1) H^T + R (solved for the gain: K's relative error is
  cond(S) u) and of P(k/k-1) (the information forms invert it); for a sigma-point filter
  (whose options have ``alpha``) whose h has a node no rule of the difference form
  covers (derive.filters.difference: its spread there is g(a') - g(a)) also the
  cancellation of its spreads, of magnitude sqrt(H P H^T) computed from values of
  magnitude |h|: max |h| / sqrt(min diag H P H^T), squared since P_zz multiplies two
  spreads (the other spreads are computed without it); 1 for a filter whose constants
  are all computed offline in double (sskf, sslf, jssklf, fir, pred).
* A unit of the run kind ``sensors`` (several sensors at their own rates, gating,
  update-first) has no one closed loop: its G and kappa are read from the trace of its
  reference run (derive.reference.sensors, :func:`sensors_conditioning`). The error of
  step k is carried by that step's map A_k = prod_s (I - K_s H_s) F_k (the sensors
  present and applied at step k, in order; F_k the transition or the EKF's Jacobian at
  x(k-1/k-1); no F at an update-first step 0), so G = max_k sum_j ||A_k ... A_{k-j+1}||_inf
  (:func:`run_growth`) over the endpoints k of the run's last cycle (its last W steps, W
  the longest gap between two updates of one sensor: the run has settled there, and the
  cycle holds every phase of the sensors' rates, the step before the slowest sensor's
  update too), and kappa is the largest cond_2 of every S = H_s P H_s^T + R_s an
  update solved (each sensor's own, as its update solves it) and of every P(k/k-1).
* ``c = 2`` (:data:`C`): the state's error and the covariance's error reach the measure by
  two routes (x through the recursion, P directly and through the gain), each bounded by
  the first-order gamma_L; second-order terms (L u)^2 are below 1e-4 of it for L < 2000.

A bound at or above 1 says the model cannot be computed meaningfully in float32;
:attr:`FloatTolerance.meaningful` says so and the verification reports it failed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..emit.c_loops import two_step
from ..emit.unit import Unit
from ..errors import ModelError
from ..filters import kind
from ..filters.difference import difference_form
from ..filters.sensors import program_name, transition_function
from ..lowering import LoweredAssign, LoweredProgram, Op, Tree, Var, lower_program
from ..precision import FLOAT
from ..riccati import kf_steady

#: The constant of the bound (see the module docstring).
C = 2.0
#: Roundings outside the step's program: the inputs rounded to float, the constants.
EXTRA_ROUNDINGS = 2
#: Operations that do not round: a negation, the missing-measurement select.
_EXACT = frozenset({"neg", "select", "cmp"})


@dataclass(frozen=True)
class FloatTolerance:
    """The float32 tolerance of one filter on one run: ``value`` = c u L G kappa."""

    roundings: int
    growth: float
    condition: float
    unit_roundoff: float = FLOAT.unit_roundoff
    c: float = C

    @property
    def value(self) -> float:
        return self.c * self.unit_roundoff * self.roundings * self.growth * self.condition

    @property
    def meaningful(self) -> bool:
        """False when the bound is 1 or more: float32 cannot carry the model."""
        return self.value < 1.0

    def text(self) -> str:
        """``c u32 L G kappa = 2 * 2^-24 * 12 * 3.1 * 1.0 = 4.4e-06``."""
        return (f"c u32 L G kappa = {self.c:g} * 2^{int(np.log2(self.unit_roundoff))} * "
                f"{self.roundings} * {self.growth:.3g} * {self.condition:.3g} = "
                f"{self.value:.2e}")


def rounding_depth(lowered: LoweredProgram) -> int:
    """The most roundings on one chain from the program's inputs to an output."""
    depths: dict[str, int] = {}

    def depth(tree: Tree) -> int:
        if isinstance(tree, Var):
            return depths.get(tree.name, 0)
        if isinstance(tree, Op):
            own = 0 if tree.kind in _EXACT else 1
            return own + max((depth(a) for a in tree.args), default=0)
        return 0

    for statement in lowered.body:
        if isinstance(statement, LoweredAssign):
            depths[statement.target] = depth(statement.tree)
    return max((depth(leaf) for _, leaves in lowered.results for leaf in leaves), default=0)


#: The programs run calls besides the step, whose roundings a stored result also carries.
RUN_PROGRAMS = ("init", "enter", "store", "backward")


def step_programs(unit: Unit) -> tuple[str, ...]:
    """The programs run calls one after the other on one step: ``step``, or (a unit
    without one, of the run kind ``sensors``) ``predict`` then each sensor's update."""
    if "step" in unit.programs:
        return ("step",)
    return ("predict",) + tuple(program_name(s.name) for s in unit.sensors)


def run_roundings(unit: Unit) -> int:
    """L: the roundings on the longest chain from run's inputs to a stored result, as the
    C computes them (fma through DERIVE_FMA), plus :data:`EXTRA_ROUNDINGS`."""
    state = tuple(port for port, _ in unit.carried)

    def depth(name: str) -> int:
        return rounding_depth(lower_program(unit.programs[name], use_fma=True,
                                            state_ports=state))

    two = two_step(unit, use_fma=True)
    step = max(sum(depth(name) for name in step_programs(unit)),
               rounding_depth(two) if two is not None else 0)
    return step + sum(depth(name) for name in RUN_PROGRAMS if name in unit.programs) + \
        EXTRA_ROUNDINGS


def growth_of(A: np.ndarray, steps: int) -> float:
    """sum_{j < steps} ||A^j||_inf, stopped once a term is below 2^-24 of the sum."""
    total, power = 0.0, np.eye(A.shape[0])
    for _ in range(max(steps, 1)):
        term = float(np.abs(power).sum(axis=1).max())
        total += term
        if term < FLOAT.unit_roundoff * total:
            break
        power = A @ power
    return total


def _closed_loop(F: np.ndarray, H: np.ndarray, Pp: np.ndarray, R: np.ndarray) -> np.ndarray:
    K = np.linalg.solve(H @ Pp @ H.T + R, H @ Pp).T
    return (np.eye(F.shape[0]) - K @ H) @ F


def _predicted(model, xs, Ps, us=None):
    """(x, P(k+1/k), F, H, R) per step of a reference run (linear: the model's matrices;
    nonlinear: the Jacobians at each filtered state)."""
    if model.kind == "linear":
        num = model.numeric()
        for P in Ps:
            yield num.F @ P @ num.F.T + num.GQGt, num.F, num.H, num.R, None
        return
    fns = model.numeric_functions()
    for k, (x, P) in enumerate(zip(xs, Ps)):
        # the next step's inputs (row k + 1 drives the prediction from x(k/k))
        u = us[min(k + 1, len(us) - 1)] if us is not None and len(us) else ()
        args = (x, u) if model.f_inputs else (x,)
        F = np.atleast_2d(fns["F"](*args))
        x_pred = fns["f"](*args)
        H = np.atleast_2d(fns["H"](x_pred, u))
        yield F @ P @ F.T + fns["Q"], F, H, fns["R"], fns["h"](x_pred, u)


def error_growth(model, name: str, steps: int, run=None) -> float:
    """G: the accumulation of one step's error along the carried state (module docstring);
    ``run``: (xs, Ps, us) of the KF (linear) or the filter's (nonlinear) reference."""
    spec = kind(name)
    if spec.run_kind == "windowed":
        return 1.0
    if model.kind == "linear":
        num = model.numeric()
        try:
            A = kf_steady(num.F, num.G, num.H, num.Q, num.R).A
        except (ModelError, np.linalg.LinAlgError):  # no steady state: the run's last P
            Pp, F, H, R, _ = list(_predicted(model, *run))[-1]
            A = _closed_loop(F, H, Pp, R)
        return growth_of(A, steps)
    Pp, F, H, R, _ = list(_predicted(model, *run))[-1]
    return growth_of(_closed_loop(F, H, Pp, R), steps)


def _spreads_cancel(model) -> bool:
    """Whether a sigma-point filter still forms a spread of h by subtracting values of h's
    size: only at the nodes h's difference form computes as g(a') - g(a)
    (derive.filters.difference; the UKF computes every other spread without that)."""
    return bool(difference_form(model.subs(model.h), model.state_symbols).fallbacks)


def condition(model, name: str, run) -> float:
    """kappa (module docstring) from a reference run ``(xs, Ps, us)``."""
    spec = kind(name)
    if not spec.covariance:
        return 1.0
    kappa = 1.0
    sigma_points = "alpha" in spec.options.specs() and _spreads_cancel(model)
    for Pp, _, H, R, h in _predicted(model, *run):
        HPH = H @ Pp @ H.T
        kappa = max(kappa, float(np.linalg.cond(HPH + R)), float(np.linalg.cond(Pp)))
        if sigma_points:
            spread = float(np.sqrt(np.min(np.diag(HPH))))
            cancellation = float(np.max(np.abs(h))) / spread if spread > 0 else np.inf
            kappa = max(kappa, cancellation**2)
    return kappa


@dataclass(frozen=True)
class SensorsConditioning:
    """What a sensors unit's reference run gives the tolerance: per step the map A_k that
    carries the error of x(k-1/k-1) to x(k/k); every matrix solved or inverted (each
    update's S, each P(k/k-1)); and ``cycle``, the longest gap between two updates of one
    sensor (the run's last ``cycle`` steps hold every phase of the sensors' rates)."""

    maps: tuple[np.ndarray, ...]
    solved: tuple[np.ndarray, ...]
    cycle: int


def sensors_conditioning(model, trace: Sequence) -> SensorsConditioning:
    """The :class:`SensorsConditioning` of ``model``'s sensors reference run from its
    ``trace`` (derive.reference.sensors.StepTrace per step)."""
    F = transition_function(model)
    n = model.n
    maps, solved, present = [], [], {}
    for k, step in enumerate(trace):
        A = np.eye(n)
        if step.P_predicted is not None:
            A = F(step.x_before, step.u, step.p)
            solved.append(step.P_predicted)
        for update in step.updates:
            solved.append(update.S)
            present.setdefault(update.sensor, []).append(k)
            if update.applied:
                A = (np.eye(n) - update.K @ update.H) @ A
        maps.append(A)
    gaps = [int(np.max(np.diff(rows))) if len(rows) > 1 else len(trace)
            for rows in present.values()]
    return SensorsConditioning(tuple(maps), tuple(solved),
                               max(1, min(max(gaps, default=len(trace)), len(trace))))


def run_growth(maps: Sequence[np.ndarray], cycle: int = 1) -> float:
    """max over the endpoints e of the run's last ``cycle`` steps of
    sum_{j >= 0} ||A_e A_{e-1} ... A_{e-j+1}||_inf (the j = 0 term: 1), the products formed
    backwards from every endpoint at once; the sums stop once every new term is below
    2^-24 of its sum."""
    steps = len(maps)
    if not steps:
        return 1.0
    n = maps[0].shape[0]
    ends = np.arange(max(steps - cycle, 0), steps)
    products = np.broadcast_to(np.eye(n), (len(ends), n, n)).copy()
    sums = np.ones(len(ends))
    for i in range(steps - 1, 0, -1):
        active = ends >= i  # the endpoints whose product reaches back past A_i
        products[active] = products[active] @ maps[i]
        terms = np.abs(products[active]).sum(axis=2).max(axis=1)
        sums[active] += terms
        if active.all() and np.all(terms < FLOAT.unit_roundoff * sums):
            break
    return float(sums.max())


def float_tolerance(model, unit: Unit, steps: int, run) -> FloatTolerance:
    """The float32 tolerance of ``unit`` (a filter of ``model``) for a run of ``steps``
    steps; ``run`` (xs, Ps, us): the float64 reference run the conditioning is read from
    (the KF's for a linear model, the filter's own for a nonlinear one), or for a unit of
    the run kind ``sensors`` the :class:`SensorsConditioning` of its reference run."""
    if isinstance(run, SensorsConditioning):
        return FloatTolerance(
            roundings=run_roundings(unit), growth=run_growth(run.maps, run.cycle),
            condition=max([1.0] + [float(np.linalg.cond(M)) for M in run.solved]))
    return FloatTolerance(roundings=run_roundings(unit),
                          growth=error_growth(model, unit.filter, steps, run),
                          condition=condition(model, unit.filter, run))


__all__ = ["C", "EXTRA_ROUNDINGS", "RUN_PROGRAMS", "FloatTolerance", "SensorsConditioning",
           "condition", "error_growth", "float_tolerance", "growth_of", "rounding_depth",
           "run_growth", "run_roundings", "sensors_conditioning", "step_programs"]
