"""The statements of the generated C run loops, built from a unit's lowered programs.

``run`` holds the step's statements with the state in local arrays (:func:`fused_body`),
or for a steady-state filter a two-step pass (:func:`two_step`, :func:`two_step_body`,
see :mod:`derive.emit.lookahead`); ``run_tracks`` advances :data:`LANES` tracks together,
each lane with its own temporaries, state and inputs (:func:`tracks_parts`).
"""

from __future__ import annotations

import re

from derive.emit import c_printer
from derive.emit.lookahead import ZNEXT, run_pass
from derive.emit.unit import Unit
from derive.lowering import LoweredProgram, lower_program
from derive.program import PARAMETER_PORT


def fused_body(unit: Unit, step_parts: dict) -> list[str]:
    """The step's statements for the run loop, reading per-step inputs at row k.

    The run loop keeps the state (x, P) and the step's outputs in local arrays indexed
    by constants, so the compiler holds them in registers: nothing is stored and
    reloaded between steps except the rows of xs and Ps written as results. The
    statements are the step's own (same operations, same count); only the per-step
    input names change (``z[`` reads ``zk[``, the row of step k; ``p[`` reads ``pk[``,
    ``p + k * p_stride``: one row for all steps or one per step).
    """
    lines = [line for line in step_parts["body"] if not line.startswith("(void)")]
    if lines and lines[-1] == "return 0;":
        lines = lines[:-1]
    rows = unit.step_inputs + ((PARAMETER_PORT,) if unit.parameters else ())
    out = []
    for line in lines:
        for name in rows:
            line = re.sub(rf"\b{name}\[", f"{name}k[", line)
        out.append(line)
    return out


#: Tracks that run_tracks advances together: independent dependency chains in one basic
#: block that the compiler interleaves, so one track's latency hides another's.
LANES = 4


def lane_lines(lines: list[str], unit: Unit, label: str) -> list[str]:
    """The fused step statements for one lane: its own temporaries, state and inputs."""
    out = []
    for line in lines:
        line = re.sub(r"\bt(\d+)\b", rf"t\1{label}", line)
        for port, new in unit.carried:
            line = re.sub(rf"\b{new}\[", f"{port}n{label}[", line)
        for port, _ in unit.carried:
            line = re.sub(rf"\b{port}\[", f"{port}{label}[", line)
        for name in unit.step_inputs:
            line = re.sub(rf"\b{name}k\[", f"{name}{label}[", line)
        out.append(line)
    return out


def tracks_parts(unit: Unit, fused: list[str], lanes: int, state: list[dict],
                 optional_stores: list[dict], lookahead: list[str] | None = None) -> dict:
    """Statements of run_tracks for ``lanes`` tracks at a time.

    Track-major arrays: track t's z, x0, P0, xs, Ps are laid out exactly as for run,
    one after the other, so every lane reads and writes its own sequential stream.
    ``state``: the carried state (derive.emit.render.carried_state); ``optional_stores``:
    run's outputs that may be NULL (each stores a carried output port).
    With ``lookahead`` (a steady-state two-step pass) each lane takes two steps per pass
    as run does, so every track's result is bitwise its run's.
    """
    n = unit.n
    by_output = {s["out"]: s["name"] for s in state}
    decl, load, body, store, pass_body, pass_store = [], [], [], [], [], []
    for lane in range(lanes):
        label = f"_l{lane}"  # never x0 or P0: those are the run's arguments
        track = f"(t + {lane})"
        for s in state:
            name, size = s["name"], s["size"]
            decl.append(f"double {name}{label}[{size}], {name}n{label}[{size}];")
            load += [f"{name}{label}[{i}] = {s['start']}[{track} * {size} + {i}];"
                     for i in range(size)]
        for name in unit.step_inputs:
            size = unit.step_input_size(name)
            decl.append(f"const double *{name}{label};")
            body.append(f"{name}{label} = {name} + ({track} * steps + k) * {size};")
        body += lane_lines(fused, unit, label)
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
        if lookahead:
            decl += [f"double xm{label}[{n}];", f"const double *{ZNEXT}{label};"]
            pass_body += [f"z{label} = z + ({track} * steps + k) * {unit.m};",
                          f"{ZNEXT}{label} = z + ({track} * steps + k + 1) * {unit.m};"]
            pass_body += [re.sub(r"\bx_mid\[", f"xm{label}[",
                                 re.sub(rf"\b{ZNEXT}k\[", f"{ZNEXT}{label}[", line))
                          for line in lane_lines(lookahead, unit, label)]
            pass_store += [f"xs[({track} * steps + k) * {n} + {i}] = xm{label}[{i}];"
                           for i in range(n)]
            pass_store += [f"xs[({track} * steps + k + 1) * {n} + {i}] = x{label}[{i}] = "
                           f"xn{label}[{i}];" for i in range(n)]
    if any(f"{PARAMETER_PORT}k[" in line for line in fused):  # the lanes share p's rows
        body.insert(0, f"const double *{PARAMETER_PORT}k = {PARAMETER_PORT} + k * p_stride;")
    return {"lanes": lanes, "decl": decl, "load": load, "body": body, "store": store,
            "pass_body": pass_body, "pass_store": pass_store}


def two_step(unit: Unit, use_fma: bool) -> LoweredProgram | None:
    """The lowered two-step map of a steady-state run loop, or None (see lookahead)."""
    program, steps = run_pass(unit)
    return lower_program(program, use_fma=use_fma) if steps == 2 else None


def two_step_body(fused: list[str], lowered: LoweredProgram, prefix: str) -> list[str]:
    """The pass's statements: the step's own (``fused``) writing x(k+1) to ``x_mid``,
    then the two-step map writing x(k+2) to ``x_new``, its temporaries numbered after
    the step's; rows k and k + 1 are read as ``zk`` and ``znk``."""
    first = 1 + max((int(m) for line in fused for m in re.findall(r"\bt(\d+)\b", line)),
                    default=-1)
    mid = [re.sub(r"\bx_new\[", "x_mid[", line) for line in fused]
    lines = [line for line in c_printer.function_parts(lowered, prefix)["body"]
             if not line.startswith("(void)") and line != "return 0;"]
    lines = [re.sub(r"\bt(\d+)\b", lambda m: f"t{int(m[1]) + first}", line) for line in lines]
    return mid + [re.sub(rf"\b{ZNEXT}\[", f"{ZNEXT}k[", re.sub(r"\bz\[", "zk[", line))
                  for line in lines]
