"""Wrap a filter's programs into the renderer's Unit, with the header facts it states.

The command that regenerates the files is the renderer's (derive.generation), not the
derivation's."""

from __future__ import annotations

import numpy as np

from ..discretize import METHODS
from ..options import SharedOptions
from ..program import ZERO, Check
from ..runs.unit import SensorSlot, Unit
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


def accepted_P0(program, port: str = "P") -> str:
    """The header line that says which P0 (and P) the code accepts: those zero outside the
    closed pattern, which the zero checks (``Program.require_zero``) of ``program`` on its
    input ``port`` enforce (the step's P, or an ``enter`` program's P0)."""
    n = program.port(port).shape[0]
    position = {program.element(port, i, j): (i, j) for i in range(n) for j in range(i, n)}
    outside = {position[c.value] for c in program.body
               if isinstance(c, Check) and c.relation == ZERO and c.value in position}
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
    option ``loglik`` the step's output ``ll`` is stored by run per step (``lls``;
    no run_tracks), with ``gradient`` also its last output ``dll`` (``dlls``).

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
    # the option loglik: the step's output ll, stored per step by run (not run_tracks)
    gradient = bool(options.get("gradient"))
    loglik = bool(options.get("loglik")) or gradient
    if loglik:
        facts.append(LOGLIK_FACT)
    if gradient:  # and its gradient dll, stored per step as dlls
        facts.append(GRADIENT_FACT)
    fields = spec.unit_fields(window=window, run_tracks=options.run_tracks and not loglik)
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
