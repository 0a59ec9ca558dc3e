"""Wrap a filter's programs into the renderer's Unit, with the header facts it states.

The command that regenerates the files is the renderer's (derive.generation), not the
derivation's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import sympy

from ..discretize import METHODS
from ..errors import FilterError
from ..options import SharedOptions
from ..program import PRESENT, ZERO, Check, ProgramError
from ..runs.unit import LOOKAHEAD_NEXT, SensorSlot, Unit
from ..sensitivity import GRADIENT_FACT
from .common import GRADIENT_STORE, LOGLIK_FACT, LOGLIK_STORE, pattern_text
from .spec import FilterSpec


def _fmt(value) -> str:
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    arr = np.asarray(value, dtype=float)
    return np.array2string(arr, precision=17, separator=", ", max_line_width=88,
                           floatmode="unique").replace("\n", "")


def _outside(program, port: str) -> set[tuple[int, int]]:
    """The entries (i, j), i <= j, of the square input ``port`` that the zero checks
    (``Program.require_zero``) of ``program`` require to be zero: outside its pattern."""
    n = program.port(port).shape[0]
    position = {program.element(port, i, j): (i, j) for i in range(n) for j in range(i, n)}
    return {position[c.value] for c in program.body
            if isinstance(c, Check) and c.relation == ZERO and c.value in position}


def accepted_P0(program, port: str = "P") -> str:
    """The header line that says which P0 (and P) the code accepts: those zero outside the
    closed pattern, which the zero checks (``Program.require_zero``) of ``program`` on its
    input ``port`` enforce (the step's P, or an ``enter`` program's P0)."""
    n = program.port(port).shape[0]
    outside = _outside(program, port)
    if not outside:
        return "P0 accepted: any symmetric P0 (P's pattern closes to dense; upper triangle read)"
    pattern = [[(i, j) not in outside and (j, i) not in outside for j in range(n)]
               for i in range(n)]
    return (f"P0 accepted: exactly those zero outside P's pattern {pattern_text(pattern)} "
            "(x may be non-zero; upper triangle read and checked; others are refused)")


def make_unit(model, spec: FilterSpec, programs: dict, options: SharedOptions,
              constants: dict | None = None, step_inputs: tuple[str, ...] = ("z",),
              window: int | None = None, horizon: int | None = None,
              lookahead=None, carried: tuple[tuple[str, str], ...] | None = None) -> Unit:
    """The Unit for ``model`` and the filter of ``spec`` with its validated ``options``;
    ``constants`` become header facts; ``window`` (fir) and ``horizon`` (pred): N;
    ``lookahead``: the two-step map of an affine step (derive.runs.kinds.two_steps);
    ``carried``: the unit's own carried (input port, output port) pairs (default: the run
    kind's), entered by an ``enter`` program and stored by a ``store`` program.  With the
    option ``loglik`` the step's output ``ll`` is stored by run (and run_tracks) per step
    (``lls``), with ``gradient`` also its last output ``dll`` (``dlls``).

    The spec gives the unit its title, run-loop kind, run descriptions and whether the
    function run_tracks applies; the run kind its carried state.  Which P0 the code accepts is
    read from the program that takes it: ``enter`` (its P0) when there is one, else
    ``step`` (its P)."""
    facts = []
    takes_P0 = (("enter", "P0") if "P0" in _input_names(programs.get("enter")) else
                ("step", "P") if "P" in _input_names(programs["step"]) else None)
    if model.kind == "linear" and takes_P0 is not None:
        facts.append(f"P0 pattern declared: {options.P0_pattern or model.P0_pattern}")
    if takes_P0 is not None:
        facts.append(accepted_P0(programs[takes_P0[0]], takes_P0[1]))
    if getattr(model, "continuous", None):
        facts.append(f"discretisation: {METHODS[model.continuous['method']]}")
    for key, value in (constants or {}).items():
        text = _fmt(value)
        facts.append(f"{key} = {text}" if len(text) <= 300 else
                     f"{key}: {np.asarray(value).shape} constants baked into the code")
    # the option loglik: the step's output ll, stored per step by run and run_tracks
    gradient = bool(options.get("gradient"))
    loglik = bool(options.get("loglik")) or gradient
    if loglik:
        facts.append(LOGLIK_FACT)
    if gradient:  # and its gradient dll, stored per step as dlls
        facts.append(GRADIENT_FACT)
    fields = spec.unit_fields(window=window, run_tracks=options.run_tracks)
    if gradient:  # its enter program starts the sensitivities at zero
        fields["extra_programs"] = tuple(fields["extra_programs"]) + ("enter",)
    unit_options = {}
    if window is not None:
        unit_options["window"] = window
    if horizon is not None:
        unit_options["horizon"] = horizon
    return Unit(
        model=model.name,
        filter=spec.name,
        **fields,
        extra_stores=((LOGLIK_STORE,) if loglik else ()) + ((GRADIENT_STORE,) if gradient
                                                            else ()),
        lookahead=lookahead,
        n=model.n,
        m=model.m,
        nt=model.n_tangent,
        programs=programs,
        parameters=tuple(p.name for p in model.parameters),
        step_inputs=step_inputs,
        facts=tuple(f for f in facts if f),
        options=unit_options,
        carried=carried,
        symbol_prefix=options.prefix,
        precision=options.precision,
        run_function=options.run,
    )


class _WithoutPrediction:
    """``model`` as its update alone sees it: F = I, no process noise (Q, G Q G^T = 0) and
    no input in the prediction (B = 0), so that a family's step of it is the update of x,
    P with z; P0 declared with ``pattern`` (the closed pattern of the model's own step,
    whatever name the derivation asks for). Everything else is the model's."""

    #: the covariance an update of this model starts from: P0 itself, not a prediction
    prior_covariance = "P0"

    def __init__(self, model, pattern) -> None:
        self._model, self._pattern = model, pattern

    def __getattr__(self, name: str):
        return getattr(self._model, name)

    def matrix(self, key: str):
        given = self._model.matrix(key)
        if key == "F":
            return sympy.ImmutableMatrix.eye(self._model.n)
        if key in ("Q", "GQGt", "B"):
            return sympy.ImmutableMatrix.zeros(*given.shape)
        return given

    def pattern_mask(self, name: str | None = None):
        return self._pattern


START_FACT = ("start: update-first: step 0 updates x0, P0 with its measurements, without a "
              "prediction (the function update)")


def update_first_unit(unit: Unit, model, spec: FilterSpec, options: SharedOptions) -> Unit:
    """``unit`` (of a run whose step fuses the prediction and the update) with the option
    start="update": its program ``update`` is the family's step of the model without a
    prediction (:class:`_WithoutPrediction`), derived with P in the pattern the step
    accepts (read from its zero checks); run calls it at step 0 (derive.runs.kinds), so
    that x(0/0), P(0/0) are x0, P0 updated with z(0), pykalman's convention. No
    run_tracks. Refused when the update would keep a carried matrix in another pattern
    than the step's (an entry the step never reads)."""
    takes = ("enter", "P0") if "enter" in unit.programs else ("step", "P")
    n = model.n
    outside = _outside(unit.programs[takes[0]], takes[1])
    pattern = tuple(tuple((min(i, j), max(i, j)) not in outside for j in range(n))
                    for i in range(n))
    alone = spec.derive(_WithoutPrediction(model, pattern), spec,
                        replace(options, P0_pattern="dense"))
    step, update = unit.programs["step"], alone.programs["step"]
    for port in (p.name for p in step.inputs if len(p.shape) == 2):
        if _outside(step, port) != _outside(update, port):
            raise FilterError(f"update-first {spec.name} of model {model.name!r}: its update "
                              f"alone keeps {port} in another pattern than its step; "
                              "generate with --P0-pattern dense")
    message = next((c.message for c in step.body
                    if isinstance(c, Check) and c.relation == ZERO), None)
    update = update.renamed("update", "the update alone, without a prediction: run's step 0 "
                            "with start=update (x0, P0 and z(0) -> x(0/0), P(0/0))",
                            pattern_message=message)
    return replace(unit, programs={**unit.programs, "update": update}, update_first=True,
                   run_tracks=False, extra_programs=unit.extra_programs + ("update",),
                   facts=unit.facts + (START_FACT,))


#: The run kinds whose measurements may be NaN by design: the sensors' run skips a row
#: holding a NaN (the sensor is silent), and the windowed run (fir) has finite memory: a
#: NaN in z(k) reaches only the N outputs whose window holds it.
NAN_ABSENT_KINDS = ("sensors", "windowed")


def checked_measurements(unit: Unit, model, spec: FilterSpec, options: SharedOptions) -> Unit:
    """``unit`` with each program that reads the measurements z (and the two-step map, z
    of the next step) checking every element is not NaN, unless a NaN means an absent
    measurement (the option ``missing``, or a run kind of :data:`NAN_ABSENT_KINDS`):
    without the check one NaN in z made every later state NaN, with status 0. One
    comparison per measurement per step; the checks come after those the program had,
    so their statuses keep their numbers."""
    if options.get("missing") or unit.run_kind in NAN_ABSENT_KINDS:
        return unit
    remedy = ("give the option missing for a NaN to mean an absent measurement"
              if spec.missing else f"filter {spec.name} takes no absent measurements")
    message = f"measurement is NaN ({remedy})"

    def checked(program):
        if "z" not in _input_names(program):
            return program
        size = program.port("z").size  # update1: one measurement, any of them
        names = model.measurements if size == model.m else ["one measurement"] * size
        return program.with_presence_checks("z", names, message)

    programs = {name: checked(program) for name, program in unit.programs.items()}
    lookahead = unit.lookahead
    if lookahead is not None:
        # the map reads z(k), which the step of its pass checks, and z(k+1): its checks of
        # z(k+1) share status 1, as the step's, which is the same status only while the
        # step has no check but these
        step = programs["step"]
        if any(isinstance(c, Check) and c.relation != PRESENT for c in step.body):
            raise ProgramError(f"unit {unit.prefix}: a two-step map beside a step with "
                               "checks of its own would number its checks apart")
        lookahead = lookahead.with_presence_checks(LOOKAHEAD_NEXT, model.measurements,
                                                   message)
    return replace(unit, programs=programs, lookahead=lookahead)


def make_sensor_unit(model, spec: FilterSpec, programs: dict, options: SharedOptions,
                     groups, thresholds: dict, predict_inputs, facts: list[str]) -> Unit:
    """The Unit of the run kind ``sensors``: ``programs`` are ``predict`` (taking the
    model's inputs ``predict_inputs``) and one ``update_<sensor>`` per sensor of ``groups``
    (derive.model.SensorGroup), gated where ``thresholds`` has a gate."""
    names = [u.name for u in model.inputs]
    slots = tuple(SensorSlot(g.name, g.m, tuple(names.index(u.name) for u in g.inputs),
                             thresholds[g.name] is not None, g.R_argument,
                             implicit=not model.sensors) for g in groups)
    header = []
    if model.kind == "linear":
        header.append(f"P0 pattern declared: {options.P0_pattern or model.P0_pattern}")
    header.append(accepted_P0(programs["predict"], "P"))
    fields = spec.unit_fields(run_tracks=False)
    fields.update(run_kind="sensors", run_tracks=False, extra_programs=(), about={
        "python": f"Run the {spec.title} over the steps: predict with u(k), then each "
                  "sensor's update in declaration order where its row is not NaN.",
        "c": f"Run the {spec.title} over steps steps (predict, then each sensor's update "
             "where its row is not NaN); Ps, nis_* and applied_* may be NULL."})
    return Unit(model=model.name, filter=spec.name, **fields, n=model.n, m=model.m,
                programs=programs, parameters=tuple(p.name for p in model.parameters),
                facts=tuple(header + facts), symbol_prefix=options.prefix, sensors=slots,
                n_inputs=len(names), nt=model.n_tangent,
                predict_inputs=tuple(names.index(u.name) for u in predict_inputs),
                update_first=options.get("start", "predict") == "update",
                precision=options.precision)


def _input_names(program) -> list[str]:
    return [] if program is None else [p.name for p in program.inputs]
