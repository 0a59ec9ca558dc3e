"""Identical blocks of a step carried in the lanes of one vector by the C run loop.

A block-diagonal model's step is k independent computations (derive.filters.blockwise
derives one block and reuses its program renamed; a steady map of identical axes is the
same k times). Scalar, the k chains are issued one after another: the run loop of three
identical axes issues three times the operations of one, although its carried chain is
one axis's. Here the lowered step is split into its independent parts (the statements,
checks and results joined by the temporaries and input elements they share; the
parameters ``p`` join nothing), and when all parts are the same statements up to naming
(:func:`split`), the run loop computes them in the lanes of one GCC/Clang vector
(``vector_size``): lane b holds block b, every statement of one block is one vector
statement, the carried state is held in vector variables from step to step, each step's
inputs are gathered into vectors once and the outputs stored lane by lane.

Each lane executes exactly the operations of its block in the scalar step, in the same
order: + - * / and negation are lane-wise IEEE operations, and an fma is written lane by
lane with the file's own ``DERIVE_FMA`` (the compiler turns the lanes into one vector
fma where the target has one), so the results are bitwise those of the scalar run. A
failed check sets the status of the first failing check in the scalar step's order.
Lanes beyond k (the vector's width is a power of two) repeat lane 0's values.

The vector run is compiled where ``DERIVE_VECTOR`` is 1 (GCC and Clang on a target whose
vector registers hold the vector, AVX for four doubles, unless the build sets it to 0),
in the file's one vector dialect (derive.emit.c_vector: its switch, its vector type
``derive_vd`` of the run's width, its ``DERIVE_VFMA``); otherwise the scalar C99 run. A
step that has vector rows of its own (derive.rows) is not also carried in lanes.
Counts are unchanged: the header counts the scalar operations of every block.

The runs it serves (:data:`LANE_KINDS`): the time-varying filters, the steady-state ones
and the predictor (whose run starts from init's ``x_init``); with the two-step pass where
the scalar run takes it. Not served, and why:

* a time-varying run with ``enter`` and ``store`` programs (a factored covariance): it
  starts from ``enter``'s factors of P0 and stores P through ``store`` each step (a
  program of its own, not vector statements); the one such filter's step is also derived
  whole rather than block by block, and for ``mpt3d_a`` sums one block's products in
  another order (sympy's order of the whole model's names), so its blocks are not the
  same statements up to naming there;
* the smoother run kind: a forward loop that also writes each step's predicted x and P
  into work rows, then a backward loop over them in reverse, with a carried state of its
  own; both steps split into identical blocks (up to naming), but the vector run spells
  one loop storing the carried outputs, so lanes there would take a vector forward loop
  writing the work rows and a vector backward loop (not done, not measured);
* the windowed run carries no state, and the sensors' run applies one group of
  measurements at a time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from derive.emit.c_printer import CPrinter
from derive.emit.c_vector import SWITCH, VFMA, VFNMA, vector_macro_lines, vector_type
from derive.lowering import LoweredAssign, LoweredCheck, LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.runs.unit import LOOKAHEAD_NEXT
from derive.trees import FUSED_KINDS, Const, Op, Tree, Var, tree_kinds

#: The operations a vector statement spells (lane-wise IEEE: bitwise those of the scalar).
VECTOR_KINDS = frozenset({"add", "sub", "mul", "div", "neg", "fma", "fnma"})
#: The most lanes (blocks) of one vector: 8 doubles, one AVX-512 register.
MOST_LANES = 8
#: The fewest: two blocks in a vector of two doubles measured 4 to 12 % slower than the
#: scalar run for gsm2d_a's steady-state filters (their scalar runs are within 1.2x of
#: their chains' bound: the gathers and the stores lane by lane cost more than the issue
#: they save) and no faster for its time-varying one; three (mpt3d_a) measured 0.5 to
#: 0.9 of the scalar time (docs/performance.md).
FEWEST_LANES = 3
_INFIX = {"add": "+", "sub": "-", "mul": "*", "div": "/"}
#: The run kinds whose C run may carry identical blocks in lanes: one carried state
#: from step to step, one row of z a step (two a pass with the two-step map); the others
#: and why: the module docstring.
LANE_KINDS = ("timevarying", "steady", "predictor")


def vector_width(lanes: int) -> int:
    """The vector's width for ``lanes`` blocks: the next power of two."""
    width = 1
    while width < lanes:
        width *= 2
    return width


def macro_lines(width: int, fused: bool = True) -> list[str]:
    """The .c file's vector dialect for a vector of ``width`` doubles
    (:func:`derive.emit.c_vector.vector_macro_lines`: the switch, the type, the fused
    multiply-adds where the step fuses) and the interleaving shuffles of the run's stores
    (:data:`PAIRS`)."""
    return (vector_macro_lines(DOUBLE, width, fused) + [f"#if {SWITCH}"] + pair_lines(width)
            + ["#endif"])


@dataclass(frozen=True)
class Lanes:
    """A step split into identical blocks.

    ``block``: one block's statements, checks and results, its input elements named
    ``port[l]`` by their local index l (the rank of the element's index among the block's
    elements of that port), its temporaries ``t0, t1, ...`` in order; the parameters keep
    their names. ``inputs``/``outputs``: (port, l) -> the element's index in each lane's
    block. ``statuses``: for each check of ``block`` (in order) the status of each lane;
    ``order``: the checks of the scalar step in its order, as (check, lane).
    ``constants``: output elements no block writes -> their constant value.
    ``shared``: the statements of the parameters alone, which every block reads (a model
    with free parameters computes them once for all blocks): scalars, before the blocks;
    with the checks of the parameters alone (their declared domains) that come before
    every block's check, once, first.
    """

    lanes: int
    block: LoweredProgram
    inputs: dict[tuple[str, int], tuple[int, ...]]
    outputs: dict[tuple[str, int], tuple[int, ...]]
    statuses: tuple[tuple[int, ...], ...]
    order: tuple[tuple[int, int], ...]
    constants: dict[tuple[str, int], float]
    shared: tuple[LoweredAssign | LoweredCheck, ...] = ()

    @property
    def has_checks(self) -> bool:
        """True when a failed check sets a status: the block's or a shared one."""
        return bool(self.block.checks) or any(isinstance(s, LoweredCheck) for s in self.shared)

    def output_of(self, port: str, index: int) -> tuple[int, int] | None:
        """(local index, lane) of an output element, or None (a constant)."""
        for (name, local), indices in self.outputs.items():
            if name == port and index in indices:
                return local, indices.index(index)
        return None


def _vars(tree: Tree) -> list[Var]:
    found, stack = [], [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, Var):
            found.append(node)
        elif isinstance(node, Op):
            stack.extend(reversed(node.args))
    return found


class _Union:
    def __init__(self) -> None:
        self.parent: dict[str, str] = {}

    def find(self, a: str) -> str:
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def join(self, names: list[str]) -> str | None:
        roots = [self.find(n) for n in names]
        for r in roots[1:]:
            self.parent[self.find(r)] = self.find(roots[0])
        return self.find(roots[0]) if roots else None


def _scalar(var: Var, shared: set[str]) -> bool:
    """True for what every block may read: the parameters p and the temporaries computed
    from them alone (``shared``)."""
    return var.name in shared if var.index is None else var.base == PARAMETER_PORT


@dataclass(frozen=True)
class Part:
    """One independent block of a step: its statements and checks with their positions in
    the step's body, its results (port, index, leaf), and its canonical form
    (:func:`_canonical`: renamed by local indices; ``key`` compares parts)."""

    body: tuple[tuple[int, LoweredAssign | LoweredCheck], ...]
    results: tuple[tuple[str, int, Tree], ...]
    canonical: dict


@dataclass(frozen=True)
class Parts:
    """A step split into its independent blocks (:func:`independent_parts`), in the order
    of their first statement; ``shared``: the statements of the parameters alone (every
    block may read them) and the checks of the parameters alone before every block's
    check (a declared domain); ``constants``: output elements no block writes."""

    parts: tuple[Part, ...]
    shared: tuple[LoweredAssign | LoweredCheck, ...]
    constants: dict[tuple[str, int], float]


def independent_parts(program: LoweredProgram) -> Parts | None:
    """The step's independent blocks: its statements, checks and results joined by the
    temporaries and input elements they share (the parameters ``p`` and the statements of
    them alone join nothing, nor do the checks of them alone before every block's check);
    None for a step with zero checks, a later check that reads no block, or a result that
    reads no block and is not a constant."""
    if program.pattern_checks:
        return None
    union = _Union()
    shared: set[str] = set()
    shared_statements: list[LoweredAssign | LoweredCheck] = []
    items = []
    for position, st in enumerate(program.body):
        names = [v.name for v in _vars(st.tree) if not _scalar(v, shared)]
        if isinstance(st, LoweredAssign) and not names:
            shared.add(st.target)
            shared_statements.append(st)
            continue
        if not names and not any(isinstance(item, LoweredCheck) for _, item in items):
            shared_statements.append(st)  # a parameter's domain: checked once, first
            continue
        if isinstance(st, LoweredAssign):
            names.append(st.target)
        if union.join(names) is None:
            return None
        items.append((position, st))
    constants: dict[tuple[str, int], float] = {}
    results = []
    for port, leaves in program.results:
        for index, leaf in enumerate(leaves):
            if isinstance(leaf, Const):
                constants[(port, index)] = leaf.value
                continue
            names = [v.name for v in _vars(leaf) if not _scalar(v, shared)]
            if not names:
                return None
            union.join(names)
            results.append((port, index, leaf, names[0]))
    # the blocks in the order of their first statement
    blocks: dict[str, dict] = {}

    def block_of(name: str) -> dict:
        root = union.find(name)
        return blocks.setdefault(root, {"body": [], "results": []})

    for position, st in items:
        name = st.target if isinstance(st, LoweredAssign) else next(
            v.name for v in _vars(st.tree) if not _scalar(v, shared))
        block_of(name)["body"].append((position, st))
    for port, index, leaf, name in results:
        block_of(name)["results"].append((port, index, leaf))
    parts = tuple(Part(tuple(b["body"]), tuple(b["results"]),
                       _canonical(b["body"], b["results"], shared)) for b in blocks.values())
    return Parts(parts, tuple(shared_statements), constants)


def split(program: LoweredProgram) -> Lanes | None:
    """The program as identical blocks in lanes, or None: fewer than :data:`FEWEST_LANES`
    blocks, more than :data:`MOST_LANES`, blocks that differ, an operation a vector does
    not spell, or what :func:`independent_parts` refuses."""
    if any(not tree_kinds(st.tree) <= VECTOR_KINDS | {"cmp"} for st in program.body) or \
            any(not isinstance(leaf, Const) and not tree_kinds(leaf) <= VECTOR_KINDS
                for _, leaves in program.results for leaf in leaves):
        return None
    found = independent_parts(program)
    if found is None:
        return None
    parts = [part.canonical for part in found.parts]
    lanes = len(parts)
    if not FEWEST_LANES <= lanes <= MOST_LANES or any(p["key"] != parts[0]["key"] for p in parts):
        return None
    first = parts[0]
    inputs = {key: tuple(p["inputs"][key] for p in parts) for key in first["inputs"]}
    outputs = {key: tuple(p["outputs"][key] for p in parts) for key in first["outputs"]}
    order = sorted((p["checks"][c], c, b) for b, p in enumerate(parts)
                   for c in range(len(p["checks"])))
    statuses = tuple(tuple(p["statuses"][c] for p in parts)
                     for c in range(len(first["checks"])))
    block = LoweredProgram(program.name, program.doc, program.inputs, program.outputs,
                           first["body"], first["results"], program.use_fma)
    return Lanes(lanes, block, inputs, outputs, statuses,
                 tuple((c, b) for _, c, b in order), found.constants, found.shared)


def _commuted(tree: Tree) -> Tree:
    """``tree`` with the operands of each sum and product (an fma's two factors) in one
    order: blocks whose statements differ only there compute the same values (IEEE
    addition and multiplication are commutative), and the sympy order of a product's
    factors follows the names of its block's temporaries."""
    if not isinstance(tree, Op):
        return tree
    args = tuple(_commuted(a) for a in tree.args)
    if tree.kind in ("add", "mul"):
        args = tuple(sorted(args, key=repr))
    elif tree.kind in ("fma", "fnma"):
        args = tuple(sorted(args[:2], key=repr)) + args[2:]
    return Op(tree.kind, args)


def _canonical(body: list, results: list, shared: set[str]) -> dict:
    """One block renamed by local indices: its statements, results, the maps from local to
    global indices, its checks' positions and statuses, and the key blocks compare by."""
    elements: dict[str, set[int]] = {}
    for _, st in body:
        for v in _vars(st.tree):
            if v.index is not None and v.base != PARAMETER_PORT:
                elements.setdefault(v.base, set()).add(v.index)
    for _, _, leaf in results:
        for v in _vars(leaf):
            if v.index is not None and v.base != PARAMETER_PORT:
                elements.setdefault(v.base, set()).add(v.index)
    local = {(port, g): local_index for port, indices in elements.items()
             for local_index, g in enumerate(sorted(indices))}
    temps: dict[str, str] = {}

    def name(v: Var) -> Var:
        if v.index is None:
            return v if v.name in shared else Var(temps[v.name])
        if v.base == PARAMETER_PORT:
            return v
        return Var(f"{v.base}[{local[(v.base, v.index)]}]")

    def renamed(tree: Tree) -> Tree:
        if isinstance(tree, Var):
            return name(tree)
        if isinstance(tree, Op):
            return Op(tree.kind, tuple(renamed(a) for a in tree.args))
        return tree

    statements, checks, statuses = [], [], []
    for position, st in body:
        if isinstance(st, LoweredAssign):
            tree = renamed(st.tree)
            temps[st.target] = f"t{len(temps)}"
            statements.append(LoweredAssign(temps[st.target], tree))
        else:
            statements.append(replace(st, tree=renamed(st.tree), status=0))
            checks.append(position)
            statuses.append(st.status)
    out_indices: dict[str, list[int]] = {}
    for port, index, _ in results:
        out_indices.setdefault(port, []).append(index)
    out_local = {(port, g): local_index for port, indices in out_indices.items()
                 for local_index, g in enumerate(sorted(indices))}
    by_port: dict[str, list] = {}
    for port, _, leaf in sorted(results, key=lambda r: (r[0], r[1])):
        by_port.setdefault(port, []).append(renamed(leaf))
    result_trees = tuple((port, tuple(leaves)) for port, leaves in by_port.items())
    body_key = tuple((s.target, _commuted(s.tree)) if isinstance(s, LoweredAssign)
                     else ("check", _commuted(s.tree), s.relation) for s in statements)
    results_key = tuple((port, tuple(_commuted(leaf) for leaf in leaves))
                        for port, leaves in result_trees)
    return {"key": (body_key, results_key), "body": tuple(statements),
            "results": result_trees,
            "inputs": {(port, local_index): g for (port, g), local_index in local.items()},
            "outputs": {(port, local_index): g for (port, g), local_index in out_local.items()},
            "checks": checks, "statuses": statuses}


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


def _row(port: str) -> str:
    """The run loop's pointer to this step's row of a per-step input (``zk``)."""
    return f"{port}k"


def run_lines(unit, state: list[dict], optional_stores: list[dict], step: Lanes,
              two: Lanes | None, prologue: list[str], tail: list[str],
              real: Precision = DOUBLE) -> list[str] | None:
    """The body of C run carrying the blocks in the lanes of one vector, or None where the
    run cannot (a store computed by a program of its own, a carried element no block
    writes in the same lanes, a two-step map of other blocks).

    ``state``: the carried state (derive.emit.render.carried_state); ``optional_stores``:
    run's outputs that may be NULL; ``step``: the loop's step split; ``two``: the two-step
    map split (two steps per pass, as the scalar run); ``prologue``: run's lines before
    the carried state starts (unused arguments, the check of P0); ``tail``: after the loop.
    """
    if real is not DOUBLE or any(s.get("call") for s in optional_stores):
        return None
    if two is not None and two.lanes != step.lanes:
        return None
    width = vector_width(step.lanes)
    vtype = vector_type(DOUBLE)
    ins = {s["name"]: s for s in state}
    producers = [step] + ([two] if two is not None else [])
    carried: dict[tuple[str, tuple[int, ...]], str] = {}
    for lanes in producers:
        for (port, _), table in lanes.inputs.items():
            if port in ins and (port, table) not in carried:
                carried[(port, table)] = f"{port}_v{len(carried)}"
    # every producer of the carried state writes each carried vector in the same lanes
    sources: list[dict] = []
    for lanes in producers:
        found = {}
        for (port, table), name in carried.items():
            out = ins[port]["out"]
            local = next((index for (p, index), t in lanes.outputs.items()
                          if p == out and t == table), None)
            if local is None:
                return None
            found[name] = (out, local)
        sources.append(found)
    for lanes in producers:
        for port, _ in lanes.block.results:
            size = next(o.size for o in lanes.block.outputs if o.name == port)
            if any(lanes.output_of(port, g) is None and (port, g) not in lanes.constants
                   for g in range(size)):
                return None
    lines = list(prologue)
    lines.append("/* the identical blocks in the lanes of one vector (lane b: block b) */")
    for (port, table), name in carried.items():
        start = ins[port]["start"]
        lines.append(f"{vtype} {name} = "
                     f"{gather(tuple(f'{start}[{g}]' for g in table), width)};")
    lines.append("size_t k;")

    def step_lines(lanes: Lanes, prefix: str, status: str,
                   rows: dict[tuple[str, tuple[int, ...]], str]) -> tuple[list[str], dict]:
        """One program's gathers and statements: (lines, its outputs' vectors); ``rows``:
        the vectors already gathered this pass, by row and elements (added to)."""
        out: list[str] = []
        gathered: dict[tuple[str, int], str] = {}
        for (port, local_index), table in lanes.inputs.items():
            if port in ins:
                gathered[(port, local_index)] = carried[(port, table)]
                continue
            row = _row(port)
            if (row, table) not in rows:
                rows[(row, table)] = f"{prefix}{port}{local_index}"
                out.append(f"const {vtype} {rows[(row, table)]} = "
                           f"{gather(tuple(f'{row}[{g}]' for g in table), width)};")
            gathered[(port, local_index)] = rows[(row, table)]
        writer = VectorStatements(width, prefix, real)
        if lanes.has_checks:
            out.append(f"int {status} = 0;")
        outputs = writer.block(lanes, lambda port, index: gathered[(port, index)], status)
        out += writer.lines
        if lanes.has_checks:
            out += [f"if ({status}) {{", f"    return {status};", "}"]
        return out, outputs

    def element(lanes: Lanes, outputs: dict, port: str, g: int) -> str:
        where = lanes.output_of(port, g)
        if where is None:
            return CPrinter(precision=real).const(lanes.constants[(port, g)])
        local, b = where
        return f"{outputs[(port, local)]}[{b}]"

    def stores(lanes: Lanes, outputs: dict, row: str) -> list[str]:
        """Run's stored rows ``row`` of a program's outputs."""
        out = []
        for s in state:
            if s["store"] and paired(lanes, s["out"], s["size"]):
                first, second = (outputs[(s["out"], i)] for i in range(2))
                start = f"&{s['store']}[{row} * {s['size']}"
                out += [f"{{ const {vtype} lo = {PAIRS}_LO({first}, {second});",
                        f"  const {vtype} hi = {PAIRS}_HI({first}, {second});",
                        f"  __builtin_memcpy({start}], &lo, sizeof lo);",
                        f"  __builtin_memcpy({start} + {width}], &hi, "
                        f"{s['size'] - width} * sizeof hi[0]); }}"]
            elif s["store"]:
                out += [f"{s['store']}[{row} * {s['size']} + {g}] = "
                        f"{element(lanes, outputs, s['out'], g)};" for g in range(s["size"])]
        for s in optional_stores:
            out += [f"if ({s['array']}) {{"]
            out += [f"    {s['array']}[{row} * {s['size']} + {g}] = "
                    f"{element(lanes, outputs, s['out'], g)};" for g in range(s["size"])]
            out.append("}")
        return out

    def paired(lanes: Lanes, port: str, size: int) -> bool:
        """True when each block's two elements of ``port`` are adjacent in its row, block
        after block (x of three 2-state axes: 0 1 | 2 3 | 4 5): the row is the two vectors
        interleaved (:func:`pair_lines`), stored in two pieces."""
        locals_ = [index for (name, index) in lanes.outputs if name == port]
        return (len(locals_) == 2 and size == 2 * lanes.lanes and all(
            lanes.outputs[(port, i)] == tuple(2 * b + i for b in range(lanes.lanes))
            for i in range(2)))

    def carry(lanes_index: int, outputs: dict) -> list[str]:
        return [f"{name} = {outputs[where]};"
                for name, where in sources[lanes_index].items()]

    def one_step() -> list[str]:
        out = [f"const {real.c_type} *restrict {_row(name)} = {name} + k * "
               f"{unit.step_input_size(name)};" for name in unit.step_inputs]
        if unit.parameters and PARAMETER_PORT in step.block.used_inputs():
            out.append(f"const {real.c_type} *restrict {_row(PARAMETER_PORT)} = "
                       f"{PARAMETER_PORT} + k * p_stride;")
        body, outputs = step_lines(step, "a", "step_status", {})
        return out + body + stores(step, outputs, "k") + carry(0, outputs)

    indent = "    "
    if two is not None:
        lines.append("for (k = 0; k + 2 <= steps; k += 2) {")
        m = unit.step_input_size("z")
        body = [f"const {real.c_type} *restrict zk = z + k * {m};",
                f"const {real.c_type} *restrict {_row(LOOKAHEAD_NEXT)} = z + (k + 1) * {m};"]
        rows: dict[tuple[str, tuple[int, ...]], str] = {}
        first, mid = step_lines(step, "a", "step_status", rows)
        second, new = step_lines(two, "b", "pass_status", rows)
        body += first + second
        body += stores(step, mid, "k") + stores(two, new, "(k + 1)") + carry(1, new)
        lines += [indent + line for line in body]
        lines += ["}", "for (; k < steps; ++k) {"]
    else:
        lines.append("for (k = 0; k < steps; ++k) {")
    lines += [indent + line for line in one_step()]
    lines.append("}")
    return lines + list(tail)


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


def vector_run(unit, step: LoweredProgram, two: LoweredProgram | None, state: list[dict],
               optional_stores: list[dict], prologue: list[str], tail: list[str],
               real: Precision = DOUBLE) -> tuple[list[str], list[str], str]:
    """C run's vector body, the file's macro lines for it and the header's line about it,
    or nothing (``[], [], ""``) for a run loop the scalar C99 run alone serves: a run kind
    other than ``timevarying``, ``steady`` and ``predictor`` (its prologue calls init and
    ``state`` starts from init's result), or a step that is not identical blocks."""
    if unit.kind not in LANE_KINDS or unit.run.window or step.rows:
        return [], [], ""
    step_lanes = split(step)
    two_lanes = split(two) if two is not None else None
    if step_lanes is None or (two is not None and two_lanes is None):
        return [], [], ""
    lines = run_lines(unit, state, optional_stores, step_lanes, two_lanes, prologue, tail,
                      real)
    if lines is None:
        return [], [], ""
    fused = any(lp.kinds() & FUSED_KINDS for lp in (step, two) if lp is not None)
    return lines, macro_lines(vector_width(step_lanes.lanes), fused), header_line(step_lanes)
