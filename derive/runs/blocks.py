"""Identical blocks of a step, found in no language: a step split into its independent
blocks (:func:`independent_parts`), the blocks that are the same statements up to naming
(:func:`split`: :class:`Lanes`), and the pass that carries a stepping run's identical
blocks in the lanes of one vector (:func:`in_lanes`), which the C printer prints
(derive.emit.c_lanes).

A block-diagonal model's step is k independent computations (derive.filters.blockwise
derives one block and reuses its program renamed; a steady map of identical axes is the
same k times). Scalar, the k chains are issued one after another: the run loop of three
identical axes issues three times the operations of one, although its carried chain is
one axis's. The lowered step is split into its independent parts (the statements,
checks and results joined by the temporaries and input elements they share; the
parameters ``p`` join nothing), and when all parts are the same statements up to naming,
a run can compute them in the lanes of one vector: lane b holds block b, every statement
of one block is one vector statement, the carried state is held in vectors from step to
step, each step's inputs are gathered into vectors once and the outputs stored lane by
lane. Lanes beyond k (the vector's width is a power of two) repeat lane 0's values.

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

from dataclasses import dataclass, replace
from functools import cached_property

from derive.lowering import LoweredAssign, LoweredCheck, LoweredProgram
from derive.program import PARAMETER_PORT
from derive.runs.loops import Call, InLanes, Run, Store, walk
from derive.trees import Const, Op, Tree, Var, tree_kinds

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
    the step's body, its results (port, index, leaf), the temporaries every block may read
    (``shared``: of the parameters alone), and its canonical form (:func:`_canonical`:
    renamed by local indices; ``key`` compares parts)."""

    body: tuple[tuple[int, LoweredAssign | LoweredCheck], ...]
    results: tuple[tuple[str, int, Tree], ...]
    shared: frozenset[str]

    @cached_property
    def canonical(self) -> dict:
        """Built when first asked for: a step of one block never compares it."""
        return _canonical(list(self.body), list(self.results), set(self.shared))


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
    frozen = frozenset(shared)
    parts = tuple(Part(tuple(b["body"]), tuple(b["results"]), frozen) for b in blocks.values())
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
    lanes = len(found.parts)
    if not FEWEST_LANES <= lanes <= MOST_LANES:
        return None
    parts = [part.canonical for part in found.parts]
    if any(p["key"] != parts[0]["key"] for p in parts):
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




def in_lanes(run: Run, kind: str, lowered: dict[str, LoweredProgram]) -> Run | None:
    """The pass carrying a stepping run's identical blocks in the lanes of one vector
    (:attr:`Run.lanes`), or None where the scalar run alone serves: a run kind not in
    :data:`LANE_KINDS`, a call that does not split into the same number of identical
    blocks, a store computed by a program of its own or of an output no block writes, or
    a carried element that the calls do not all write in the same lanes."""
    calls = [c for c in walk(run.loops) if isinstance(c, Call)]
    if kind not in LANE_KINDS or run.enter is not None and run.enter.program != "init":
        return None
    produced = ({s.name for s in run.states} | {name for c in calls for _, _, name in c.into}
                | {p.name for c in calls for p in lowered[c.program].outputs})
    if any(isinstance(s, Store) and (s.program or s.state not in produced)
           for s in walk(run.loops)):
        return None
    blocks = {}
    for call in calls:
        lp = lowered[call.program]
        found = split(lp.without_pattern_checks()) if not lp.rows else None
        if found is None or found.lanes != next(iter(blocks.values()), found).lanes:
            return None
        blocks[call.program] = found
    ins = {s.name: s for s in run.states}
    carried: dict[tuple[str, tuple[int, ...]], None] = {}
    for lanes in blocks.values():
        for (port, _), table in lanes.inputs.items():
            if port in ins:
                carried.setdefault((port, table))
    sources = {}
    for program, lanes in blocks.items():
        found = []
        for port, table in carried:
            out = ins[port].new
            local = next((index for (p, index), t in lanes.outputs.items()
                          if p == out and t == table), None)
            if local is None:
                return None
            found.append((out, local))
        sources[program] = tuple(found)
        for port, _ in lanes.block.results:
            size = next(o.size for o in lanes.block.outputs if o.name == port)
            if any(lanes.output_of(port, g) is None and (port, g) not in lanes.constants
                   for g in range(size)):
                return None
    return replace(run, lanes=InLanes(vector_width(next(iter(blocks.values())).lanes),
                                      tuple(blocks.items()), tuple(carried),
                                      tuple(sources.items())))
