"""A :class:`~derive.runs.loops.Run` printed as the body of Python ``run`` (after its
prologue and ``xs = np.empty(...)``): the loop works on every track at once, each array
with the tracks as trailing axes; where only some tracks hold a measurement, the others
keep their state by a mask (:func:`numpy.where`)."""

from __future__ import annotations

from math import prod

from derive.lowering import LoweredProgram
from derive.program import PARAMETER_PORT
from derive.runs.loops import (
    AfterFirst,
    AnySteps,
    Call,
    Carried,
    Columns,
    Copy,
    Node,
    Present,
    Record,
    Row,
    Run,
    State,
    Steps,
    Store,
    Window,
    walk,
)

#: The names run's prologue gives p as one row per step, and its first row
#: (derive.emit.render).
PARAMETER_ROWS, PARAMETER_START = "p_rows", "p_start"
_FILL = {"nan": "np.nan", "zero": "0.0"}


class _Printer:
    def __init__(self, run: Run, lowered: dict[str, LoweredProgram], names: dict[str, str],
                 functions: dict[str, str]):
        self.run, self.lowered, self.names, self.functions = run, lowered, names, functions
        self.fill = {r.array: r.fill for r in run.records}

    def source(self, source) -> str:
        if isinstance(source, str):
            return source
        if isinstance(source, Carried):
            return source.name
        if isinstance(source, Window):
            return "zw"
        work = self.run.work
        if work is not None and source.array == work.array:  # a list of rows of outputs
            index = [offset for offset in _offsets(work)].index(source.offset)
            row = "-1" if source.row == "steps - 1" else source.row
            return f"{work.array}[{row}][{index}]"
        if isinstance(source, Columns):
            name = self.names[source.array]
            return (f"{name}[k]" if source.whole
                    else f"{name}[k, [{', '.join(str(c) for c in source.columns)}]]")
        if source.array == PARAMETER_PORT:
            return PARAMETER_START if source.row == "0" else f"{PARAMETER_ROWS}[{source.row}]"
        name = self.names.get(source.array, source.array)
        if source.row == "":  # the argument itself, a matrix flat
            return f"{name}.reshape(({source.size},) + {name}.shape[2:])" if source.side else name
        if source.side:  # a matrix a row: flat, as the program takes it
            return f"{name}[{source.row}].reshape(({source.size},) + {name}.shape[3:])"
        return f"{name}[{source.row}]"

    def checked(self, loop: Steps) -> bool:
        """True when a program the loop calls has a check that raises NumericalError (the
        loop then names the step of a failure, as the one-track branch does)."""
        return any(isinstance(node, Call) and any(not c.is_pattern
                                                  for c in self.lowered[node.program].checks)
                   for node in walk(loop.body))

    def call(self, call: Call, outputs: str) -> str:
        lp = self.lowered[call.program]
        bound = dict(call.args)
        args = ", ".join(self.source(bound.get(p.name, p.name)) for p in lp.inputs)
        return f"{outputs} = {self.functions.get(call.program, call.program)}({args})"

    def outputs(self, call: Call, carried: str) -> str:
        """The names a call's outputs are assigned to: the state a row written becomes, the
        carried state's ``carried`` (``x_up``, or ``x`` itself), the other ports by their
        names."""
        states = {f"{s.name}_new": s.name for s in self.run.states} if call.carry else {}
        into = {port: name for port, _, name in call.into}
        return ", ".join(into[p.name] if p.name in into else
                         carried.format(states[p.name]) if p.name in states else p.name
                         for p in self.lowered[call.program].outputs)

    def store(self, target: Row, name: str, indent: str) -> list[str]:
        return [f"{indent}for i in range({target.size}):",
                f"{indent}    {self.names.get(target.array, target.array)}[{target.row}, i] = "
                f"{name}[i]"]

    def written(self, call: Call, indent: str) -> list[str]:
        """The rows a call writes: a work row keeps the outputs (appended), another row
        stores its state."""
        work = self.run.work.array if self.run.work is not None else None
        kept = [name for _, row, name in call.into if row.array == work]
        lines = [f"{indent}{work}.append(({', '.join(kept)}))"] if kept else []
        for _, row, name in call.into:
            if row.array != work:
                lines += self.store(row, name, indent)
        return lines

    def nodes(self, nodes: tuple[Node, ...], indent: str) -> list[str]:
        lines = []
        for node in nodes:
            if isinstance(node, Call):
                for _, w in node.args:
                    if isinstance(w, Window):
                        z = self.names[w.array]
                        lines.append(f"{indent}zw = padded[k:k + {w.window}][::-1].reshape(("
                                     f"{w.window * w.size},) + {z}.shape[2:])")
                lines.append(indent + self.call(node, self.outputs(node, "{}")))
                lines += self.written(node, indent)
            elif isinstance(node, AnySteps):
                copies = [c for c in node.body if isinstance(c, Copy)]
                lines += [f"{indent}if steps:  # {node.note}",
                          f"{indent}    {', '.join(c.name for c in copies)} = "
                          f"{', '.join(self.source(c.source) for c in copies)}"]
                for c in copies:
                    lines += self.store(c.target, c.name, indent + "    ")
            elif isinstance(node, AfterFirst):
                lines.append(f"{indent}if k:  # update-first: step 0 has no prediction")
                lines += self.nodes(node.body, indent + "    ")
            elif isinstance(node, Present):
                lines += self.present(node, indent)
            elif isinstance(node, Store) and node.program:  # from the carried state
                value = f"{node.array}_k"
                args = ", ".join(p.name for p in self.lowered[node.program].inputs)
                lines += [f"{indent}{value} = "
                          f"{self.functions.get(node.program, node.program)}({args})",
                          f"{indent}for i in range({node.size}):",
                          f"{indent}    {self.names[node.array]}[k, i] = {value}[i]"]
            elif isinstance(node, Store):
                lines += [f"{indent}for i in range({node.size}):",
                          f"{indent}    {self.names[node.array]}[k, i] = {node.state}[i]"]
            elif isinstance(node, Steps):
                lines.append(f"{indent}for k in range(steps - {node.down}, -1, -1):"
                             if node.down else
                             f"{indent}for k in range(min(steps, 1)):  # update-first: step 0"
                             if node.first else
                             f"{indent}for k in range({node.start}, steps):" if node.start
                             else f"{indent}for k in range(steps):")
                if not self.checked(node):
                    lines += self.nodes(node.body, indent + "    ")
                    continue
                lines += ([f"{indent}    try:"] + self.nodes(node.body, indent + "        ")
                          + [f"{indent}    except NumericalError as failure:  # name the step",
                             f'{indent}        raise type(failure)(f"step {{k}}: {{failure}}")'
                             " from None"])
            else:
                raise TypeError(f"no Python for {node!r}")
        return lines

    def present(self, node: Present, indent: str) -> list[str]:
        """The tracks with row k of the measurement: the call on all of them, its results
        kept where the row is present (every track when all hold it)."""
        inner = indent + "    "
        z = self.source(Row(node.array, node.size))
        lines = [f"{indent}present = ~np.isnan({z}).any(axis=0)", f"{indent}if np.any(present):"]
        for sub in node.body:
            if isinstance(sub, Call):
                states = [s.name for s in self.run.states]
                lines += [inner + self.call(sub, self.outputs(sub, "{}_up")),
                          f"{inner}if np.all(present):",
                          f"{inner}    {', '.join(states)} = "
                          f"{', '.join(f'{s}_up' for s in states)}",
                          f"{inner}else:  # tracks without this measurement keep "
                          f"{' and '.join(states)}"]
                lines += [f"{inner}    {s} = [np.where(present, a, b) for a, b in "
                          f"zip({s}_up, {s})]" for s in states]
            elif isinstance(sub, Record):
                lines.append(f"{inner}{sub.array}[k] = np.where(present, {sub.value}[0], "
                             f"{_FILL[self.fill[sub.array]]})")
            else:
                raise TypeError(f"no Python for {sub!r} where a measurement is present")
        return lines

    def start(self, state: State) -> list[str]:
        n, size = state.side, state.size
        if not n:
            return [f"{state.name} = {state.start}"]
        if not state.whole:
            return [f"{state.name} = {state.start}.reshape(({size},) + {state.start}.shape[2:])"]
        # the upper triangle, mirrored: the programs read the matrix whole
        m = f"{state.start}m"
        return [f"{m} = {state.start}.reshape(({n}, {n}) + {state.start}.shape[2:])",
                f"upper = np.triu(np.ones(({n}, {n}), dtype=bool)).reshape(({n}, {n}) + "
                f"(1,) * ({m}.ndim - 2))",
                f"{state.name} = np.where(upper, {m}, {m}.swapaxes(0, 1)).reshape(({size},) "
                f"+ {m}.shape[2:])"]


def run_lines(run: Run, lowered: dict[str, LoweredProgram], names: dict[str, str],
              functions: dict[str, str] | None = None, single: tuple[str, ...] = ()
              ) -> list[str]:
    """The body of Python run after its prologue (and ``xs = np.empty(...)`` unless
    ``single``); ``names``: run's arrays by their C names (run's Python argument names:
    ``us`` for ``u``); ``functions``: the function a program's call calls, where not its
    own (the step without its pattern check); ``single``: the one-track branch
    (derive.emit.python_loop), which returns before xs is allocated."""
    printer = _Printer(run, lowered, names, functions or {})
    recorded = {r.array for r in run.records}
    lines = []
    if single:
        lines.append("if not track:  # one track: the step's statements inline, on Python "
                     "floats")
        if run.enter is not None and run.enter.program == "init":
            lines.append("    " + printer.call(run.enter, "x_start").replace(
                "x_start = ", "x_start = np.asarray(", 1) + ", dtype=float)")
        lines += list(single)
        lines.append(f"xs = np.empty((steps, {prod(run.returns[0][1])}) + track)")
    lines += [f"{name} = np.empty((steps, {prod(shape)}) + track)" for name, shape in run.returns
              if name != "xs" and name not in recorded]
    lines += [f"{r.array} = np.full((steps,) + track, np.nan)" if r.fill == "nan"
              else f"{r.array} = np.zeros((steps,) + track)" for r in run.records]
    if run.enter is not None:
        lines.append(printer.call(run.enter, printer.outputs(run.enter, "{}")
                                  if run.enter.into else
                                  ", ".join(state.name for state in run.states)))
    else:
        for state in run.states:
            lines += printer.start(state)
    if run.work is not None:
        lines.append(f"{run.work.array} = []  # {run.work.note}")
    for w in {s for n in walk(run.loops) if isinstance(n, Call) for _, s in n.args
              if isinstance(s, Window)}:  # the rows before the first are zero
        z = names[w.array]
        lines.append(f"padded = np.concatenate([np.zeros(({w.window - 1}, {w.size}) + "
                     f"{z}.shape[2:]), {z}])")
    lines += printer.nodes(run.loops, "")
    returned = [name if len(shape) == 1 or name in recorded else
                f"{name}.reshape((steps, {', '.join(str(d) for d in shape)}) + track)"
                for name, shape in run.returns]
    return lines + [f"return {', '.join(returned)}"]


def _offsets(work) -> list[int]:
    offsets, at = [], 0
    for _, size in work.ports:
        offsets.append(at)
        at += size
    return offsets
