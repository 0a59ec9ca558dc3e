"""A :class:`~derive.runs.loops.Run` printed as the statements of C ``run``: one track,
the carried state in local arrays, each program called on them and its outputs copied
back; a guard is a branch."""

from __future__ import annotations

from derive.emit import c_printer
from derive.lowering import LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.runs.loops import (
    AfterFirst,
    Call,
    Columns,
    Node,
    Present,
    Record,
    Row,
    Run,
    Steps,
    Store,
    walk,
)

#: C run's stride of p: 0 when p is one row for every step, NP when one row per step.
P_STRIDE = "p_stride"


def call_lines(prefix: str, lp: LoweredProgram, names: dict[str, str]) -> list[str]:
    """The C call of ``PREFIX_NAME`` with its ports named by ``names`` (else their names);
    a non-zero status is returned at once."""
    args = ", ".join(names.get(name, name) for name in c_printer.argument_order(lp))
    if not lp.has_checks:
        return [f"{prefix}_{lp.name}({args});"]
    return [f"status = {prefix}_{lp.name}({args});", "if (status) {", "    return status;",
            "}"]


def _indent(lines: list[str], by: str = "    ") -> list[str]:
    return [by + line for line in lines]


class _Printer:
    def __init__(self, run: Run, lowered: dict[str, LoweredProgram], prefix: str,
                 real: Precision):
        self.run, self.lowered, self.prefix, self.real = run, lowered, prefix, real
        self.row: dict[str, str] = {}  # run arrays whose row k a guard points at

    def subset(self, program: str) -> str:
        """The local array of the columns of u a program takes (named for the program: a
        sensor named predict would otherwise declare predict's a second time)."""
        return f"u_{program}"

    def source(self, source, program: str) -> str:
        if isinstance(source, str):
            return source
        if isinstance(source, Columns):
            return "uk" if source.whole else self.subset(program)
        if source.array == PARAMETER_PORT:
            return f"{PARAMETER_PORT}k"
        if source.array in self.row:
            return self.row[source.array]
        return f"{source.array} + {source.row} * {source.size}"

    def copies(self) -> list[str]:
        lines = []
        for s in self.run.states:
            lines += [f"for (i = 0; i < {s.size}; ++i) {{", f"    {s.name}[i] = {s.name}_new[i];",
                      "}"]
        return lines

    def call(self, call: Call) -> list[str]:
        lp = self.lowered[call.program]
        lines = []
        names = {}
        for port, source in call.args:
            if isinstance(source, Columns) and not source.whole:
                lines += [f"{self.subset(call.program)}[{j}] = uk[{c}];"
                          for j, c in enumerate(source.columns)]
            names[port] = self.source(source, call.program)
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
            elif isinstance(node, Steps):
                lines += ["for (k = 0; k < steps; ++k) {"] + _indent(
                    self.step_rows() + self.nodes(node.body)) + ["}"]
            else:
                raise TypeError(f"no C for {node!r}")
        return lines

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
        return [n for n in walk((self.run.loop,)) if isinstance(n, kind)]

    def step_rows(self) -> list[str]:
        t = self.real.c_type
        columns = [s for c in self.uses(Call) for _, s in c.args if isinstance(s, Columns)]
        rows = [f"const {t} *uk = u + k * {columns[0].width};"] if columns else []
        if any(isinstance(s, Row) and s.array == PARAMETER_PORT
               for c in self.uses(Call) for _, s in c.args):
            rows.append(f"const {t} *{PARAMETER_PORT}k = {PARAMETER_PORT} + k * {P_STRIDE};")
        return rows

    def declarations(self, inputs: int) -> list[str]:
        t = self.real.c_type
        lines = [f"{t} {s.name}[{s.size}];" for s in self.run.states]
        lines += [f"{t} {s.name}_new[{s.size}];" for s in self.run.states]
        carried = {f"{s.name}_new" for s in self.run.states}
        outputs = {}
        subsets = {}
        for call in self.uses(Call):
            for port in self.lowered[call.program].outputs:
                if port.name not in carried:
                    outputs.setdefault(port.name, port.size)
            for _, source in call.args:
                if isinstance(source, Columns) and not source.whole:
                    subsets[self.subset(call.program)] = len(source.columns)
        lines += [f"{t} {name}[{size}];" for name, size in outputs.items()]
        lines += [f"{t} {name}[{size}];" for name, size in subsets.items()]
        lines += ["size_t k;", "size_t i;"]
        if any(lp.has_checks for lp in self.lowered.values()):
            lines.append("int status;")
        if inputs and not any(isinstance(s, Columns) for c in self.uses(Call)
                              for _, s in c.args):
            lines.append("(void)u;")
        return lines

    def start(self) -> list[str]:
        lines = []
        for s in self.run.states:
            n = s.side
            value = (f"i / {n} <= i % {n} ? {s.start}[i] : {s.start}[(i % {n}) * {n} + i / {n}]"
                     if s.whole else f"{s.start}[i]")
            lines += [f"for (i = 0; i < {s.size}; ++i) {{", f"    {s.name}[i] = {value};", "}"]
        return lines


def run_lines(run: Run, lowered: dict[str, LoweredProgram], prefix: str, inputs: int = 0,
              real: Precision = DOUBLE) -> list[str]:
    """The statements of C run (unindented); ``inputs``: the width of run's u (0: none)."""
    printer = _Printer(run, lowered, prefix, real)
    printer.fill = {r.array: r.fill for r in run.records}
    status = any(lp.has_checks for lp in lowered.values())
    return (printer.declarations(inputs) + printer.start() + printer.nodes((run.loop,))
            + (["return 0;"] if status else []))
