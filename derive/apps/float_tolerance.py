"""The tolerance a float32 filter is verified against, derived from float32's unit
roundoff, the generated step and the conditioning of the model (not typed in): for a unit
of the run kind ``sensors`` a first-order bound propagated along its reference run
(below), for every other unit c u L G kappa.

The error measure is derive.apps.verify's (relative_error): per step, ``||gen_k - ref_k||_inf /
max(||ref_k||_inf, floor)``, floor = min(1, the lower median of the non-zero step sizes), for
x(k) and P(k), the largest over the run, against the float64
NumPy reference on the same data. The bound is

    tol = c * u32 * L * G * kappa,      u32 = 2^-24 (FLOAT.unit_roundoff)

* ``L`` (:func:`run_roundings`): the roundings on the longest chain of the step, read
  from its lowered C programs (:func:`rounding_depth`: each add, sub, mul, div, fma, sqrt
  or call rounds once; a temporary passes its depth on; the two-step map instead where
  run takes two steps per pass, if deeper). Where run calls several programs per step in
  sequence (:func:`step_programs`: a unit of the run kind ``sensors`` calls ``predict``
  then each ``update_<sensor>``), the chain runs through all of them: each program's
  carried outputs enter the next at the depth they left with (:func:`chained_depth`; at
  most the sum of their depths). Plus those of the other programs run calls
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
* ``kappa`` (:func:`condition_terms`): the conditioning of what the filter's step
  factorises, solves with, inverts or cancels, as its spec declares it
  (``FilterSpec.conditioning``, derive.filters.spec: the KF's S and its update, the
  information form's R, its update and P(k/k)^-1, ...), read from the reference run from
  P0 on: per step the product of the declared terms (each amplifies the relative error
  the ones before it leave), the largest over the run. The terms:

  - an LDL^T solve with (or inverse of, one solve per column) a symmetric positive-
    definite M (``ldl``: the KF's S, the information form's R and P(k/k)^-1, the RTS
    backward gain's P(k+1/k)): cond_2 of M scaled to a unit diagonal,
    D^-1/2 M D^-1/2 (:func:`scaled_condition`). The computed solution solves
    (M + dM) X = B with |dM| <= gamma |L||D||L^T| (Higham, Thm 10.3), and
    (|L||D||L^T|)_ij <= sqrt(m_ii m_jj), so dM = D^1/2 E D^1/2 with ||E|| of order gamma:
    for the gain, P(k/k) moves by K dM K^T, ||K D K^T|| <= cond_2(D^-1/2 S D^-1/2)
    ||K S K^T|| <= that condition times ||P(k/k-1)|| (Higham Section 10.1.1: Cholesky is
    invariant under diagonal scaling). cond_2(S) itself would charge the units of S
    (metres against metres per second) as error;
  - an unpivoted LU inverse of a general matrix (``lu``: the LF's I + P On): cond_2;
  - the update P(k/k-1) -> P(k/k) (``cancel``: the standard form's P(k/k-1) - K S K^T,
    whose roundings and the solve's error are relative to ||P(k/k-1)||; the information
    form's inverse of P(k/k-1), whose residual reaches P(k/k) as (I - K H) E (I - K H)^T):
    ||P(k/k-1)||_inf / ||P(k/k)||_inf, at least 1 (:func:`cancellation`): the measure
    judges P(k/k) at its own size, so a P(k/k) of 1e-9 cancelled from 1e4 loses 13 digits;
  - a sigma-point filter (whose options have ``alpha``) whose h has a node no rule of the
    difference form covers (derive.filters.difference: its spread there is computed as
    g(a') - g(a)) also has the cancellation of its spreads, of magnitude sqrt(H P H^T)
    computed from values of magnitude |h|: max |h| / sqrt(min diag H P H^T), squared
    since P_zz multiplies two spreads (:func:`spread_cancellation`, kept apart: it
    describes how the UKF's update forms its spreads; every other spread is computed
    without it); kappa is the larger of the two.

  A filter that never inverts or cancels P pays nothing for P's conditioning: the KF and
  EKF solve only S (cond P(1/0) = 2.25e6 for the INS/GNSS EKF, whose kappa is 2.5), the
  UD filter carries P's factors (Bierman's updates divide by S's pivots; its U D U^T is
  an LDL^T, backward stable, never inverted), the UKF's Cholesky of P only spreads its
  sigma points (its backward error, bounded by P's diagonal, is a perturbation of P that
  L counts). 1 for a filter whose constants are all computed offline in double (sskf,
  sslf, jssklf, fir, pred: nothing declared).
* ``c = 2`` (:data:`C`): the state's error and the covariance's error reach the measure by
  two routes (x through the recursion, P directly and through the gain), each bounded by
  the first-order gamma_L; second-order terms (L u)^2 are below 1e-4 of it for L < 2000.

A unit of the run kind ``sensors`` (several sensors at their own rates, gating,
update-first: the EKF, the error-state EKF and the KF of a model with sensors) has a
first-order bound of its own (:class:`PropagatedTolerance`, :func:`propagated_bound`),
evaluated along the trace of its float64 reference run (derive.reference.sensors: per
step the values each program was called with):

* the local error (:func:`local_errors`): per step, the running error bound u E of
  x(k/k) and P(k/k) (derive.apps.running_error, Wilkinson's running error analysis:
  first order, each operation's rounding at its own numbers, nothing counted by depth)
  of the programs run calls on the step (predict, then each present sensor's update),
  one program's outputs entering the next with their E; the carried x and P enter the
  step exact, z, u, p (and step 0's x0, P0) carry their rounding to float32;
* the carried error: the first-order error of the filter's carried state obeys
  e_k = A_k e_{k-1} + d_k, A_k = prod_s (I - K_s H_s) F_k (:func:`sensors_conditioning`:
  the updates applied at step k, in order; F_k the transition or the EKF's Jacobian,
  over the tangent space for manifold states; the identity at an update-first step 0),
  for x, and dP_k = A_k dP_{k-1} A_k^T + D_k for P (the first-order change of the
  Riccati step, P - P H^T S^-1 H P, is (I - K H) dP (I - K H)^T: the gain's own change
  cancels at the optimal gain). Neither recursion is taken in absolute values (|A| over
  a thousand steps grows without bound where the maps barely contract: the weakly
  observed earth field, magnetic bias and wind); each carries a bound through the
  signed maps instead: P's error by a Loewner majorant, -M_k <= dP_k <= M_k with
  M_k = A_k M_{k-1} A_k^T + Lambda_k, Lambda_k diagonal from D_k's scaled row sums
  (Gershgorin, :func:`_majorant`), so |dP_ij| <= sqrt(M_ii M_jj); x's error by an
  ellipsoid, e e^T <= W, W_k = (1 + 1/p) A W A^T + (1 + p) n diag(d_k^2) (the box of the
  local error inside an ellipsoid, the sum of two ellipsoids inside a third, p of least
  trace: :func:`_ellipsoid_sum`), so |e_i| <= sqrt(W_ii), on storage coordinates
  through the retraction Jacobian N(x) for manifold states;
* the coupling: P's carried error moves each applied update's gain, dK = (I - K H) dP
  H^T S^-1, so x takes dK nu, bounded componentwise by sqrt(r_i^T M r_i) sqrt(w^T M w)
  (r_i the rows of I - K H, w = H^T S^-1 nu) and added to that step's local error;
* the value: u max(x, P), each the largest over the run's steps of the bound over the
  measure's scale (:func:`measure_scales`: derive.apps.verify.relative_error's).

What it leaves out, stated: second-order terms (the bound is first order, as the
running error analysis is); the EKF's linearisation's own dependence on x's error (the
change of F, H and of the gain through H, second derivatives of f and h: zero for a
linear model: not small next to P's part on the INS models, below the value there, which
x's part sets; docs/generated-code.md has the estimate); a gate's decision, taken as the
reference run's; the reset Jacobian G of an error-state filter's option ``reset`` in the
maps (G = I to first order in the injected dx).

A bound at or above 1 says the model cannot be computed meaningfully in float32;
:attr:`FloatTolerance.meaningful` says so and the verification reports it failed.

The same bound at double's unit roundoff, u64 = 2^-53 (:func:`in_double`: the inputs need
no rounding, so L has one rounding fewer), is what two correct double implementations can
differ by on an ill-conditioned model: `derive verify` holds a linear double filter to
1e-12, or to this bound where the model's conditioning puts it above 1e-12
(derive.apps.verify).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from .. import manifolds
from ..errors import ModelError
from ..filters import kind
from ..filters.difference import difference_form
from ..filters.sensors import program_name, transition_function
from ..filters.spec import (
    INNOVATION,
    LAINIOTIS,
    NEXT_PRIOR,
    NOISE,
    NOMINAL,
    POSTERIOR,
    PRIOR,
    UPDATE,
    Conditioned,
    FilterSpec,
)
from ..lowering import LoweredAssign, LoweredProgram, lower_program
from ..precision import DOUBLE, FLOAT
from ..riccati import kf_steady
from ..runs import kinds
from ..runs.unit import Unit
from ..trees import Op, Tree, Var, element_name
from .running_error import port_values, running_errors

#: The constant of the bound (see the module docstring).
C = 2.0
#: Roundings outside the step's program: the inputs rounded to float, the constants.
EXTRA_ROUNDINGS = 2
#: Operations that do not round: a negation, the missing-measurement select.
_EXACT = frozenset({"neg", "select", "cmp"})


class _Bound:
    """What a bound of either kind says beside its ``value`` and ``unit_roundoff``."""

    value: float
    unit_roundoff: float

    @property
    def meaningful(self) -> bool:
        """False when the bound is 1 or more: the precision cannot carry the model."""
        return self.value < 1.0

    @property
    def precision_name(self) -> str:
        """``float32`` or ``double``: the precision whose unit roundoff the bound uses."""
        return "float32" if self.unit_roundoff == FLOAT.unit_roundoff else "double"


@dataclass(frozen=True)
class FloatTolerance(_Bound):
    """The float32 tolerance of one filter on one run: ``value`` = c u L G kappa;
    ``terms``: what kappa is made of, (name, value) at the step where it is largest (each
    thing the filter's step factorises, solves or cancels: :func:`condition_terms`)."""

    roundings: int
    growth: float
    condition: float
    unit_roundoff: float = FLOAT.unit_roundoff
    c: float = C
    terms: tuple[tuple[str, float], ...] = ()

    @property
    def value(self) -> float:
        return self.c * self.unit_roundoff * self.roundings * self.growth * self.condition

    def text(self) -> str:
        """``c u32 L G kappa = 2 * 2^-24 * 12 * 3.1 * 1.0 = 4.4e-06`` (``u64`` and 2^-53 in
        double), then what kappa is made of (``; kappa: cond S 1 * P(k/k-1) -> P(k/k) 2.51``)."""
        u = "u32" if self.precision_name == "float32" else "u64"
        text = (f"c {u} L G kappa = {self.c:g} * 2^{int(np.log2(self.unit_roundoff))} * "
                f"{self.roundings} * {self.growth:.3g} * {self.condition:.3g} = "
                f"{self.value:.2e}")
        if self.terms:
            text += "; kappa: " + " * ".join(f"{name} {value:.3g}" for name, value in self.terms)
        return text


@dataclass(frozen=True)
class PropagatedTolerance(_Bound):
    """The float32 tolerance of a unit of the run kind sensors: ``u * max(x, P)``, ``x``
    and ``P`` the largest over the run of the first-order bound on the error of x(k/k) and
    of P(k/k) over the measure's scale, in units of u (:func:`propagated_bound`)."""

    x: float
    P: float
    unit_roundoff: float = FLOAT.unit_roundoff

    @property
    def value(self) -> float:
        return self.unit_roundoff * max(self.x, self.P)

    def text(self) -> str:
        """``first order u32 * max(x 2.1e+03, P 3.4e+02) = 1.3e-04, each step's running
        error carried by the filter's maps``."""
        u = "u32" if self.precision_name == "float32" else "u64"
        return (f"first order {u} * max(x {self.x:.3g}, P {self.P:.3g}) = {self.value:.2e}, "
                "each step's running error carried by the filter's maps")


def output_depths(lowered: LoweredProgram, inputs: Mapping[str, int] | None = None
                  ) -> dict[str, list[int]]:
    """Per output port, the most roundings on one chain to each of its elements, from the
    program's inputs (each input element ``x[3]`` starting at ``inputs``' depth, 0 when
    not given)."""
    depths: dict[str, int] = dict(inputs or {})

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
    return {port: [depth(leaf) for leaf in leaves] for port, leaves in lowered.results}


def rounding_depth(lowered: LoweredProgram) -> int:
    """The most roundings on one chain from the program's inputs to an output."""
    return max((d for found in output_depths(lowered).values() for d in found), default=0)


def chained_depth(unit: Unit, names: Sequence[str]) -> int:
    """The most roundings on one chain through the programs ``names`` run one after the
    other on a step: each program's carried outputs (``x_new``, ``P_new``) enter the next
    as its inputs (``x``, ``P``) at the depth they left with."""
    state = tuple(port for port, _ in unit.carried)
    carried = {out: port for port, out in unit.carried}
    entering: dict[str, int] = {}
    deepest = 0
    for name in names:
        found = output_depths(lower_program(unit.programs[name], use_fma=True,
                                            state_ports=state), entering)
        deepest = max([deepest] + [d for depths in found.values() for d in depths])
        entering = {element_name(carried[port], i): d for port, depths in found.items()
                    if port in carried for i, d in enumerate(depths)}
    return deepest


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
    C computes them (fma through DERIVE_FMA and DERIVE_FNMA), plus :data:`EXTRA_ROUNDINGS`;
    through the programs run calls on one step, chained (:func:`chained_depth`)."""
    state = tuple(port for port, _ in unit.carried)

    def depth(name: str) -> int:
        return rounding_depth(lower_program(unit.programs[name], use_fma=True,
                                            state_ports=state))

    two = kinds.two_step_map(unit, use_fma=True)
    step = max(chained_depth(unit, step_programs(unit)),
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


class ReferenceRun(NamedTuple):
    """A float64 reference run the tolerance reads the conditioning from: xs and Ps (x(k/k),
    P(k/k) per step), the inputs us (row k with step k; None: none) and x0, P0, where the
    run starts (the first prediction's P(1/0) = F P0 F^T + G Q G^T is often the worst
    conditioned)."""

    xs: np.ndarray
    Ps: np.ndarray
    us: np.ndarray | None
    x0: np.ndarray
    P0: np.ndarray


def _predicted(model, xs, Ps, us=None, offset: int = 1):
    """(P(k+1/k), F, H, R, h) per step of a reference run (linear: the model's matrices;
    nonlinear: the Jacobians at each filtered state); the prediction from row k of xs and
    Ps takes row k + ``offset`` of the inputs us."""
    if model.kind == "linear":
        num = model.numeric()
        for P in Ps:
            yield num.F @ P @ num.F.T + num.GQGt, num.F, num.H, num.R, None
        return
    fns = model.numeric_functions()
    for k, (x, P) in enumerate(zip(xs, Ps)):
        # the next step's inputs (row k + 1 drives the prediction from x(k/k))
        u = us[min(k + offset, len(us) - 1)] if us is not None and len(us) else ()
        args = (x, u) if model.f_inputs else (x,)
        F = np.atleast_2d(fns["F"](*args))
        x_pred = fns["f"](*args)
        H = np.atleast_2d(fns["H"](x_pred, u))
        Q = fns["Q"](x, u) if callable(fns["Q"]) else fns["Q"]  # at x(k/k), u as the filter
        R = fns["R"](x_pred, u) if callable(fns["R"]) else fns["R"]  # at the prediction
        yield F @ P @ F.T + Q, F, H, R, fns["h"](x_pred, u)


def error_growth(model, name: str, steps: int, run: ReferenceRun | None = None) -> float:
    """G: the accumulation of one step's error along the carried state (module docstring);
    ``run``: the KF's (linear) or the filter's (nonlinear) :class:`ReferenceRun`."""
    spec = kind(name)
    if spec.run_kind == "windowed":
        return 1.0
    if model.kind == "linear":
        num = model.numeric()
        try:
            A = kf_steady(num.F, num.G, num.H, num.Q, num.R).A
        except (ModelError, np.linalg.LinAlgError):  # no steady state: the run's last P
            Pp, F, H, R, _ = list(_predicted(model, run.xs, run.Ps, run.us))[-1]
            A = _closed_loop(F, H, Pp, R)
        return growth_of(A, steps)
    Pp, F, H, R, _ = list(_predicted(model, run.xs, run.Ps, run.us))[-1]
    return growth_of(_closed_loop(F, H, Pp, R), steps)


def scaled_condition(M: np.ndarray) -> float:
    """cond_2 of ``M`` scaled to a unit diagonal, D^-1/2 M D^-1/2 with D = diag(M) (a
    matrix with a diagonal entry <= 0 unscaled, one with a non-finite entry infinite):
    what bounds an LDL^T or Cholesky solve
    with ``M``, whose backward error is componentwise bounded by sqrt(m_ii m_jj) (Higham,
    Thm 10.3 and Section 10.1.1: invariant under diagonal scaling)."""
    if not np.all(np.isfinite(M)):
        return float("inf")
    d = np.diag(M)
    if np.any(d <= 0):
        return float(np.linalg.cond(M))
    scale = 1.0 / np.sqrt(d)
    return float(np.linalg.cond(M * scale[:, None] * scale[None, :]))


def cancellation(before: np.ndarray, after: np.ndarray) -> float:
    """The update's subtraction P(k/k) = P(k/k-1) - K S K^T: its operands (K S K^T <=
    P(k/k-1)) over its result, ||P(k/k-1)||_inf / ||P(k/k)||_inf: the factor by which the
    roundings of the operands, relative to them, grow relative to the result, which the
    error measure (derive.apps.verify.relative_error) judges at the result's own size (or
    at a floor below it, never above 1); at least 1 (the roundings relative to the result
    itself); infinite for a zero result of a non-zero P(k/k-1)."""
    top = float(np.abs(before).sum(axis=1).max())
    bottom = float(np.abs(after).sum(axis=1).max())
    if bottom == 0.0:
        return 1.0 if top == 0.0 else float("inf")
    return max(1.0, top / bottom)


def conditioned(entry: Conditioned, matrices: Sequence) -> float:
    """The conditioning of one :class:`~derive.filters.spec.Conditioned` entry of a step:
    ``matrices`` the step's instances (for ``cancel``: (before, after) pairs); the
    largest."""
    if entry.method == "cancel":
        values = [cancellation(before, after) for before, after in matrices]
    elif entry.method == "ldl":
        values = [scaled_condition(M) for M in matrices]
    else:
        values = [float(np.linalg.cond(M)) for M in matrices]
    return max(values, default=1.0)


def term_name(entry: Conditioned) -> str:
    """How a kappa term is printed: ``cond S`` (a factorisation), ``P(k/k-1) -> P(k/k)``
    (a cancellation)."""
    return entry.matrix if entry.method == "cancel" else f"cond {entry.matrix}"


def step_terms(conditioning: Sequence[Conditioned], step: Mapping[str, Sequence]
               ) -> tuple[tuple[str, float], ...]:
    """Each entry's conditioning in one step, by :func:`term_name`."""
    return tuple((term_name(entry), conditioned(entry, step[entry.matrix]))
                 for entry in conditioning)


def worst_step(conditioning: Sequence[Conditioned], steps: Sequence[Mapping[str, Sequence]]
               ) -> tuple[float, tuple[tuple[str, float], ...]]:
    """(kappa, its terms): the largest kappa of a step over ``steps`` and the terms of that
    step; (1, ()) for a filter that declares nothing. A step's kappa is the product of its
    entries' conditioning (each multiplies the relative error the previous ones leave: a
    solve's error relative to P(k/k-1) is amplified by the update's cancellation relative
    to P(k/k))."""
    if not conditioning:
        return 1.0, ()
    kappa, terms = 1.0, step_terms(conditioning, steps[0]) if steps else ()
    for step in steps:
        found = step_terms(conditioning, step)
        value = float(np.prod([v for _, v in found]))
        if value > kappa:
            kappa, terms = value, found
    return kappa, terms


def run_steps(model, spec: FilterSpec, run: ReferenceRun) -> list[dict[str, list]]:
    """Per step of a reference run (from P0 on), the matrices ``spec.conditioning`` names:
    a dict from each of derive.filters.spec.MATRICES the filter declares to its instances
    in the step (UPDATE: the pair (P(k/k-1), P(k/k)))."""
    wanted = {entry.matrix for entry in spec.conditioning}
    previous = [run.P0] + list(run.Ps[:-1])
    predicted = _predicted(model, [run.x0] + list(run.xs[:-1]), previous, run.us, offset=0)
    lainiotis = lainiotis_matrices(model) if wanted & {LAINIOTIS, NOMINAL} else None
    steps = []
    for P_before, P, (Pp, _, H, R, _) in zip(previous, run.Ps, predicted):
        step: dict[str, list] = {}
        for name in wanted:
            if name == INNOVATION:
                step[name] = [H @ Pp @ H.T + R]
            elif name in (PRIOR, NEXT_PRIOR):  # NEXT_PRIOR: moved one step back below
                step[name] = [Pp]
            elif name == POSTERIOR:
                step[name] = [information(P)]
            elif name == NOISE:
                step[name] = [R]
            elif name == UPDATE:
                step[name] = [(Pp, P)]
            elif name == LAINIOTIS:
                step[name] = [np.eye(len(P)) + P_before @ lainiotis[0]]
            else:  # NOMINAL
                step[name] = [lainiotis[1]]
        steps.append(step)
    if NEXT_PRIOR in wanted:  # output k's backward solve takes step k + 1's P(k+1/k)
        for step, following in zip(steps, steps[1:] + [{NEXT_PRIOR: []}]):
            step[NEXT_PRIOR] = following[NEXT_PRIOR]
    return steps


def information(P: np.ndarray) -> np.ndarray:
    """P^-1 (infinite where P is singular: nothing inverts it finitely)."""
    try:
        return np.linalg.inv(P)
    except np.linalg.LinAlgError:
        return np.full_like(P, np.inf)


def lainiotis_matrices(model) -> tuple[np.ndarray, np.ndarray]:
    """(On, H GQG^T H^T + R) of a linear model (derive.filters.lf's constants)."""
    num = model.numeric()
    nominal = num.H @ num.GQGt @ num.H.T + num.R
    HF = num.H @ num.F
    return HF.T @ np.linalg.solve(nominal, HF), nominal


def spreads_cancel(model) -> bool:
    """Whether a sigma-point filter still forms a spread of h by subtracting values of h's
    size: only at the nodes h's difference form computes as g(a') - g(a)
    (derive.filters.difference; the UKF computes every other spread without that)."""
    return bool(difference_form(model.subs(model.h), model.state_symbols).fallbacks)


def spread_cancellation(model, spec: FilterSpec, run: ReferenceRun) -> float:
    """A sigma-point filter's (whose options have ``alpha``) cancellation of its spreads:
    h(sigma_i) - h_mean, of magnitude sqrt(H P H^T), is computed from values of magnitude
    |h|: max |h| / sqrt(min diag H P H^T), squared since P_zz multiplies two spreads; 1 for
    any other filter, and for one whose h's difference form has a rule for every node
    (:func:`spreads_cancel`). (Kept apart from the factorisations: it describes how the
    UKF's generated update forms its spreads, and changes with it.)"""
    if "alpha" not in spec.options.specs() or not spreads_cancel(model):
        return 1.0
    worst = 1.0
    for Pp, _, H, _, h in _predicted(model, run.xs, run.Ps, run.us):
        spread = float(np.sqrt(np.min(np.diag(H @ Pp @ H.T))))
        ratio = float(np.max(np.abs(h))) / spread if spread > 0 else np.inf
        worst = max(worst, ratio**2)
    return worst


def condition_terms(model, name: str, run: ReferenceRun
                    ) -> tuple[float, tuple[tuple[str, float], ...]]:
    """(kappa, its terms) (module docstring) from a reference run: the largest over its
    steps of the product of what the filter's spec declares its step factorises, solves
    with, inverts or cancels (derive.filters.spec.Conditioned), or a sigma-point filter's
    spread cancellation where that is larger."""
    spec = kind(name)
    kappa, terms = worst_step(spec.conditioning, run_steps(model, spec, run)
                              if spec.conditioning else [])
    spreads = spread_cancellation(model, spec, run)
    if spreads > kappa:
        return spreads, (("spreads", spreads),)
    return kappa, terms


def condition(model, name: str, run: ReferenceRun) -> float:
    """kappa (:func:`condition_terms`)."""
    return condition_terms(model, name, run)[0]


@dataclass(frozen=True)
class SensorsConditioning:
    """What a sensors unit's reference run gives the tolerance: per step the map A_k that
    carries the error of x(k-1/k-1) to x(k/k) and the transition F_k it starts with (the
    identity at an update-first step 0); ``trace``: the run's
    derive.reference.sensors.StepTrace s, the values :func:`local_errors` runs the
    unit's programs at."""

    maps: tuple[np.ndarray, ...]
    transitions: tuple[np.ndarray, ...]
    trace: tuple


def sensors_conditioning(model, trace: Sequence) -> SensorsConditioning:
    """The :class:`SensorsConditioning` of ``model``'s sensors reference run from its
    ``trace`` (derive.reference.sensors.StepTrace per step): A_k = prod_s (I - K_s H_s) F_k
    over the updates applied at step k, in order, F_k the transition or the EKF's
    Jacobian at x(k-1/k-1) (over the tangent space for manifold states)."""
    F = transition_function(model)
    n = model.n_tangent  # the error's dimension: P's
    maps, transitions = [], []
    for step in trace:
        A = np.eye(n) if step.P_predicted is None else F(step.x_before, step.u, step.p)
        transitions.append(A)
        for update in step.updates:
            if update.applied:
                A = (np.eye(n) - update.K @ update.H) @ A
        maps.append(A)
    return SensorsConditioning(tuple(maps), tuple(transitions), tuple(trace))


def error_floor(step_sizes) -> float:
    """The smallest scale a step's error is divided by: min(1, the lower median of the
    non-zero step sizes ``||ref_k||_inf``), 0 when every step is zero.

    A step whose reference is (near) zero is judged at the size of the array's typical
    step, not divided by its own noise; an array of small numbers (P ~ 1e-20) is judged at
    its own size, not at 1 (which made the measure absolute for it: a doubled P of 1e-20
    passed 1e-12). The median, not the largest step, so a large start (P0 = 1 settling to
    1e-20) does not set the scale of the steps after it; at most 1, so the measure is never
    looser than it was with the floor 1 (absolute below 1, relative above)."""
    sizes = np.sort(np.asarray(step_sizes, dtype=float).ravel())
    sizes = sizes[sizes > 0]
    if sizes.size == 0:
        return 0.0
    return float(min(sizes[(sizes.size - 1) // 2], 1.0))


def measure_scales(arrays: np.ndarray) -> np.ndarray:
    """Per step the scale derive.apps.verify.relative_error divides that step's error by:
    max(||ref_k||_inf, :func:`error_floor`), ``arrays`` the reference's (steps, ...)."""
    sizes = np.abs(np.asarray(arrays, dtype=float)).reshape(len(arrays), -1).max(axis=1)
    return np.maximum(sizes, error_floor(sizes))


def _call_inputs(lowered: LoweredProgram, trace: Sequence, rows: Sequence, columns
                 ) -> dict[str, np.ndarray]:
    """The values each input port of ``lowered`` takes on its calls ``rows`` ((step,
    UpdateTrace or None for predict) pairs) of the reference run ``trace`` (ValueError
    for a port the trace does not give: a program run calls has no other inputs)."""
    given = {}
    for port in lowered.inputs:
        if port.name == "x":
            found = [t.x if t else trace[k].x_before for k, t in rows]
        elif port.name == "P":
            found = [t.P if t else trace[k].P_before for k, t in rows]
        elif port.name == "u":
            found = [trace[k].u if t is None else trace[k].u[list(columns)] for k, t in rows]
        elif port.name == "p":
            found = [trace[k].p for k, _ in rows]
        elif port.name == "z" and rows[0][1] is not None:
            found = [t.z for _, t in rows]
        elif port.name == "R" and rows[0][1] is not None:  # the R given per call
            found = [t.S - t.H @ t.P @ t.H.T for _, t in rows]
        else:
            raise ValueError(f"{lowered.name}: no reference value for its input {port.name!r}")
        given[port.name] = np.asarray(found, dtype=float).reshape(len(rows), -1)
    return given


def local_errors(unit: Unit, trace: Sequence, dtype=np.float32
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(Dx, DP): per step k the running error bound E (derive.apps.running_error) of
    x(k/k) (steps, n) and of P(k/k) (steps, nt, nt), the step's programs (predict, then
    each present sensor's update) run in order at the reference run's values (``trace``:
    derive.reference.sensors.StepTrace per step), each program's x_new and P_new entering
    the next with their E. The carried x and P enter a step exact (their earlier errors
    are what the filter's maps carry: :func:`propagated_bound`), but for step 0's x0 and
    P0, which carry their rounding to ``dtype`` (E = |x0|, |P0|), as z, u, p and a per-call
    R do on every call."""
    state = tuple(port for port, _ in unit.carried)
    steps = len(trace)
    n, nt = len(trace[0].x_before), len(trace[0].P_before)
    Dx, DP = np.zeros((steps, n)), np.zeros((steps, nt * nt))
    Dx[0], DP[0] = np.abs(trace[0].x_before), np.abs(trace[0].P_before).ravel()
    calls = [("predict", (), [(k, None) for k, step in enumerate(trace)
                              if step.P_predicted is not None])]
    calls += [(program_name(slot.name), slot.inputs,
               [(k, t) for k, step in enumerate(trace) for t in step.updates
                if t.sensor == slot.name]) for slot in unit.sensors]
    for name, columns, rows in calls:
        if not rows:
            continue
        lowered = lower_program(unit.programs[name], use_fma=True, state_ports=state)
        given = _call_inputs(lowered, trace, rows, columns)
        ks = [k for k, _ in rows]
        values, errors = {}, {}
        for port, array in given.items():
            values.update(port_values(port, array))
            carried = {"x": Dx, "P": DP}.get(port)
            errors.update(port_values(port, np.abs(array) if carried is None
                                      else carried[ks]))
        out = running_errors(lowered, values, errors, dtype)
        Dx[ks], DP[ks] = out["x_new"][1], out["P_new"][1]
    return Dx, DP.reshape(steps, nt, nt)


def _majorant(D: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Lambda with -Lambda <= E <= Lambda (Loewner order) for every symmetric E with
    |E| <= D elementwise: Lambda_ii = sum_j max(D, D^T)_ij sqrt(P_ii / P_jj) (S (Lambda -
    E) S is diagonally dominant for S = diag(P_ii^-1/2), Gershgorin): in each state's own
    units, ``P`` the covariance that sets them (where its diagonal is not positive:
    the unscaled row sums)."""
    D = np.maximum(D, D.T)
    d = np.diag(P)
    if np.any(d <= 0) or not np.all(np.isfinite(d)):
        return np.diag(D.sum(axis=1))
    s = np.sqrt(d)
    return np.diag((D / s[None, :]).sum(axis=1) * s)


def propagated_bound(model, run: SensorsConditioning, Dx: np.ndarray, DP: np.ndarray,
                     unit_roundoff: float = FLOAT.unit_roundoff) -> tuple[float, float]:
    """(x's, P's): the largest over the run's steps of the first-order bound on the
    error of x(k/k) and P(k/k), each over the scale the measure divides it by
    (:func:`measure_scales`), from the running errors ``Dx``, ``DP`` of each step
    (:func:`local_errors`, times u) carried by the filter's own first-order error maps
    (the module docstring)."""
    u, trace = unit_roundoff, run.trace
    nt = len(trace[0].P_before)
    layout = getattr(model, "layout", None)
    x_scale = measure_scales(np.array([step.x_after for step in trace]))
    P_scale = measure_scales(np.array([step.P_after for step in trace]))
    W, M = np.zeros((nt, nt)), np.zeros((nt, nt))  # x's ellipsoid, P's majorant
    worst_x = worst_P = 0.0
    for k, step in enumerate(trace):
        x = step.x_after
        lift = np.eye(nt) if layout is None else np.abs(manifolds.lift_numeric(layout, x))
        retract = np.eye(nt) if layout is None else manifolds.retraction_numeric(layout, x)
        F = run.transitions[k]
        before = F @ M @ F.T  # P's error before each update
        cross = np.zeros(nt)  # x's error from P's through the gains (tangent)
        for update in step.updates:
            if not update.applied:
                continue
            IKH = np.eye(nt) - update.K @ update.H
            w = update.H.T @ np.linalg.solve(update.S, update.nu)
            cross = np.abs(IKH) @ cross + np.sqrt(np.clip(
                np.diag(IKH @ before @ IKH.T), 0.0, None) * max(float(w @ before @ w), 0.0))
            before = IKH @ before @ IKH.T
        A = run.maps[k]
        carried = A @ W @ A.T
        x_error = (np.sqrt(np.clip(np.diag(retract @ carried @ retract.T), 0.0, None))
                   + u * Dx[k] + np.abs(retract) @ cross)
        worst_x = max(worst_x, float(x_error.max() / x_scale[k]))
        box = lift @ (u * Dx[k]) + cross  # this step's own error, in the tangent space
        W = _ellipsoid_sum(carried, nt * np.diag(box**2))
        M = before + _majorant(u * DP[k], step.P_after)
        worst_P = max(worst_P, float(np.clip(np.diag(M), 0.0, None).max() / P_scale[k]))
    return worst_x, worst_P


def _ellipsoid_sum(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """An ellipsoid (its shape matrix) holding the sum of a vector of the ellipsoid A and
    one of B: (1 + 1/p) A + (1 + p) B with p = sqrt(tr A / tr B), the p of least trace
    ((a + b)(a + b)^T <= (1 + 1/p) a a^T + (1 + p) b b^T for every p > 0)."""
    ta, tb = float(np.trace(A)), float(np.trace(B))
    if ta <= 0.0 or tb <= 0.0:
        return A + B
    p = np.sqrt(ta / tb)
    return (1.0 + 1.0 / p) * A + (1.0 + p) * B


def float_tolerance(model, unit: Unit, steps: int, run
                    ) -> FloatTolerance | PropagatedTolerance:
    """The float32 tolerance of ``unit`` (a filter of ``model``) for a run of ``steps``
    steps; ``run`` (a :class:`ReferenceRun`): the float64 reference run the conditioning is
    read from
    (the KF's for a linear model, the filter's own for a nonlinear one), or for a unit of
    the run kind ``sensors`` the :class:`SensorsConditioning` of its reference run."""
    if isinstance(run, SensorsConditioning):
        x, P = propagated_bound(model, run, *local_errors(unit, run.trace), unit_roundoff=1.0)
        return PropagatedTolerance(x, P)
    kappa, terms = condition_terms(model, unit.filter, run)
    return FloatTolerance(roundings=run_roundings(unit),
                          growth=error_growth(model, unit.filter, steps, run),
                          condition=kappa, terms=terms)


def in_double(bound: FloatTolerance | PropagatedTolerance
              ) -> FloatTolerance | PropagatedTolerance:
    """``bound`` (a float32 tolerance) at double's unit roundoff: the inputs are doubles
    already, so one rounding fewer (the baked constants are still rounded once); a
    :class:`PropagatedTolerance` keeps the inputs' and constants' roundings (an
    overestimate: in double they are exact)."""
    if isinstance(bound, PropagatedTolerance):
        return replace(bound, unit_roundoff=DOUBLE.unit_roundoff)
    return replace(bound, unit_roundoff=DOUBLE.unit_roundoff, roundings=bound.roundings - 1)


__all__ = ["C", "EXTRA_ROUNDINGS", "RUN_PROGRAMS", "FloatTolerance", "ReferenceRun",
           "chained_depth", "output_depths",
           "SensorsConditioning", "cancellation", "condition", "condition_terms", "conditioned",
           "error_growth",
           "float_tolerance", "growth_of", "in_double", "lainiotis_matrices", "rounding_depth",
           "run_roundings", "run_steps", "scaled_condition", "PropagatedTolerance",
           "error_floor", "local_errors", "measure_scales", "propagated_bound",
           "sensors_conditioning", "spread_cancellation", "step_programs",
           "step_terms", "term_name", "worst_step"]
