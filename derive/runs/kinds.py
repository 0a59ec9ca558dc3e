"""One builder per run kind: the :class:`~derive.runs.loops.Run` of a unit, in no
language (the printers: :mod:`derive.emit.c_run`, :mod:`derive.emit.python_run`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from math import prod

from derive.lowering import LoweredProgram, lower_program
from derive.program import PARAMETER_PORT, Program
from derive.runs.loops import (
    AfterFirst,
    AnySteps,
    Call,
    Carried,
    Columns,
    Copy,
    Output,
    Present,
    Record,
    Row,
    Run,
    State,
    Steps,
    Store,
    Window,
    Work,
)
from derive.runs.unit import LOOKAHEAD_NEXT, Unit
from derive.runs.unit import sizes as run_sizes


def _parameters(unit: Unit) -> tuple:
    """p bound to its row k (run's p: one row for every step, or one per step)."""
    return ((PARAMETER_PORT, Row(PARAMETER_PORT, len(unit.parameters))),) \
        if unit.parameters else ()


def reads_whole(lowered: Mapping[str, LoweredProgram]) -> bool:
    """True when a program reads its symmetric P below the diagonal (vector rows): run then
    mirrors P0's upper triangle, so that P0 is read as everywhere else (upper triangle)."""
    return any(lp.reads_below_diagonal(port) for lp in lowered.values()
               for port in lp.inputs if port.symmetric)


def sensors(unit: Unit, lowered: Mapping[str, LoweredProgram]) -> Run:
    """The run kind ``sensors``: per step k, ``predict`` with u(k) (not at k = 0 with
    update-first), then each sensor's ``update_<sensor>`` in declaration order where its
    row k holds no NaN; x and P stored after the step and, for a gated sensor, its NIS
    (NaN where absent) and whether the update applied (1, else 0). The loop calls the
    unit's own functions, whose counts the header states; it adds no arithmetic."""
    n, nt = unit.n, unit.nt  # x: n, P: nt x nt (the tangent space's, with manifold states)
    nn = nt * nt
    p = _parameters(unit)
    u = ((("u", Columns("u", unit.predict_inputs, unit.n_inputs)),)
         if unit.predict_inputs else ())
    predict = Call("predict", u + p, carry=True)
    body = [AfterFirst((predict,)) if unit.update_first else predict]
    records = []
    for s in unit.sensors:
        args = [("z", Row(s.z_c, s.m))]
        if s.R_argument:
            args.append(("R", Row(f"R_{s.name}", s.m * s.m, side=s.m)))
        if s.inputs:
            args.append(("u", Columns("u", s.inputs, unit.n_inputs)))
        inner = [Call(f"update_{s.name}", tuple(args) + p, carry=True)]
        missing = ()
        if s.gated:
            inner += [Record(f"nis_{s.name}", "nis"), Record(f"applied_{s.name}", "applied")]
            missing = (Record(f"nis_{s.name}", fill=True),
                       Record(f"applied_{s.name}", fill=True))
            records += [Output(f"nis_{s.name}", "nan"), Output(f"applied_{s.name}", "zero")]
        body.append(Present(s.z_c, s.m, s.name, tuple(inner), missing))
    body += [Store("xs", "x", n), Store("Ps", "P", nn, optional=True)]
    returns = [("xs", (n,)), ("Ps", (nt, nt))] + [(r.array, ()) for r in records]
    return Run((State("x", n, "x0"), State("P", nn, "P0", whole=reads_whole(lowered), side=nt)),
               (Steps(tuple(body)),), tuple(records), tuple(returns))


def smoother(unit: Unit, lowered: Mapping[str, LoweredProgram]) -> Run:
    """The run kind ``smoother`` (a fixed-interval smoother): forward, ``step`` on each row of z
    from the filtered state of the row before (x0, P0 first), its outputs kept in row k of
    the work array; the last row's filtered state is the smoothed one there; backward, from
    row steps - 2 down to 0, ``backward`` on a row's filtered state, the next row's
    prediction and the next smoothed state (p of the next row: its F predicted it)."""
    n, nn = unit.n, unit.n * unit.n
    step = unit.programs["step"]
    array, held = unit.run.work[0]
    work = Work(array, tuple((port, step.port(port).size) for port in held),
                note="per step: x(k/k), P(k/k), x(k/k-1), P(k/k-1)")
    rows = tuple((name, Row(name, unit.step_input_size(name))) for name in unit.step_inputs)
    p = _parameters(unit)
    forward = Call("step", (("x", Carried("x", work.slot("x_new", "k - 1"), "x0")),
                            ("P", Carried("P", work.slot("P_new", "k - 1"), "P0")))
                   + rows + p,
                   into=tuple((port, work.slot(port, "k"), port.replace("_new", ""))
                              for port, _ in work.ports))
    last = AnySteps((Copy(Row("xs", n, "steps - 1"), work.slot("x_new", "steps - 1"),
                          "x_smooth"),
                     Copy(Row("Ps", nn, "steps - 1"), work.slot("P_new", "steps - 1"),
                          "P_smooth")), note="the last step: smoothed = filtered")
    next_p = tuple((port, Row(source.array, source.size, "k + 1")) for port, source in p)
    backward = Call("backward", (("x", work.slot("x_new", "k")), ("P", work.slot("P_new", "k")),
                                 ("x_pred", work.slot("x_pred", "k + 1")),
                                 ("P_pred", work.slot("P_pred", "k + 1")),
                                 ("x_smooth_next", Carried("x_smooth", Row("xs", n, "k + 1"))),
                                 ("P_smooth_next", Carried("P_smooth", Row("Ps", nn, "k + 1"))))
                    + next_p,
                    into=(("x_smooth", Row("xs", n), "x_smooth"),
                          ("P_smooth", Row("Ps", nn), "P_smooth")))
    loops = (*update_first(unit, Steps((forward,), note="forward: the Kalman filter; row k of "
                                                       "work gets x(k+1/k+1), P(k+1/k+1) and "
                                                       "the\nprediction x(k+1/k), P(k+1/k)")),
             last,
             Steps((backward,), down=2, note="backward, rows steps - 2 down to 0: row j of "
                                              "xs, Ps from row j + 1"))
    return Run((State("x", n, "x0"), State("P", nn, "P0", side=n)), loops,
               returns=(("xs", (n,)), ("Ps", (n, n))), work=work)


def windowed(unit: Unit, lowered: Mapping[str, LoweredProgram]) -> Run:
    """The run kind ``windowed``: per step k, ``step`` on the last N rows of z (newest
    first, zero before the first), its x_new stored as row k of xs."""
    n = unit.n
    step = Call("step", (("zw", Window("z", unit.m, unit.window)),) + _parameters(unit),
                into=(("x_new", Row("xs", n), "x"),))
    return Run((), (Steps((step,)),), returns=(("xs", (n,)),))


def stepping(unit: Unit, lowered: Mapping[str, LoweredProgram]) -> Run:
    """The run kinds whose step carries a state (``timevarying``, ``steady``,
    ``predictor``, ``filter_predict``): the state starts from run's start arguments in
    order (from init(x0) for a predictor; from the enter program where the unit has one),
    then per step k the step body on the state and row k of each per-step input, and row
    k of each stored output (where no carried port holds it: by the store program, or
    the step's own output, e.g. its prediction)."""
    ports = {p.name: p for p in lowered["step"].inputs}
    sizes = run_sizes(unit)
    starts = list(unit.run.start) + [("", ())] * len(unit.carried)
    states = tuple(State(port, ports[port].size, starts[i][0], out=out,
                         side=sizes[starts[i][1][0]] if len(starts[i][1]) > 1 else 0)
                   for i, (port, out) in enumerate(unit.carried))
    p = _parameters(unit)
    rows = tuple((name, Row(name, unit.step_input_size(name))) for name in unit.step_inputs)
    body = [Call("step", rows + p, carry=True, body=True)]
    by_output = {s.new: s for s in states}
    returns = []
    for array, out, dims, optional in unit.stores:  # the kind's, then the unit's own
        size = prod(sizes[d] for d in dims)
        if out in by_output:
            body.append(Store(array, by_output[out].name, size, optional))
            returns.append((array, ports[by_output[out].name].shape))
        elif out in {p.name for p in lowered["step"].outputs}:
            # an output of the step that no carried port holds (a prediction, ll)
            body.append(Store(array, out, size, optional))
            returns.append((array, tuple(sizes[d] for d in dims)))
        else:  # from the carried state, by the store program
            body.append(Store(array, "", size, optional, program="store"))
            returns.append((array, lowered["store"].outputs[0].shape))
    enter = None
    if "init" in lowered:
        first = ((PARAMETER_PORT, Row(PARAMETER_PORT, len(unit.parameters), "0")),) \
            if unit.parameters else ()
        enter = Call("init", (("x0", "x0"),) + first, into=(("x_new", Row("x_init", unit.n, ""),
                                                             "x"),))
    elif "enter" in lowered:
        enter = Call("enter", tuple((name, Row(name, prod(sizes[d] for d in dims), "",
                                               side=len(dims) > 1))
                                    for name, dims in unit.run.start))
    loop = Steps(tuple(body), note="the step body on local arrays: inlined, it holds the "
                                   "state in registers")
    return Run(states, update_first(unit, loop), returns=tuple(returns), enter=enter)


def update_first(unit: Unit, loop: Steps) -> tuple[Steps, ...]:
    """``loop``, or with update-first (a step that fuses the prediction and the update) the
    loop at step 0 alone with the unit's ``update`` called instead of ``step``, then the
    loop from step 1."""
    if not unit.update_first:
        return (loop,)
    first = tuple(replace(c, program="update") if isinstance(c, Call) and c.program == "step"
                  else c for c in loop.body)
    return (replace(loop, body=first, first=True,
                    note="update-first: step 0 updates x0, P0 with its measurements, without "
                         "a prediction"), replace(loop, start=1))


def two_steps(run: Run, unit: Unit) -> Run:
    """The pass of the two-step map over a stepping run (a unit with ``Unit.lookahead``):
    two steps a pass, x(k+1) by the step into x_mid, x(k+2) from x(k) by the map, rows k
    and k + 1 stored; an odd last step by the loop as it was."""
    (loop,) = run.loops
    n, m = unit.n, unit.m
    step = next(c for c in loop.body if isinstance(c, Call))
    pair = Steps((Call("step", step.args, into=(("x_new", Row("x_mid", n, ""), "x_mid"),),
                       body=True),
                  Call("pass", (("z", Row("z", m)), (LOOKAHEAD_NEXT, Row("z", m, "k + 1"))),
                       carry=True, body=True),
                  Store("xs", "x_mid", n), Store("xs", "x", n, row="k + 1")),
                 by=2, note="two steps per pass: x(k+1) by the step, x(k+2) from x(k) by the "
                            "two-step map;\nonly x(k+2) is carried, so the chain from pass to "
                            "pass is one step deep")
    return replace(run, loops=(pair, replace(loop, rest=True, note="an odd last step")))


def two_step_map(unit: Unit, use_fma: bool) -> LoweredProgram | None:
    """The lowered two-step map of the unit's run loop, or None (no lookahead)."""
    if unit.lookahead is None:
        return None
    return lower_program(unit.lookahead, use_fma=use_fma,
                         state_ports=tuple(port for port, _ in unit.carried))


def carried_pass(unit: Unit) -> tuple[Program, int]:
    """(program, steps) of the carried chain of one pass of the C run loop of ``unit``: its
    two-step map (x(k+1) beside it is not carried), else the step itself."""
    if unit.lookahead is not None:
        return unit.lookahead, 2
    return unit.programs["step"], 1


#: The builder of each run kind whose loop is built as data.
BUILDERS = {"sensors": sensors, "smoother": smoother, "windowed": windowed,
            "timevarying": stepping, "steady": stepping, "predictor": stepping,
            "filter_predict": stepping}
