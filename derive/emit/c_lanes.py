"""A run's identical blocks in the lanes of one vector (:attr:`derive.runs.loops.Run.lanes`,
the pass :func:`derive.runs.blocks.in_lanes`), printed as C run's vector body.

Lane b holds block b: every statement of one block is one GCC/Clang vector statement
(``vector_size``), the carried state is held in vector variables from step to step, each
step's inputs are gathered into vectors once and the outputs stored lane by lane. Each
lane executes exactly the operations of its block in the scalar step, in the same order:
+ - * / and negation are lane-wise IEEE operations, and an fma is the file's one vector
dialect's ``DERIVE_VFMA`` (derive.emit.c_vector), so the results are bitwise those of the
scalar run. A failed check sets the status of the first failing check in the scalar
step's order.

The vector run is compiled where ``DERIVE_VECTOR`` is 1 (GCC and Clang on a target whose
vector registers hold the vector, AVX for four doubles, unless the build sets it to 0),
in the file's one vector dialect (derive.emit.c_vector: its switch, its vector type
``derive_vd`` of the run's width, its ``DERIVE_VFMA``); otherwise the scalar C99 run. A
step that has vector rows of its own (derive.rows) is not also carried in lanes. Counts
are unchanged: the header counts the scalar operations of every block.
"""

from __future__ import annotations

from collections.abc import Callable

from derive.emit.c_loops import P_STRIDE, loop_head, row_pointer
from derive.emit.c_printer import CPrinter
from derive.emit.c_run import call_lines
from derive.emit.c_vector import SWITCH, VFMA, VFNMA, vector_macro_lines, vector_type
from derive.lowering import LoweredAssign, LoweredCheck, LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.runs.blocks import Lanes, vector_width
from derive.runs.loops import Call, Row, Run, Steps, Store
from derive.trees import Const, Op, Tree, Var

_INFIX = {"add": "+", "sub": "-", "mul": "*", "div": "/"}


def lanes_macro_lines(width: int, fused: bool = True) -> list[str]:
    """The .c file's vector dialect for a vector of ``width`` doubles
    (:func:`derive.emit.c_vector.vector_macro_lines`: the switch, the type, the fused
    multiply-adds where the step fuses) and the interleaving shuffles of the run's stores
    (:data:`PAIRS`)."""
    return (vector_macro_lines(DOUBLE, width, fused) + [f"#if {SWITCH}"] + pair_lines(width)
            + ["#endif"])


class VectorStatements:
    """Vector C statements of one block (:class:`Lanes`), each operation its own vector
    temporary; ``names``: the C text of the block's inputs (``port[l]`` -> a vector
    variable; ``p[i]`` -> a scalar)."""

    def __init__(self, width: int, prefix: str, real: Precision = DOUBLE) -> None:
        self.width = width
        self.type = vector_type(DOUBLE)
        self.prefix = prefix
        self.lines: list[str] = []
        self.count = 0
        self.scalar = CPrinter(precision=real)

    def _new(self, text: str) -> str:
        name = f"{self.prefix}{self.count}"
        self.count += 1
        self.lines.append(f"const {self.type} {name} = {text};")
        return name

    def value(self, tree: Tree, names: Callable[[Var], tuple[str, bool]]) -> tuple[str, bool]:
        """(C text, is a vector) of ``tree``; every vector operation a new temporary."""
        if isinstance(tree, Const):
            return self.scalar.const(tree.value), False
        if isinstance(tree, Var):
            return names(tree)
        args = [self.value(a, names) for a in tree.args]
        if not any(vector for _, vector in args):  # parameters and constants alone
            text = self.scalar.expression(Op(tree.kind, tuple(Var(t) for t, _ in args)))
            return f"({text})", False
        if tree.kind in ("fma", "fnma"):
            splat = [t if v else f"(({self.type}){{{', '.join([t] * self.width)}}})"
                     for t, v in args]
            name = VFMA if tree.kind == "fma" else VFNMA
            return self._new(f"{name}({', '.join(splat)})"), True
        if tree.kind == "neg":
            return self._new(f"-{args[0][0]}"), True
        (a, _), (b, _) = args
        return self._new(f"{a} {_INFIX[tree.kind]} {b}"), True

    def block(self, lanes: Lanes, inputs: Callable[[str, int], str],
              status: str | None) -> dict[tuple[str, int], str]:
        """The block's statements; returns each output (port, local index) -> its vector.
        ``inputs(port, local_index)``: the vector of the block's input element ``port[l]``;
        ``status``: the int the checks set (the first failing, in the scalar order)."""
        temps: dict[str, tuple[str, bool]] = {}

        def names(v: Var) -> tuple[str, bool]:
            if v.index is None:
                return temps[v.name]
            if v.base == PARAMETER_PORT:
                return f"{PARAMETER_PORT}k[{v.index}]", False
            return inputs(v.base, v.index), True

        scalar = CPrinter(lambda v: names(v)[0], precision=self.scalar.precision)
        for st in lanes.shared:  # of the parameters alone: once, as in the scalar step
            if isinstance(st, LoweredCheck):  # before every block's check, as there
                self.lines += [f"if (!({st.passes(scalar.expression(st.tree.args[0]))}) "
                               f"&& !{status}) {{", f"    {status} = {st.status};", "}"]
                continue
            name = f"{self.prefix}{st.target}"
            self.lines.append(f"const {self.scalar.precision.c_type} {name} = "
                              f"{scalar.expression(st.tree)};")
            temps[st.target] = name, False

        checked = []
        for st in lanes.block.body:
            if isinstance(st, LoweredAssign):
                temps[st.target] = self.value(st.tree, names)
            else:
                checked.append((*self.value(st.tree.args[0], names), st))
        for c, b in lanes.order:
            text, vector, check = checked[c]
            value = f"{text}[{b}]" if vector else text
            self.lines += [f"if (!({check.passes(value)}) && !{status}) {{",
                           f"    {status} = {lanes.statuses[c][b]};", "}"]
        outputs = {}
        for port, leaves in lanes.block.results:
            for local_index, leaf in enumerate(leaves):
                text, vector = self.value(leaf, names)
                outputs[(port, local_index)] = text if vector else self._new(
                    "{" + ", ".join([text] * self.width) + "}")
        return outputs


def gather(values: tuple[str, ...], width: int) -> str:
    """A vector initialiser of one value per lane, the lanes beyond them lane 0's."""
    return "{" + ", ".join(values + (values[0],) * (width - len(values))) + "}"


#: The macros interleaving two vectors a, b: ``PAIRS_LO`` is a0 b0 a1 b1 ..., the first
#: half of the lanes; ``PAIRS_HI`` the second half.
PAIRS = "DERIVE_PAIRS"


def pair_lines(width: int) -> list[str]:
    """The definitions of the :data:`PAIRS` macros for vectors of ``width`` doubles (GCC's
    ``__builtin_shuffle``, Clang's ``__builtin_shufflevector``)."""
    def mask(half: int) -> list[int]:
        return [half * width // 2 + j // 2 + (width if j % 2 else 0) for j in range(width)]

    lo, hi = mask(0), mask(1)
    index = f"derive_i{width}"
    return ["#if defined(__clang__)",
            f"#define {PAIRS}_LO(a, b) __builtin_shufflevector((a), (b), "
            f"{', '.join(map(str, lo))})",
            f"#define {PAIRS}_HI(a, b) __builtin_shufflevector((a), (b), "
            f"{', '.join(map(str, hi))})",
            "#else",
            f"__extension__ typedef long long {index} "
            f"__attribute__((vector_size({8 * width})));",
            f"#define {PAIRS}_LO(a, b) __builtin_shuffle((a), (b), "
            f"({index}){{{', '.join(map(str, lo))}}})",
            f"#define {PAIRS}_HI(a, b) __builtin_shuffle((a), (b), "
            f"({index}){{{', '.join(map(str, hi))}}})",
            "#endif"]


def header_line(lanes: Lanes) -> str:
    """The header's statement of how the vector run issues the counted operations."""
    width = vector_width(lanes.lanes)
    target = {2: "SSE2", 4: "AVX", 8: "AVX-512"}[width]
    return (f"run: the {lanes.lanes} identical blocks of the step in the lanes of one vector "
            f"of {width} doubles where {SWITCH} is 1 (GCC, Clang where a vector register "
            f"holds them: x86-64 with {target}; "
            f"a build setting it to 0 runs the scalar C99 loop): each lane executes "
            "its block's operations of the counts above in the same order, one block's "
            "count of vector instructions issuing them each step; bitwise the scalar run's "
            "results")


def lanes_lines(run: Run, lowered: dict[str, LoweredProgram], prefix: str,
                prologue: list[str], real: Precision = DOUBLE) -> list[str]:
    """The body of C run carrying the blocks in the lanes of one vector
    (:attr:`Run.lanes`); ``prologue``: lines before the carried state starts (a
    function the vector run does not call named, so that it counts as used)."""
    lanes = run.lanes
    width, vtype, t = lanes.width, vector_type(DOUBLE), real.c_type
    blocks = dict(lanes.blocks)
    sources = dict(lanes.sources)
    states = {s.name: s for s in run.states}
    carried = {key: f"{key[0]}_v{i}" for i, key in enumerate(lanes.carried)}
    status = any(lp.has_checks for lp in lowered.values())
    lines = []
    if run.enter is not None:  # init(x0) into x_init, where the state starts
        (_, start, _), = run.enter.into
        # call_lines sets status only from an enter program that has checks
        enter_checks = lowered[run.enter.program].has_checks
        lines += [f"{t} {start.array}[{start.size}];"] + (["int status;"] if enter_checks
                                                           else [])
        names = {port: (PARAMETER_PORT if isinstance(src, Row) else src)
                 for port, src in run.enter.args}
        names.update({port: row.array for port, row, _ in run.enter.into})
        lines += call_lines(prefix, lowered[run.enter.program], names)
    step = next(c for c in run.loops[0].body if isinstance(c, Call))
    if any(p == PARAMETER_PORT for p, _ in step.args) and \
            PARAMETER_PORT not in lowered["step"].used_inputs():
        lines += [f"(void){PARAMETER_PORT};", f"(void){P_STRIDE};"]
    lines += list(prologue)
    lines.append("/* the identical blocks in the lanes of one vector (lane b: block b) */")
    for (port, table), name in carried.items():
        start = run.enter.into[0][1].array if run.enter is not None else states[port].start
        lines.append(f"{vtype} {name} = "
                     f"{gather(tuple(f'{start}[{g}]' for g in table), width)};")
    lines.append("size_t k;")

    def call_body(call: Call, prefix: str, status: str,
                  rows: dict[tuple[str, tuple[int, ...]], str]) -> tuple[list[str], dict]:
        """One call's gathers and vector statements: (lines, its outputs' vectors);
        ``rows``: the vectors already gathered this pass, by row and elements (added to)."""
        block = blocks[call.program]
        out: list[str] = []
        gathered: dict[tuple[str, int], str] = {}
        for (port, local_index), table in block.inputs.items():
            if port in states:
                gathered[(port, local_index)] = carried[(port, table)]
                continue
            row = row_pointer(port)
            if (row, table) not in rows:
                rows[(row, table)] = f"{prefix}{port}{local_index}"
                out.append(f"const {vtype} {rows[(row, table)]} = "
                           f"{gather(tuple(f'{row}[{g}]' for g in table), width)};")
            gathered[(port, local_index)] = rows[(row, table)]
        writer = VectorStatements(width, prefix, real)
        if block.has_checks:
            out.append(f"int {status} = 0;")
        outputs = writer.block(block, lambda port, index: gathered[(port, index)], status)
        out += writer.lines
        if block.has_checks:
            out += [f"if ({status}) {{", f"    return {status};", "}"]
        return out, outputs

    def element(block: Lanes, outputs: dict, port: str, g: int) -> str:
        where = block.output_of(port, g)
        if where is None:
            return CPrinter(precision=real).const(block.constants[(port, g)])
        local, b = where
        return f"{outputs[(port, local)]}[{b}]"

    def paired(block: Lanes, port: str, size: int) -> bool:
        """True when each block's two elements of ``port`` are adjacent in its row, block
        after block (x of three 2-state axes: 0 1 | 2 3 | 4 5): the row is the two vectors
        interleaved (:func:`pair_lines`), stored in two pieces."""
        locals_ = [index for (name, index) in block.outputs if name == port]
        return (len(locals_) == 2 and size == 2 * block.lanes and all(
            block.outputs[(port, i)] == tuple(2 * b + i for b in range(block.lanes))
            for i in range(2)))

    def store(s: Store, block: Lanes, outputs: dict, port: str) -> list[str]:
        """Row ``s.row`` of run's output ``s.array``: the call's output ``port``."""
        row = s.row if s.row.isidentifier() else f"({s.row})"
        if s.optional:
            return ([f"if ({s.array}) {{"]
                    + [f"    {s.array}[{row} * {s.size} + {g}] = "
                       f"{element(block, outputs, port, g)};" for g in range(s.size)] + ["}"])
        if paired(block, port, s.size):
            first, second = (outputs[(port, i)] for i in range(2))
            start = f"&{s.array}[{row} * {s.size}"
            return [f"{{ const {vtype} lo = {PAIRS}_LO({first}, {second});",
                    f"  const {vtype} hi = {PAIRS}_HI({first}, {second});",
                    f"  __builtin_memcpy({start}], &lo, sizeof lo);",
                    f"  __builtin_memcpy({start} + {width}], &hi, "
                    f"{s.size - width} * sizeof hi[0]); }}"]
        return [f"{s.array}[{row} * {s.size} + {g}] = {element(block, outputs, port, g)};"
                for g in range(s.size)]

    def loop_body(loop: Steps) -> list[str]:
        calls = [c for c in loop.body if isinstance(c, Call)]
        out, seen = [], set()
        for call in calls:  # the rows the calls read, each once
            for port, source in call.args:
                if not isinstance(source, Row) or port in seen:
                    continue
                seen.add(port)
                if source.array != PARAMETER_PORT:
                    row = "k" if source.row == "k" else f"({source.row})"
                    out.append(f"const {t} *restrict {row_pointer(port)} = {source.array} + "
                               f"{row} * {source.size};")
                elif PARAMETER_PORT in blocks[call.program].block.used_inputs():
                    out.append(f"const {t} *restrict {row_pointer(PARAMETER_PORT)} = "
                               f"{PARAMETER_PORT} + k * {P_STRIDE};")
        rows: dict = {}
        made = {}  # the name of a state or local array -> (block, outputs, its port)
        for call, (letter, status) in zip(calls, (("a", "step_status"), ("b", "pass_status"))):
            body, outputs = call_body(call, letter, status, rows)
            out += body
            block = blocks[call.program]
            made.update({name: (block, outputs, port) for port, _, name in call.into})
            if call.carry:
                made.update({s.name: (block, outputs, s.new) for s in run.states})
                carry = [f"{carried[key]} = {outputs[where]};"
                         for key, where in zip(lanes.carried, sources[call.program])]
            made.update({p.name: (block, outputs, p.name)
                         for p in lowered[call.program].outputs if p.name not in made})
        stores = [s for s in loop.body if isinstance(s, Store)]
        for s in sorted(stores, key=lambda s: s.optional):
            out += store(s, *made[s.state])
        return out + carry

    indent = "    "
    for loop in run.loops:
        lines += [loop_head(loop)] + [indent + line for line in loop_body(loop)] + ["}"]
    return lines + (["return 0;"] if status else [])
