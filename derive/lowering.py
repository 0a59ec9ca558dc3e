"""Lowering of whole programs: every statement of an optimised
:class:`~derive.program.Program` lowered (:mod:`derive.expression_lowering`) to an
operation tree (:mod:`derive.trees`), its checks numbered, its vector chunks' lanes
lowered by their form.

A program's trees are at most :data:`MAX_DEPTH` operations deep: :func:`lower_program`
names each subtree that reaches that depth as a temporary of its own, computed just
before the statement that reads it (the same operations in the same order, so the
results and the counts do not change). A 600-term sum is otherwise a chain 600 deep,
deeper than the printers' and passes' recursion allows, and C99 only promises 63
nesting levels of parentheses in one expression.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from derive.expression_lowering import STATE_PORTS, ExpressionLowerer, LoweringError
from derive.single_use import fold_single_use
from derive.statements import OPERATORS, PRESENT, ZERO, Assign, Check
from derive.trees import Const, Op, Tree, Var, depth, element_name, rename_tree, tree_kinds

if TYPE_CHECKING:
    from derive.program import Port, Program
    from derive.rows import LoweredChunk

#: The deepest tree a lowered program holds (C99's translation limits promise 63 nesting
#: levels of parenthesised expressions; Python's default recursion limit is 1000 frames).
MAX_DEPTH = 60


@dataclass(frozen=True)
class LoweredAssign:
    """``target = tree`` (``target`` a temporary's name)."""

    target: str
    tree: Tree


@dataclass(frozen=True)
class LoweredCheck:
    """``tree`` is ``cmp(value, 0)``: fails unless value > 0 (``relation`` "positive"),
    value >= 0 ("nonnegative") or value == 0 ("zero"); or ``cmp(value, value)``: fails
    for a NaN ("present", a measurement); ``status`` numbers the check.
    Every check but the zero and presence checks has its own status, in order; the
    presence checks of a program (its measurements) share the next one, the zero checks
    (its pattern) the one after. ``parameter``: the name of the parameter whose declared
    domain the check is (derive.statements.Check; empty for the others), whose refused
    value generated Python names; ``measurement``: a presence check's measurement."""

    tree: Op
    message: str
    status: int
    relation: str = "positive"
    parameter: str = ""
    measurement: str = ""

    @property
    def is_pattern(self) -> bool:
        """True for a zero check: an input element outside a declared pattern."""
        return self.relation == "zero"

    @property
    def is_presence(self) -> bool:
        """True for a presence check: a measurement that must not be NaN."""
        return self.relation == PRESENT

    @property
    def operator(self) -> str:
        """How generated code compares the value with 0 (``>``, ``>=``, ``==``)."""
        return OPERATORS[self.relation]

    def passes(self, value: str, zero: str = "0.0") -> str:
        """The text of the test the check requires, given the printed value and zero:
        ``value > 0.0`` (as :attr:`operator` says), ``value == value`` for a presence
        check (false for NaN only)."""
        if self.is_presence:
            return f"{value} == {value}"
        return f"{value} {self.operator} {zero}"


@dataclass(frozen=True)
class LoweredProgram:
    """A program as the printers see it: every statement lowered."""

    name: str
    doc: str
    inputs: tuple[Port, ...]
    outputs: tuple[Port, ...]
    body: tuple[LoweredAssign | LoweredCheck, ...]
    results: tuple[tuple[str, tuple[Tree, ...]], ...]
    use_fma: bool
    #: The vector chunks (derive.rows): each one's lanes are consecutive assignments of
    #: the body, whose trees are the lanes of the chunk's form.
    rows: tuple[LoweredChunk, ...] = ()

    @property
    def has_checks(self) -> bool:
        return any(isinstance(s, LoweredCheck) for s in self.body)

    @property
    def checks(self) -> tuple[LoweredCheck, ...]:
        return tuple(s for s in self.body if isinstance(s, LoweredCheck))

    @property
    def pattern_checks(self) -> tuple[LoweredCheck, ...]:
        """The zero checks: input elements that must be 0 (outside P's pattern)."""
        return tuple(c for c in self.checks if c.is_pattern)

    def without_pattern_checks(self) -> LoweredProgram:
        """The program without its zero checks: what a run loop executes once the
        initial P has been checked (the recursion keeps P inside its pattern)."""
        return replace(self, body=tuple(s for s in self.body
                                        if not (isinstance(s, LoweredCheck) and s.is_pattern)))

    def renamed(self, ports: Mapping[str, str],
                temporary: Callable[[str], str] | None = None) -> LoweredProgram:
        """The same statements with the elements of ports renamed by ``ports`` (a port
        not in it keeps its name) and each temporary by ``temporary`` (the port
        declarations stay, so only the statements are printed from it): how a run loop gives
        the step its own arrays (``z`` read as ``zk``, the row of step k), a lane its own
        state and temporaries, a second step its own temporaries."""
        def port(name: str) -> str:
            return ports.get(name, name)

        def temp(name: str) -> str:
            return temporary(name) if temporary is not None else name

        def var(v: Var) -> str:
            return temp(v.name) if v.index is None else element_name(port(v.base), v.index)

        body = tuple(LoweredAssign(temp(s.target), rename_tree(s.tree, var))
                     if isinstance(s, LoweredAssign) else
                     replace(s, tree=rename_tree(s.tree, var)) for s in self.body)
        return replace(
            self, body=body,
            results=tuple((port(name), tuple(rename_tree(leaf, var) for leaf in leaves))
                          for name, leaves in self.results),
            rows=tuple(chunk.renamed(temp, var) for chunk in self.rows))

    def temporaries(self) -> int:
        """One more than the largest temporary number ``tN`` assigned (0: none)."""
        return 1 + max((int(s.target[1:]) for s in self.body
                        if isinstance(s, LoweredAssign) and s.target[1:].isdigit()),
                       default=-1)

    def kinds(self) -> set[str]:
        """Every operation kind used."""
        return tree_kinds(*(s.tree for s in self.body))

    def reads_below_diagonal(self, port: Port) -> bool:
        """True when an element of the square input ``port`` below its diagonal is read (a
        vector row of a symmetric P reads P whole: derive.filters.vector_rows)."""
        n = port.shape[-1]
        stack: list[Tree] = [s.tree for s in self.body]
        while stack:
            tree = stack.pop()
            if isinstance(tree, Op):
                stack.extend(tree.args)
            elif (isinstance(tree, Var) and tree.index is not None and tree.base == port.name
                  and tree.index // n > tree.index % n):
                return True
        return False

    def used_inputs(self) -> set[str]:
        """Names of the input ports read anywhere."""
        names: set[str] = set()
        stack: list[Tree] = [s.tree for s in self.body]
        stack.extend(leaf for _, leaves in self.results for leaf in leaves)
        while stack:
            tree = stack.pop()
            if isinstance(tree, Op):
                stack.extend(tree.args)
            elif isinstance(tree, Var) and "[" in tree.name:
                names.add(tree.name.split("[", 1)[0])
        return names


def lower_program(program: Program, *, use_fma: bool = False,
                  state_ports: tuple[str, ...] = STATE_PORTS,
                  first_status: int = 1) -> LoweredProgram:
    """Lower every statement of ``program.optimize()`` (an optimised program as is).

    ``state_ports``: the input ports that carry state from step to step; in an fma chain
    products that read them go last (see :func:`_late`). ``first_status``: the status of
    the program's first check (the next ones count on from it), so that the programs of
    one file number their checks apart (:func:`lower_programs`)."""
    program = program.optimize()
    lowerer = ExpressionLowerer(use_fma, state_ports, program.order_names,
                                program.sort_keys())
    body: list[LoweredAssign | LoweredCheck] = []
    cut = _DepthCut(1 + max((int(st.target.name[1:]) for st in program.body
                             if isinstance(st, Assign) and st.target.name[1:].isdigit()),
                            default=-1), body)
    status = first_status - 1
    present_status = first_status + sum(1 for st in program.body if isinstance(st, Check)
                                        and st.relation not in (ZERO, PRESENT))
    pattern_status = present_status + any(isinstance(st, Check) and st.relation == PRESENT
                                          for st in program.body)
    lanes = {t: (chunk, lane) for chunk in program.rows for lane, t in enumerate(chunk.targets)}
    statements = (fold_single_use(program.body, program.results, frozenset(lanes)) if use_fma
                  else program.body)
    for st in statements:
        if isinstance(st, Assign) and st.target in lanes:
            chunk, lane = lanes[st.target]
            tree = chunk.form.tree(lane, use_fma)
            if depth(tree) >= MAX_DEPTH:
                raise LoweringError(f"lane {st.target} of a vector chunk is {depth(tree)} "
                                    f"operations deep (at most {MAX_DEPTH - 1})")
            body.append(LoweredAssign(st.target.name, tree))
            continue
        if isinstance(st, Assign):
            body.append(LoweredAssign(st.target.name, cut(lowerer.lower(st.expr))))
            continue
        value = cut(lowerer.lower(st.value))
        tree = Op("cmp", (value, value if st.relation == PRESENT else Const(0.0)))
        if st.relation == PRESENT:
            body.append(LoweredCheck(tree, st.message, present_status, PRESENT,
                                     measurement=st.measurement))
        elif st.relation != ZERO:
            status += 1
            body.append(LoweredCheck(tree, st.message, status, st.relation, st.parameter))
        else:
            body.append(LoweredCheck(tree, st.message, pattern_status, ZERO))
    results = tuple((name, tuple(cut(lowerer.lower(v)) for v in values))
                    for name, values in program.results.items())
    return LoweredProgram(program.name, program.doc, program.inputs, program.outputs,
                          tuple(body), results, use_fma,
                          tuple(chunk.lowered() for chunk in program.rows))


def next_status(lowered: LoweredProgram, first_status: int) -> int:
    """The first status free after ``lowered``'s checks (``first_status`` without any)."""
    return max((c.status for c in lowered.checks), default=first_status - 1) + 1


def lower_programs(programs: Sequence[Program], *, use_fma: bool = False,
                   state_ports: tuple[str, ...] = STATE_PORTS) -> dict[str, LoweredProgram]:
    """:func:`lower_program` of each of the programs of one file, in order, their checks
    numbered apart: the first program's from 1, each next one's from the first status
    after the previous one's, so that a status (what a C function returns, what run
    returns from whichever program failed) names exactly one check of the file."""
    lowered: dict[str, LoweredProgram] = {}
    first = 1
    for program in programs:
        lp = lower_program(program, use_fma=use_fma, state_ports=state_ports,
                           first_status=first)
        lowered[lp.name] = lp
        first = next_status(lp, first)
    return lowered


class _DepthCut:
    """Calls give a tree no deeper than :data:`MAX_DEPTH`: each subtree that reaches that
    depth becomes a temporary ``tN`` (numbered from ``first``) appended to ``body``, in the
    order the operations are evaluated. Iterative: the trees it cuts are too deep to
    recurse over."""

    def __init__(self, first: int, body: list) -> None:
        self.next = first
        self.body = body

    def __call__(self, tree: Tree) -> Tree:
        done: dict[int, tuple[Tree, int]] = {}     # id(node) -> (its cut tree, its depth)
        stack: list[tuple[Tree, bool]] = [(tree, False)]
        while stack:
            node, expanded = stack.pop()
            if id(node) in done:
                continue
            if not isinstance(node, Op):
                done[id(node)] = (node, 0)
            elif not expanded:
                stack.append((node, True))
                stack.extend((a, False) for a in reversed(node.args))
            else:
                args = [done[id(a)] for a in node.args]
                cut = node if all(c is a for (c, _), a in zip(args, node.args)) else \
                    Op(node.kind, tuple(c for c, _ in args))
                deep = 1 + max(d for _, d in args)
                if deep >= MAX_DEPTH and node is not tree:
                    name = f"t{self.next}"
                    self.next += 1
                    self.body.append(LoweredAssign(name, cut))
                    cut, deep = Var(name), 0
                done[id(node)] = (cut, deep)
        return done[id(tree)][0]

