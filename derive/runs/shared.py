"""Identical blocks that start equal compute what reads no data once: a pass over a
stepping :class:`~derive.runs.loops.Run` (:func:`share_blocks`), which the Python run's
one-track loop prints (derive.emit.python_loop).

A block-diagonal model with identical blocks (the three axes of ``mpt3d_a``) runs k
independent filters of one model. The part of each block's step that reads no per-step
data (no measurement, no input; the parameters are the same element in every block) and
only carried state that itself reads no data is, for a linear filter, the covariance
recursion: P(k/k-1), S, its factorisation and its checks, the gain, P(k/k). Blocks that
are the same statements (:func:`derive.runs.blocks.independent_parts`, compared up to
naming and the order of a sum's or product's operands) and whose carried elements start
bitwise equal therefore compute bitwise equal values at every step: the same operations
in the same order on the same values. The run loop checks that once, on the initial
state, and then computes each such statement once for all blocks.

:func:`shared_step` finds those statements and returns the step with each of them once:

* the carried elements that are shared: start with every carried element a block reads,
  and drop (until nothing changes) each whose new value reads anything but the
  parameters, shared statements and shared carried elements;
* a statement (or check) is shared when it reads only those: of its k copies the
  earliest in the step's order is kept (renamed to read the shared elements of the first
  block), the others dropped and their readers renamed to it. Every statement therefore
  still follows what it reads, and a failing check is the one the full step would fail
  first (its copies fail together; the earliest is first in the step's order), with the
  full step's message;
* every block's results of shared carried elements are the first block's.

The statements kept are those of the full step, renamed: their results are bitwise the
full step's when the condition holds (:attr:`SharedStep.equal`). Counts are those of the
full step (what a step computes); the run does less of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from derive.lowering import LoweredAssign, LoweredProgram
from derive.program import PARAMETER_PORT
from derive.runs.blocks import Part, independent_parts
from derive.runs.loops import Run
from derive.trees import Tree, element_name, rename_tree, tree_vars


@dataclass(frozen=True)
class SharedStep:
    """The step with its shared statements once (``program``), the statements it drops
    per step (``dropped``), and what must hold of the initial state for it to be the full
    step: ``equal``, per carried port, the flat indices of each later block's shared
    elements and, in the same order, those of its group's first block (bitwise equal)."""

    program: LoweredProgram
    dropped: int
    equal: tuple[tuple[str, tuple[int, ...], tuple[int, ...]], ...]


def shared_step(program: LoweredProgram, carried: Sequence[tuple[str, str]]
                ) -> SharedStep | None:
    """``program`` (a step) with what its identical blocks share computed once, or None
    when no two blocks are identical or they share nothing. ``carried``: the (input
    port, output port) pairs the run carries from step to step."""
    found = independent_parts(program)
    if found is None or len(found.parts) < 2:
        return None
    groups: dict[object, list[Part]] = {}
    for part in found.parts:
        groups.setdefault(part.canonical["key"], []).append(part)
    scalars = {st.target for st in found.shared if isinstance(st, LoweredAssign)}
    next_of = dict(carried)
    results = {port: list(leaves) for port, leaves in program.results}
    rename: dict[str, str] = {}
    dropped: set[int] = set()
    equal: dict[str, tuple[list[int], list[int]]] = {}
    for parts in groups.values():
        if len(parts) < 2:
            continue
        elements = _shared_elements(parts, next_of, results, scalars)
        if not elements:
            continue
        first = parts[0].canonical["inputs"]
        for port, local in sorted(elements):
            for part in parts[1:]:
                index = part.canonical["inputs"][(port, local)]
                rename[element_name(port, index)] = element_name(port, first[(port, local)])
                later, firsts = equal.setdefault(port, ([], []))
                later.append(index)
                firsts.append(first[(port, local)])
        for j in _data_free(parts[0], elements, scalars)[2]:
            copies = sorted((part.body[j][0], part.body[j][1]) for part in parts)
            kept = copies[0][1]
            for position, st in copies[1:]:
                dropped.add(position)
                if isinstance(st, LoweredAssign) and isinstance(kept, LoweredAssign):
                    rename[st.target] = kept.target
        # every block's new shared elements are the first block's (renamed)
        for port, local in sorted(elements):
            out = next_of[port]
            leaf = results[out][first[(port, local)]]
            for part in parts[1:]:
                results[out][part.canonical["inputs"][(port, local)]] = leaf
    if not dropped:
        return None

    def renamed(tree: Tree) -> Tree:
        return rename_tree(tree, lambda var: rename.get(var.name, var.name))

    body = []
    for position, st in enumerate(program.body):
        if position in dropped:
            continue
        if isinstance(st, LoweredAssign):
            body.append(LoweredAssign(st.target, renamed(st.tree)))
        else:
            body.append(replace(st, tree=renamed(st.tree)))
    shared = LoweredProgram(program.name, program.doc, program.inputs, program.outputs,
                            tuple(body),
                            tuple((port, tuple(renamed(leaf) for leaf in leaves))
                                  for port, leaves in results.items()),
                            program.use_fma)
    return SharedStep(shared, len(dropped),
                      tuple((port, tuple(later), tuple(firsts))
                            for port, (later, firsts) in equal.items()))


def share_blocks(run: Run, step: LoweredProgram) -> Run:
    """The pass marking a stepping run whose step (``step``, without its pattern checks)
    shares statements among identical blocks (:attr:`Run.shared`: :func:`shared_step` of
    the carried state that the step reads and writes); the run as it is otherwise."""
    ports = {p.name for p in step.inputs}
    outputs = dict(step.results)
    shared = shared_step(step, [(s.name, s.new) for s in run.states
                                if s.name in ports and s.new in outputs])
    return run if shared is None else replace(run, shared=shared)


def _reads_only(tree: Tree, elements: set[str], temporaries: set[str]) -> bool:
    """True when ``tree`` reads only parameters, the elements named in ``elements`` and the
    temporaries in ``temporaries``."""
    for var in tree_vars(tree):
        if var.index is None:
            if var.name not in temporaries:
                return False
        elif var.base != PARAMETER_PORT and var.name not in elements:
            return False
    return True


def _shared_elements(parts: list[Part], next_of: dict[str, str],
                     results: dict[str, list[Tree]], scalars: set[str]
                     ) -> set[tuple[str, int]]:
    """The carried elements (port, local index) of a group of identical blocks whose values
    read no data: each block reads it, its new value is the same local element of the
    same output in every block, and that value reads only parameters, statements of the
    parameters and other such elements (a fixed point from all carried elements)."""
    first = parts[0]
    elements = {(port, local) for port, local in first.canonical["inputs"]
                if port in next_of and _next_local(first, port, local, next_of) is not None
                and all(_next_local(part, port, local, next_of) ==
                        _next_local(first, port, local, next_of) for part in parts)}
    while True:
        names, temporaries, _ = _data_free(first, elements, scalars)
        kept = {(port, local) for port, local in elements
                if _reads_only(results[next_of[port]][first.canonical["inputs"][(port, local)]],
                               names, temporaries)}
        if kept == elements:
            return elements
        elements = kept


def _next_local(part: Part, port: str, local: int, next_of: dict[str, str]) -> int | None:
    """The local index of the block's output element that is the next value of its carried
    element (port, local): the output port's element of the same flat index; None when the
    block does not write it. Blocks whose elements carry to the same local output carry
    lane by lane the same values."""
    index = part.canonical["inputs"][(port, local)]
    return next((out_local for (name, out_local), g in part.canonical["outputs"].items()
                 if name == next_of[port] and g == index), None)


def _data_free(first: Part, elements: set[tuple[str, int]], scalars: set[str]
               ) -> tuple[set[str], set[str], list[int]]:
    """What of the block reads only parameters, statements of the parameters and the
    carried ``elements``: those elements' names, its temporaries of that kind, and the
    indices (in the block's body) of its statements and checks of that kind."""
    names = {element_name(port, first.canonical["inputs"][(port, local)])
             for port, local in elements}
    temporaries = set(scalars)
    positions = []
    for j, (_, st) in enumerate(first.body):
        if _reads_only(st.tree, names, temporaries):
            positions.append(j)
            if isinstance(st, LoweredAssign):
                temporaries.add(st.target)
    return names, temporaries, positions
