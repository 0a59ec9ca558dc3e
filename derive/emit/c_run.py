"""A :class:`~derive.runs.loops.Run` printed as the statements of C ``run``: one track,
the carried state in local arrays, each program called on them and its outputs copied
back; a guard is a branch."""

from __future__ import annotations

from derive.emit.c_loops import (
    P_STRIDE,
    body_name,
    call_lines,
    checked_call,
    loop_head,
    row_pointer,
)
from derive.lowering import LoweredProgram
from derive.precision import DOUBLE, Precision
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
    Steps,
    Store,
    Window,
    walk,
)


def comment(note: str) -> list[str]:
    """A C comment: ``note``'s lines, the later ones under the first's text."""
    lines = note.split("\n")
    return [("/* " if i == 0 else "   ") + line + (" */" if i == len(lines) - 1 else "")
            for i, line in enumerate(lines)]


def _indent(lines: list[str], by: str = "    ") -> list[str]:
    return [by + line for line in lines]


class _Printer:
    def __init__(self, run: Run, lowered: dict[str, LoweredProgram], prefix: str,
                 real: Precision, inputs: tuple[str, ...]):
        self.run, self.lowered, self.prefix, self.real = run, lowered, prefix, real
        self.inputs = inputs  # run's arrays read one row per step
        self.row: dict[str, str] = {}  # run arrays whose row k a guard points at
        self.k = "k"  # the row variable of the loop being printed
        # a call that writes rows is given the addresses of the rows it reads, p's too
        self.addressed = any(c.into and not any(isinstance(s, Carried) for _, s in c.args)
                             for c in walk(run.loops) if isinstance(c, Call))

    def row_of(self, row: str) -> str:
        """A row's index in C: ``k``, ``(k + 1)``; in a loop down, ``j``."""
        row = row.replace("k", self.k)
        return row if row.isidentifier() else f"({row})"

    def address(self, row: Row) -> str:
        """Where a row starts in its array."""
        stride = P_STRIDE if row.array == PARAMETER_PORT else (row.stride or row.size)
        return (f"{row.array} + {self.row_of(row.row)} * {stride}"
                + (f" + {row.offset}" if row.offset else ""))

    def element(self, row: Row) -> str:
        """Element i of a row."""
        return (f"{row.array}[{self.row_of(row.row)} * {row.stride or row.size}"
                + (f" + {row.offset}" if row.offset else "") + " + i]")

    def pointers(self, call: Call) -> tuple[list[str], dict[str, str]]:
        """A pointer per row a call reads or writes (named as its port; a row of a per-step
        input as ``zk``), each the one before it plus its size where it follows it in the
        same row; and the names the call is made with."""
        t = self.real.c_type
        lp = self.lowered[call.program]
        bound = dict(call.args)
        bound.update({port: row for port, row, _ in call.into})
        lines, names, before = [], {}, None
        for port in lp.inputs + lp.outputs:
            source = bound.get(port.name)
            if not isinstance(source, (Row, Carried)):
                before = None
                continue
            row = source.row if isinstance(source, Carried) else source
            name = (f"{row.array}k" if row.array in self.inputs or row.array == PARAMETER_PORT
                    else port.name)
            if (isinstance(source, Row) and before is not None and before[1].array == row.array
                    and before[1].row == row.row
                    and before[1].offset + before[1].size == row.offset):
                where = f"{before[0]} + {before[1].size}"
            else:
                where = self.address(row)
            if isinstance(source, Carried) and source.start:
                where = f"{self.k} ? {where} : {source.start}"
            const = "" if port in lp.outputs else "const "
            lines.append(f"{const}{t} *restrict {name} = {where};")
            names[port.name] = name
            before = None if isinstance(source, Carried) else (name, row)
        return lines, names

    def subset(self, program: str) -> str:
        """The local array of the columns of u a program takes (named for the program: a
        sensor named predict would otherwise declare predict's a second time)."""
        return f"u_{program}"

    def source(self, source, program: str) -> str:
        if isinstance(source, str):
            return source
        if isinstance(source, Columns):
            return "uk" if source.whole else self.subset(program)
        if isinstance(source, Window):
            return "zw"
        if source.array == PARAMETER_PORT and source.row == "k" and not self.addressed:
            return f"{PARAMETER_PORT}k"
        if source.array in self.row:
            return self.row[source.array]
        return self.address(source)

    def copies(self) -> list[str]:
        lines = []
        for s in self.run.states:
            lines += [f"for (i = 0; i < {s.size}; ++i) {{", f"    {s.name}[i] = {s.name}_new[i];",
                      "}"]
        return lines

    def call(self, call: Call) -> list[str]:
        lp = self.lowered[call.program]
        if any(isinstance(source, Carried) for _, source in call.args):
            lines, names = self.pointers(call)
            return lines + call_lines(self.prefix, lp, names)
        lines = []
        for _, w in call.args:
            if isinstance(w, Window):  # newest row first, zero before the first row
                lines += [f"for (i = 0; i < {w.window}; ++i) {{",
                          f"    for (j = 0; j < {w.size}; ++j) {{",
                          f"        zw[i * {w.size} + j] = i <= k ? {w.array}[(k - i) * "
                          f"{w.size} + j] : {self.real.zero()};",
                          "    }", "}"]
        names = {}
        for port, source in call.args:
            if isinstance(source, Columns) and not source.whole:
                lines += [f"{self.subset(call.program)}[{j}] = uk[{c}];"
                          for j, c in enumerate(source.columns)]
            names[port] = self.source(source, call.program)
        names.update({port: self.address(row) for port, row, _ in call.into})
        lines += call_lines(self.prefix, lp, names)
        return lines + (self.copies() if call.carry else [])

    def nodes(self, nodes: tuple[Node, ...]) -> list[str]:
        lines = []
        for node in nodes:
            if isinstance(node, Call):
                lines += self.call(node)
            elif isinstance(node, AfterFirst):
                lines += (["if (k > 0) { /* update-first: step 0 has no prediction */"]
                          + _indent(self.nodes(node.body)) + ["}"])
            elif isinstance(node, Present):
                lines += self.present(node)
            elif isinstance(node, Record):
                value = (("NAN" if self.fill[node.array] == "nan" else self.real.zero())
                         if node.fill else f"{node.value}[0]")
                lines += [f"if ({node.array}) {{", f"    {node.array}[k] = {value};", "}"]
            elif isinstance(node, Store):
                store = [f"for (i = 0; i < {node.size}; ++i) {{",
                         f"    {node.array}[k * {node.size} + i] = {node.state}[i];", "}"]
                lines += ([f"if ({node.array}) {{"] + _indent(store) + ["}"]
                          if node.optional else store)
            elif isinstance(node, Copy):
                lines += [f"for (i = 0; i < {node.target.size}; ++i) {{",
                          f"    {self.element(node.target)} = {self.element(node.source)};",
                          "}"]
            elif isinstance(node, AnySteps):
                lines += comment(node.note) + ["if (steps) {"] + _indent(
                    self.nodes(node.body)) + ["}"]
            elif isinstance(node, Steps):
                lines += self.steps(node)
            else:
                raise TypeError(f"no C for {node!r}")
        return lines

    def steps(self, node: Steps) -> list[str]:
        head = comment(node.note) if node.note else []
        if not node.down:
            return head + [loop_head(node)] + _indent(
                self.step_rows(node) + self.nodes(node.body)) + ["}"]
        self.k = "j"
        body = [f"const size_t j = k - {node.down};"] + self.nodes(node.body)
        self.k = "k"
        return head + [f"for (k = steps; k > {node.down - 1}; --k) {{"] + _indent(body) + ["}"]

    def present(self, node: Present) -> list[str]:
        t = self.real.c_type
        self.row[node.array] = "zk"
        test = " && ".join(f"zk[{i}] == zk[{i}]" for i in range(node.size))
        lines = ["{", f"    const {t} *zk = {node.array} + k * {node.size};",
                 f"    if ({test}) {{ /* a NaN: no {node.sensor} measurement at step k */"]
        lines += _indent(self.nodes(node.body), " " * 8)
        if node.missing:
            lines += ["    } else {"] + _indent(self.nodes(node.missing), " " * 8)
        del self.row[node.array]
        return lines + ["    }", "}"]

    def uses(self, kind) -> list:
        return [n for n in walk(self.run.loops) if isinstance(n, kind)]

    def step_rows(self, node: Steps) -> list[str]:
        """The rows of u and p a loop's guarded calls read (a call that writes rows points
        at those it reads itself)."""
        t = self.real.c_type
        calls = [c for c in walk(node.body) if isinstance(c, Call) and not self.addressed
                 and not any(isinstance(s, Carried) for _, s in c.args)]
        columns = [s for c in calls for _, s in c.args if isinstance(s, Columns)]
        rows = [f"const {t} *uk = u + k * {columns[0].width};"] if columns else []
        if any(isinstance(s, Row) and s.array == PARAMETER_PORT
               for c in calls for _, s in c.args):
            rows.append(f"const {t} *{PARAMETER_PORT}k = {PARAMETER_PORT} + k * {P_STRIDE};")
        return rows

    def declarations(self, inputs: int) -> list[str]:
        t = self.real.c_type
        carrying = self.carrying()
        states = self.run.states if carrying else ()
        lines = [f"{t} {s.name}[{s.size}];" for s in states]
        lines += [f"{t} {s.name}_new[{s.size}];" for s in states]
        carried = {f"{s.name}_new" for s in self.run.states}
        outputs = {}
        subsets = {}
        for call in self.uses(Call):
            if call.into:  # its outputs are rows of run's arrays
                continue
            for port in self.lowered[call.program].outputs:
                if port.name not in carried:
                    outputs.setdefault(port.name, port.size)
            for _, source in call.args:
                if isinstance(source, Columns) and not source.whole:
                    subsets[self.subset(call.program)] = len(source.columns)
        lines += [f"{t} {name}[{size}];" for name, size in outputs.items()]
        lines += [f"{t} {name}[{size}];" for name, size in subsets.items()]
        windows = {s for c in self.uses(Call) for _, s in c.args if isinstance(s, Window)}
        lines += [f"{t} zw[{w.window * w.size}];" for w in windows]
        lines += ["size_t k, i, j;"] if windows else ["size_t k;", "size_t i;"]
        if any(lp.has_checks for lp in self.lowered.values()):
            lines.append("int status;")
        if inputs and not any(isinstance(s, Columns) for c in self.uses(Call)
                              for _, s in c.args):
            lines.append("(void)u;")
        return lines

    def carrying(self) -> bool:
        """True when a call carries the state in run's local arrays (else the loops point
        at the rows that hold it)."""
        return any(c.carry for c in self.uses(Call))

    def start(self) -> list[str]:
        lines = []
        for s in self.run.states if self.carrying() else ():
            n = s.side
            value = (f"i / {n} <= i % {n} ? {s.start}[i] : {s.start}[(i % {n}) * {n} + i / {n}]"
                     if s.whole else f"{s.start}[i]")
            lines += [f"for (i = 0; i < {s.size}; ++i) {{", f"    {s.name}[i] = {value};", "}"]
        return lines


def run_lines(run: Run, lowered: dict[str, LoweredProgram], prefix: str, inputs: int = 0,
              real: Precision = DOUBLE, per_step: tuple[str, ...] = ()) -> list[str]:
    """The statements of C run (unindented); ``inputs``: the width of run's u (0: none);
    ``per_step``: run's arrays read one row per step (a pointer at row k of one is ``zk``)."""
    printer = _Printer(run, lowered, prefix, real, per_step)
    printer.fill = {r.array: r.fill for r in run.records}
    status = any(lp.has_checks for lp in lowered.values())
    return (printer.declarations(inputs) + printer.start() + printer.nodes(run.loops)
            + (["return 0;"] if status else []))


def _unrolled(target: str, source: str, size: int) -> list[str]:
    return [f"{target.format(i)} = {source.format(i)};" for i in range(size)]


def stepping_lines(run: Run, lowered: dict[str, LoweredProgram], prefix: str,
                   bodies: dict[str, LoweredProgram], checks: list[str] = (),
                   real: Precision = DOUBLE) -> list[str]:
    """The statements of C run for a run whose step is its body inline on run's local
    arrays (derive.runs.kinds.stepping): the state in local arrays, the copies unrolled;
    ``bodies``: the programs of the step bodies its calls name (``step``; ``pass``: the
    two-step map's, derive.emit.c_loops); ``checks``: run's check of its start arguments,
    once before the loop."""
    t = real.c_type
    calls = [c for c in walk(run.loops) if isinstance(c, Call)]
    step = next(c for c in calls if c.program == "step")
    reads_p = PARAMETER_PORT in lowered["step"].used_inputs()
    local = [row.array for c in calls + [run.enter] if c is not None
             for _, row, _ in c.into if row.row == ""]
    first = [name for name in local if name == "x_init"]
    lines = [f"{t} {name}[{run.states[0].size}];" for name in first]
    lines += [f"{t} {s.name}[{s.size}];" for s in run.states]
    lines += [f"{t} {s.new}[{s.size}];" for s in run.states]
    lines += [f"{t} {name}[{run.states[0].size}];" for name in local if name not in first]
    states = {state.name for state in run.states}
    stored = {s.state: s.size for s in walk(run.loops)  # other outputs stored, once each
              if isinstance(s, Store) and s.state and s.state not in states
              and s.state not in local}
    lines += [f"{t} {name}[{size}];" for name, size in stored.items()]
    lines.append("size_t k;")
    if (run.enter is not None and lowered[run.enter.program].has_checks) or any(
            isinstance(s, Store) and s.program and lowered[s.program].has_checks
            for s in walk(run.loops)):
        lines.append("int status;")
    if any(p == PARAMETER_PORT for p, _ in step.args) and not reads_p:
        lines += [f"(void){PARAMETER_PORT};", f"(void){P_STRIDE};"]
    if checks:
        lines += ["/* P0 must be zero outside P's pattern; the loop keeps P inside it */"]
        lines += list(checks)
    enter = run.enter
    if enter is not None and enter.program == "enter":
        lines += ["/* the carried state from run's arguments */"]
        lines += call_lines(prefix, lowered["enter"], {})
    elif enter is not None:  # init(x0) into x_init, the state's start
        names = {port: (PARAMETER_PORT if isinstance(src, Row) else src)
                 for port, src in enter.args}
        names.update({port: row.array for port, row, _ in enter.into})
        lines += call_lines(prefix, lowered[enter.program], names)
        lines += _unrolled(f"{run.states[0].name}[{{}}]", "x_init[{}]", run.states[0].size)
    else:
        for s in run.states:
            lines += _unrolled(f"{s.name}[{{}}]", f"{s.start}[{{}}]", s.size)
    for loop in run.loops:
        lines += _stepping_loop(loop, run, lowered, prefix, bodies, reads_p, real)
    if any(lp.has_checks for lp in lowered.values()):
        lines.append("return 0;")
    return lines


def _stepping_loop(loop: Steps, run: Run, lowered, prefix: str, bodies, reads_p: bool,
                   real: Precision) -> list[str]:
    t = real.c_type
    head = comment(loop.note) + [loop_head(loop)]
    rows = {}  # the rows the bodies read
    for call in (c for c in loop.body if isinstance(c, Call)):
        for port, source in call.args:
            if isinstance(source, Row) and source.array != PARAMETER_PORT:
                row = "k" if source.row == "k" else f"({source.row})"
                rows[port] = (f"const {t} *restrict {port}k = {source.array} + {row} * "
                              f"{source.size};")
            elif isinstance(source, Row) and reads_p:
                rows[port] = (f"const {t} *restrict {PARAMETER_PORT}k = {PARAMETER_PORT} + k * "
                              f"{P_STRIDE};")
    body = list(rows.values())
    for call in (c for c in loop.body if isinstance(c, Call)):  # a body on local arrays
        names = {port: (row_pointer(port) if source.array != PARAMETER_PORT or reads_p
                        else PARAMETER_PORT)
                 for port, source in call.args if isinstance(source, Row)}
        names.update({port: row.array for port, row, _ in call.into})
        body += checked_call(bodies[call.program], body_name(prefix, call.program), names,
                             f"{call.program}_status")
    states = {s.name: s for s in run.states}
    stored = {s.state: s for s in loop.body if isinstance(s, Store) and not s.optional
              and s.state and s.row == ("k + 1" if loop.by == 2 else "k")}
    for s in loop.body:
        if (isinstance(s, Store) and s.state and s.state not in states
                and not s.optional):  # a local array (x_mid, an output no state holds)
            body += _unrolled(f"{s.array}[k * {s.size} + {{}}]", f"{s.state}[{{}}]", s.size)
    row = "(k + 1)" if loop.by == 2 else "k"
    for state in run.states:
        store = stored.get(state.name)
        target = (f"{store.array}[{row} * {state.size} + {{}}] = {state.name}[{{}}]" if store
                  else f"{state.name}[{{}}]")
        body += [f"{target.format(i, i)} = {state.new}[{i}];" for i in range(state.size)]
    for s in loop.body:
        if isinstance(s, Store) and s.optional:
            if s.program:
                lp = lowered[s.program]
                inner = call_lines(prefix, lp, {lp.outputs[0].name: f"{s.array} + k * {s.size}"})
            else:
                out = states[s.state].new if s.state in states else s.state
                inner = _unrolled(f"{s.array}[k * {s.size} + {{}}]", f"{out}[{{}}]", s.size)
            body += [f"if ({s.array}) {{"] + _indent(inner) + ["}"]
    return head + _indent(body) + ["}"]
