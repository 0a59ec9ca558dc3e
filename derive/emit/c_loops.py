"""The statements of the generated C run loops, built from a unit's lowered programs.

``run`` holds the step's statements with the state in local arrays (:func:`fused_body`),
or, for a unit with a two-step map (``Unit.lookahead``), a two-step pass
(:func:`two_step`, :func:`two_step_body`); ``run_tracks`` advances :data:`LANES` tracks
together, each lane with its own temporaries, state and inputs (:func:`tracks_parts`).

Every renaming is done on the lowered program (:meth:`LoweredProgram.renamed`) before it
is printed: the per-step rows (``z`` read as ``zk``), a lane's state and temporaries, the
second step's temporaries.  No printed line is edited.
"""

from __future__ import annotations

from derive.emit import c_printer
from derive.emit.unit import LOOKAHEAD_NEXT, Unit
from derive.lowering import LoweredProgram, lower_program
from derive.precision import precision
from derive.program import PARAMETER_PORT

#: Tracks that run_tracks advances together: independent dependency chains in one basic
#: block that the compiler interleaves, so one track's latency hides another's.
LANES = 4


def _rows(unit: Unit) -> tuple[str, ...]:
    """The step's inputs read one row per step: the per-step inputs, then ``p``."""
    return unit.step_inputs + ((PARAMETER_PORT,) if unit.parameters else ())


def _row(name: str) -> str:
    """The run loop's pointer to row k of a per-step input (``zk``)."""
    return f"{name}k"


def fused_body(unit: Unit, step: LoweredProgram) -> list[str]:
    """The step's statements for the run loop, reading per-step inputs at row k.

    The run loop keeps the state and the step's outputs in local arrays indexed by
    constants, so the compiler holds them in registers: nothing is stored and reloaded
    between steps except the rows of the stored results. The statements are the step's
    own (same operations, same count); only the per-step inputs are renamed (``z`` reads
    ``zk``, the row of step k; ``p`` reads ``pk``, ``p + k * p_stride``: one row for all
    steps or one per step).
    """
    return c_printer.statements(step.renamed({name: _row(name) for name in _rows(unit)}),
                                precision(unit.precision))


def lane_names(unit: Unit, label: str) -> dict[str, str]:
    """One lane's names: its own state (``x`` -> ``x_l0``, ``x_new`` -> ``xn_l0``) and
    per-step inputs (``z`` -> ``z_l0``); the parameters' row ``pk`` is shared."""
    names = {port: f"{port}{label}" for port, _ in unit.carried}
    names.update({new: f"{port}n{label}" for port, new in unit.carried})
    names.update({name: f"{name}{label}" for name in unit.step_inputs})
    if unit.parameters:
        names[PARAMETER_PORT] = _row(PARAMETER_PORT)
    return names


def _lane_temporary(label: str, offset: int = 0):
    return lambda name: f"t{int(name[1:]) + offset}{label}"


def tracks_parts(unit: Unit, step: LoweredProgram, lanes: int, state: list[dict],
                 optional_stores: list[dict], two: LoweredProgram | None = None) -> dict:
    """Statements of run_tracks for ``lanes`` tracks at a time.

    Track-major arrays: track t's z, x0, P0, xs, Ps are laid out exactly as for run,
    one after the other, so every lane reads and writes its own sequential stream.
    ``state``: the carried state (derive.emit.render.carried_state); ``optional_stores``:
    run's outputs that may be NULL (each stores a carried output port).
    With ``two`` (the lowered two-step map) each lane takes two steps per pass as run
    does, so every track's result is bitwise its run's.
    """
    n = unit.n
    real = precision(unit.precision)
    by_output = {s["out"]: s["name"] for s in state}
    decl, load, body, store, pass_body, pass_store = [], [], [], [], [], []
    for lane in range(lanes):
        label = f"_l{lane}"  # never x0 or P0: those are the run's arguments
        track = f"(t + {lane})"
        names = lane_names(unit, label)
        for s in state:
            name, size = s["name"], s["size"]
            decl.append(f"{real.c_type} {name}{label}[{size}], {name}n{label}[{size}];")
            load += [f"{name}{label}[{i}] = {s['start']}[{track} * {size} + {i}];"
                     for i in range(size)]
        for name in unit.step_inputs:
            size = unit.step_input_size(name)
            decl.append(f"const {real.c_type} *{name}{label};")
            body.append(f"{name}{label} = {name} + ({track} * steps + k) * {size};")
        body += c_printer.statements(step.renamed(names, _lane_temporary(label)), real)
        for s in state:
            name, size = s["name"], s["size"]
            store += [(f"{s['store']}[({track} * steps + k) * {size} + {i}] = " if s["store"]
                       else "") + f"{name}{label}[{i}] = {name}n{label}[{i}];"
                      for i in range(size)]
        for s in optional_stores:
            array, size, name = s["array"], s["size"], by_output[s["out"]]
            store += [f"if ({array}) {{"] + [
                f"    {array}[({track} * steps + k) * {size} + {i}] = {name}n{label}[{i}];"
                for i in range(size)] + ["}"]
        if two is not None:
            mid = f"xm{label}"
            decl += [f"{real.c_type} {mid}[{n}];",
                     f"const {real.c_type} *{LOOKAHEAD_NEXT}{label};"]
            pass_body += [f"z{label} = z + ({track} * steps + k) * {unit.m};",
                          f"{LOOKAHEAD_NEXT}{label} = z + ({track} * steps + k + 1) * {unit.m};"]
            pass_body += c_printer.statements(
                step.renamed({**names, "x_new": mid}, _lane_temporary(label)), real)
            pass_body += c_printer.statements(two.renamed(
                {**names, LOOKAHEAD_NEXT: f"{LOOKAHEAD_NEXT}{label}"},
                _lane_temporary(label, step.temporaries())), real)
            pass_store += [f"xs[({track} * steps + k) * {n} + {i}] = {mid}[{i}];"
                           for i in range(n)]
            pass_store += [f"xs[({track} * steps + k + 1) * {n} + {i}] = x{label}[{i}] = "
                           f"xn{label}[{i}];" for i in range(n)]
    if unit.parameters and PARAMETER_PORT in step.used_inputs():  # the lanes share p's rows
        body.insert(0, f"const {real.c_type} *{_row(PARAMETER_PORT)} = {PARAMETER_PORT} + k * "
                       "p_stride;")
    return {"lanes": lanes, "decl": decl, "load": load, "body": body, "store": store,
            "pass_body": pass_body, "pass_store": pass_store}


def two_step(unit: Unit, use_fma: bool) -> LoweredProgram | None:
    """The lowered two-step map of the unit's run loop, or None (no lookahead)."""
    if unit.lookahead is None:
        return None
    return lower_program(unit.lookahead, use_fma=use_fma,
                         state_ports=tuple(port for port, _ in unit.carried))


def two_step_body(unit: Unit, step: LoweredProgram, two: LoweredProgram) -> list[str]:
    """The pass's statements: the step's own writing x(k+1) to ``x_mid``, then the
    two-step map writing x(k+2) to ``x_new``, its temporaries numbered after the step's;
    rows k and k + 1 are read as ``zk`` and ``znk``."""
    rows = {name: _row(name) for name in _rows(unit)}
    real = precision(unit.precision)
    mid = c_printer.statements(step.renamed({**rows, "x_new": "x_mid"}), real)
    first = step.temporaries()
    return mid + c_printer.statements(two.renamed(
        {"z": _row("z"), LOOKAHEAD_NEXT: _row(LOOKAHEAD_NEXT)},
        lambda name: f"t{int(name[1:]) + first}"), real)
