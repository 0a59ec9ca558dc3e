"""Operation trees: what lowering makes of an expression and what every printer and the
counter walk, so that a count is by construction the count of what is printed.

Operation kinds: ``add sub mul div sqrt fma fnma neg cmp select gate if_gt if_ge`` and
``call:NAME`` (``fma(a, b, c)`` is ``a*b + c``, ``fnma(a, b, c)`` is ``c - a*b``, each one
rounding where the hardware fuses them). :class:`OpCount` counts them by kind: ``flops`` =
add + sub + mul + div + sqrt + 2 fma (negations, comparisons and selects are reported, not
counted as flops); ``instructions`` = every operation. Each of the choosing kinds (a
missing measurement's ``select(z, a, b)``, the gate's ``gate(v, bound, a, b)``, a guard's
``if_gt(l, r, a, b)`` and ``if_ge(l, r, a, b)``: :mod:`derive.guards`) is one comparison
(``cmp``) and one select (``select``) of two already computed values.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, fields

KINDS = ("add", "sub", "mul", "div", "sqrt", "fma", "fnma", "neg", "cmp", "select", "gate",
         "if_gt", "if_ge")
#: The kinds that choose one of two values by a comparison: a ``cmp`` and a ``select`` each.
CHOOSING_KINDS = frozenset({"select", "gate", "if_gt", "if_ge"})
#: The fused multiply-adds: one instruction and two flops each, counted as ``fma``.
FUSED_KINDS = frozenset({"fma", "fnma"})


@dataclass(frozen=True)
class Const:
    """A double constant."""

    value: float


@dataclass(frozen=True)
class Var:
    """A variable, by the name generated code uses (``x[0]``, ``t3``)."""

    name: str

    @property
    def base(self) -> str:
        """The port of an element (``x`` of ``x[0]``), or the temporary's name."""
        return self.name.partition("[")[0]

    @property
    def index(self) -> int | None:
        """The element's flat index (0 of ``x[0]``); None for a temporary."""
        _, bracket, rest = self.name.partition("[")
        return int(rest[:-1]) if bracket else None


def element_name(port: str, index: int) -> str:
    """The name generated code uses for element ``index`` of ``port``: ``x[3]``."""
    return f"{port}[{index}]"


def rename_tree(tree: Tree, name: Callable[[Var], str]) -> Tree:
    """``tree`` with every variable renamed by ``name``."""
    if isinstance(tree, Var):
        return Var(name(tree))
    if isinstance(tree, Op):
        return Op(tree.kind, tuple(rename_tree(a, name) for a in tree.args))
    return tree


def tree_vars(tree: Tree) -> set[Var]:
    """The variables ``tree`` reads."""
    found: set[Var] = set()
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, Var):
            found.add(node)
        elif isinstance(node, Op):
            stack.extend(node.args)
    return found


@dataclass(frozen=True)
class Op:
    """An operation: ``kind`` is one of :data:`KINDS` or ``call:NAME``."""

    kind: str
    args: tuple[Tree, ...]


Tree = Const | Var | Op


def tree_kinds(*trees: Tree) -> set[str]:
    """Every operation kind in ``trees`` (iterative)."""
    found: set[str] = set()
    stack: list[Tree] = list(trees)
    while stack:
        tree = stack.pop()
        if isinstance(tree, Op):
            found.add(tree.kind)
            stack.extend(tree.args)
    return found


def depth(tree: Tree) -> int:
    """Longest chain of operations from a leaf to the root."""
    if isinstance(tree, Op):
        return 1 + max(depth(a) for a in tree.args)
    return 0


@dataclass(frozen=True)
class OpCount:
    """Operations by kind; ``calls`` counts math.h function calls other than sqrt."""

    add: int = 0
    sub: int = 0
    mul: int = 0
    div: int = 0
    sqrt: int = 0
    fma: int = 0
    neg: int = 0
    cmp: int = 0
    select: int = 0
    calls: int = 0

    @property
    def flops(self) -> int:
        """Floating-point operations as the papers count them (an fma is two)."""
        return self.add + self.sub + self.mul + self.div + self.sqrt + 2 * self.fma

    @property
    def instructions(self) -> int:
        """Every operation, an fma, a negation, a comparison and a select one each (calls
        excluded)."""
        return (self.add + self.sub + self.mul + self.div + self.sqrt + self.fma + self.neg
                + self.cmp + self.select)

    def __add__(self, other: OpCount) -> OpCount:
        if not isinstance(other, OpCount):
            return NotImplemented
        return OpCount(**{f.name: getattr(self, f.name) + getattr(other, f.name)
                          for f in fields(self)})

    def scaled(self, times: int) -> OpCount:
        """Every count times ``times`` (the lanes of a vector statement)."""
        return OpCount(**{f.name: getattr(self, f.name) * times for f in fields(self)})

    def as_dict(self) -> dict[str, int]:
        """Counts by kind, in a fixed order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def summary(self) -> str:
        """One line: every kind (``select`` where there is one: code without a choice reads
        as it always has), then flops and instructions."""
        kinds = ", ".join(f"{k} {v}" for k, v in self.as_dict().items()
                          if v or k != "select")
        return f"{kinds} (flops {self.flops}, instructions {self.instructions})"


def _kind_field(kind: str) -> str:
    if kind == "fnma":
        return "fma"
    return "calls" if kind.startswith("call:") else kind


def _tally_tree(tree: Tree, tally: dict[str, int]) -> None:
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, Op):
            if node.kind in CHOOSING_KINDS:
                tally["cmp"] = tally.get("cmp", 0) + 1
                tally["select"] = tally.get("select", 0) + 1
            else:
                key = _kind_field(node.kind)
                tally[key] = tally.get(key, 0) + 1
            stack.extend(node.args)


def count_tree(tree: Tree) -> OpCount:
    """Operations in one lowered tree."""
    tally: dict[str, int] = {}
    _tally_tree(tree, tally)
    return OpCount(**tally)


def count_trees(trees: Iterable[Tree]) -> OpCount:
    """Operations in several lowered trees."""
    tally: dict[str, int] = {}
    for tree in trees:
        _tally_tree(tree, tally)
    return OpCount(**tally)
