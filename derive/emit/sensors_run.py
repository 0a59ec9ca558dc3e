"""The run loop of the run kind ``sensors``, as lines of Python and C.

Per step k: ``predict`` with u(k) (skipped at k = 0 with update-first), then each
sensor's ``update_<sensor>`` in declaration order when its row k of ``z_<sensor>`` holds
no NaN (a row with a NaN: no measurement of that sensor at that step); run stores x and P
after the step and, for a gated sensor, its NIS (NaN where absent) and whether the update
was applied (1, else 0). The loop calls the unit's own functions, whose counts the header
states; it adds no arithmetic.
"""

from __future__ import annotations

from derive.emit import c_printer
from derive.emit.python_printer import flat_name
from derive.lowering import LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.runs.unit import Unit

PARAMETER_ROWS = "p_rows"
"""The name run's prologue gives p as one row per step (derive.emit.render)."""


def _columns(columns: tuple[int, ...], n_inputs: int) -> str:
    """The Python index of run's u row k for ``columns`` (all of them: the row itself)."""
    if list(columns) == list(range(n_inputs)):
        return "us[k]"
    return f"us[k, [{', '.join(str(c) for c in columns)}]]"


def python_loop(unit: Unit, lowered: dict[str, LoweredProgram]) -> list[str]:
    """The body of Python run after its prologue and ``xs = np.empty(...)``."""
    n, nt, nn = unit.n, unit.nt, unit.nt * unit.nt  # x: n, P: nt x nt
    p_arg = f", {PARAMETER_ROWS}[k]" if unit.parameters else ""
    lines = [f"Ps = np.empty((steps, {nn}) + track)"]
    for s in unit.sensors:
        if s.gated:
            lines += [f"nis_{s.name} = np.full((steps,) + track, np.nan)",
                      f"applied_{s.name} = np.zeros((steps,) + track)"]
    lines.append("x = x0")
    if reads_whole(lowered):  # P0's upper triangle, mirrored: the programs read P whole
        lines += [f"P0m = P0.reshape(({nt}, {nt}) + P0.shape[2:])",
                  f"upper = np.triu(np.ones(({nt}, {nt}), dtype=bool))"
                  ".reshape((n_, n_) + (1,) * (P0m.ndim - 2))".replace("n_", str(nt)),
                  f"P = np.where(upper, P0m, P0m.swapaxes(0, 1)).reshape(({nn},) + "
                  "P0m.shape[2:])"]
    else:
        lines.append(f"P = P0.reshape(({nn},) + P0.shape[2:])")
    lines.append("for k in range(steps):")
    u_predict = (f", {_columns(unit.predict_inputs, unit.n_inputs)}"
                 if unit.predict_inputs else "")
    calls = {name: flat_name(lp) for name, lp in lowered.items()}
    predict = f"x, P = {calls['predict']}(x, P{u_predict}{p_arg})"
    if unit.update_first:
        lines += ["    if k:  # update-first: step 0 has no prediction", f"        {predict}"]
    else:
        lines.append(f"    {predict}")
    for s in unit.sensors:
        z = f"{s.z_py}[k]"
        u = f", {_columns(s.inputs, unit.n_inputs)}" if s.inputs else ""
        if s.R_argument:  # R before u, as the update takes them
            u = f", R_{s.name}[k].reshape(({s.m * s.m},) + R_{s.name}.shape[3:])" + u
        outs = "x_up, P_up" + (", nis, applied" if s.gated else "")
        lines += [f"    present = ~np.isnan({z}).any(axis=0)",
                  "    if np.any(present):",
                  f"        {outs} = {calls['update_' + s.name]}(x, P, {z}{u}{p_arg})",
                  "        if np.all(present):",
                  "            x, P = x_up, P_up",
                  "        else:  # tracks without this measurement keep x and P",
                  "            x = [np.where(present, a, b) for a, b in zip(x_up, x)]",
                  "            P = [np.where(present, a, b) for a, b in zip(P_up, P)]"]
        if s.gated:
            lines += [f"        nis_{s.name}[k] = np.where(present, nis[0], np.nan)",
                      f"        applied_{s.name}[k] = np.where(present, applied[0], 0.0)"]
    lines += [f"    for i in range({n}):", "        xs[k, i] = x[i]",
              f"    for i in range({nn}):", "        Ps[k, i] = P[i]"]
    outputs = ["xs", f"Ps.reshape((steps, {nt}, {nt}) + track)"]
    for s in unit.sensors:
        if s.gated:
            outputs += [f"nis_{s.name}", f"applied_{s.name}"]
    return lines + [f"return {', '.join(outputs)}"]


def reads_whole(lowered: dict[str, LoweredProgram]) -> bool:
    """True when a program reads its symmetric P below the diagonal (vector rows): run then
    mirrors P0's upper triangle, so that P0 is read as everywhere else (upper triangle)."""
    return any(lp.reads_below_diagonal(port) for lp in lowered.values()
               for port in lp.inputs if port.symmetric)


def _call(prefix: str, lp: LoweredProgram, names: dict[str, str]) -> list[str]:
    args = ", ".join(names.get(name, name) for name in c_printer.argument_order(lp))
    if not lp.has_checks:
        return [f"{prefix}_{lp.name}({args});"]
    return [f"status = {prefix}_{lp.name}({args});", "if (status) {", "    return status;",
            "}"]


def _gather(target: str, columns: tuple[int, ...]) -> list[str]:
    """``target[j] = uk[column j];`` for the columns of run's u a function takes."""
    return [f"{target}[{j}] = uk[{c}];" for j, c in enumerate(columns)]


def c_run_body(unit: Unit, lowered: dict[str, LoweredProgram],
               real: Precision = DOUBLE) -> list[str]:
    """The statements of C run (unindented; the template indents them), in the
    precision's element type."""
    t = real.c_type
    n, nt, prefix = unit.n, unit.nt, unit.prefix  # x: n, P: nt x nt
    nn = nt * nt
    gated = any(s.gated for s in unit.sensors)
    status = any(lp.has_checks for lp in lowered.values())
    all_columns = tuple(range(unit.n_inputs))
    lines = [f"{t} x[{n}];", f"{t} P[{nn}];", f"{t} x_new[{n}];",
             f"{t} P_new[{nn}];"]
    if gated:
        lines += [f"{t} nis[1];", f"{t} applied[1];"]
    subsets = {}  # a function's u when it takes some of run's u columns, not all in order
    if unit.predict_inputs and unit.predict_inputs != all_columns:
        subsets["predict"] = ("u_predict", unit.predict_inputs)
    for s in unit.sensors:
        if s.inputs and s.inputs != all_columns:
            # named for the function, not the sensor: a sensor named predict would
            # otherwise declare predict's u_predict a second time
            subsets[f"update_{s.name}"] = (f"u_update_{s.name}", s.inputs)
    lines += [f"{t} {name}[{len(cols)}];" for name, cols in subsets.values()]
    lines += ["size_t k;", "size_t i;"] + (["int status;"] if status else [])
    used_u = bool(unit.predict_inputs) or any(s.inputs for s in unit.sensors)
    if unit.n_inputs and not used_u:
        lines.append("(void)u;")
    lines += [f"for (i = 0; i < {n}; ++i) {{", "    x[i] = x0[i];", "}"]
    if reads_whole(lowered):  # P0's upper triangle, mirrored: the programs read P whole
        lines += [f"for (i = 0; i < {nn}; ++i) {{",
                  f"    P[i] = i / {nt} <= i % {nt} ? P0[i] : P0[(i % {nt}) * {nt} + i / {nt}];",
                  "}"]
    else:
        lines += [f"for (i = 0; i < {nn}; ++i) {{", "    P[i] = P0[i];", "}"]
    lines.append("for (k = 0; k < steps; ++k) {")
    body = []
    if used_u:
        body.append(f"const {t} *uk = u + k * {unit.n_inputs};")
    if unit.parameters:
        body.append(f"const {t} *{PARAMETER_PORT}k = {PARAMETER_PORT} + k * p_stride;")
    copy = [f"for (i = 0; i < {n}; ++i) {{", "    x[i] = x_new[i];", "}",
            f"for (i = 0; i < {nn}; ++i) {{", "    P[i] = P_new[i];", "}"]
    rows = {PARAMETER_PORT: f"{PARAMETER_PORT}k"}
    u_name, cols = subsets.get("predict", ("uk", ()))
    predict = (_gather(u_name, cols)
               + _call(prefix, lowered["predict"], {**rows, "u": u_name}) + copy)
    if unit.update_first:
        body += ["if (k > 0) { /* update-first: step 0 has no prediction */"]
        body += ["    " + line for line in predict] + ["}"]
    else:
        body += predict
    for s in unit.sensors:
        name = f"update_{s.name}"
        u_name, cols = subsets.get(name, ("uk", ()))
        test = " && ".join(f"zk[{i}] == zk[{i}]" for i in range(s.m))
        given = {"R": f"R_{s.name} + k * {s.m * s.m}"} if s.R_argument else {}
        inner = (_gather(u_name, cols)
                 + _call(prefix, lowered[name], {**rows, **given, "u": u_name, "z": "zk"})
                 + copy)
        if s.gated:
            inner += [f"if (nis_{s.name}) {{", f"    nis_{s.name}[k] = nis[0];", "}",
                      f"if (applied_{s.name}) {{", f"    applied_{s.name}[k] = applied[0];",
                      "}"]
        body += ["{", f"    const {t} *zk = {s.z_c} + k * {s.m};",
                 f"    if ({test}) {{ /* a NaN: no {s.name} measurement at step k */"]
        body += ["        " + line for line in inner]
        if s.gated:
            body += ["    } else {", f"        if (nis_{s.name}) {{",
                     f"            nis_{s.name}[k] = NAN;", "        }",
                     f"        if (applied_{s.name}) {{",
                     f"            applied_{s.name}[k] = {real.zero()};",
                     "        }"]
        body += ["    }", "}"]
    body += [f"for (i = 0; i < {n}; ++i) {{", f"    xs[k * {n} + i] = x[i];", "}",
             "if (Ps) {", f"    for (i = 0; i < {nn}; ++i) {{",
             f"        Ps[k * {nn} + i] = P[i];", "    }", "}"]
    lines += ["    " + line for line in body] + ["}"]
    return lines + (["return 0;"] if status else [])


__all__ = ["c_run_body", "python_loop"]
