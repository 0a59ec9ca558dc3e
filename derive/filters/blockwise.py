"""Time-varying linear filters of a block-diagonal model, derived block by block.

A linear model whose F, G Q G^T, H and R split into independent blocks
(:func:`derive.structure.find_blocks`) is filtered by one independent filter per block,
as long as P stays block diagonal: every declared P0 pattern but ``dense`` keeps it so
(the closure of a pattern inside the blocks stays inside them). Deriving the whole model
at once walks n x n matrices at every stage (sympy multiplies every zero), which made
generation grow like n^3 for k identical axes; here each distinct block is derived once
and its program reused for the blocks identical to it, renamed into the model's ports,
so the work is linear in the number of blocks.

Two blocks are identical when their matrices with values substituted are equal after
naming each block's free parameters by position, and the declared pattern is the same.

The assembled step is the one the whole-model derivation gives, up to naming and order:

* the zero checks of P come first, for every upper-triangle entry outside the closed
  pattern in row-major order, with the whole model's pattern message (as before);
* then each block's statements, block after block (the whole-model derivation ran each
  stage over all blocks before the next stage); temporaries are numbered in that order;
* each block's pivot checks name the pivot by its row in the whole model
  (:class:`derive.staging.PivotMessage`), so their messages are the whole model's and
  their statuses are numbered in block order;
* the terms of a sum and the factors of a product are lowered in the order of the block's
  own program (``Program.order_names``: each renamed symbol -> the block's symbol), so
  the renamed copies of a block lower to its operations in the same order (before,
  sympy's order of the renamed names: ``t10*t2*t7`` and ``t22*t27*t30`` multiply in
  different orders) and identical blocks are identical up to naming
  (:mod:`derive.runs.blocks` carries them in the lanes of one vector).

A model with free parameters is optimised once more as a whole, so that expressions of
the parameters alone that several blocks compute are shared as before. Counts are
exactly k times one block's for k identical blocks without shared parameters.

Models with per-step inputs, a dense declared pattern, a single block, or blocks
``find_blocks`` refuses (a state no measurement observes) are derived whole.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import sympy

from ..domains import declared_domain
from ..errors import SymbolError
from ..program import Program
from ..staging import PivotMessage
from ..statements import ZERO, Assign, Check, Temporary
from ..structure import Block, block_size, find_blocks, largest_block_size
from .common import input_port, pattern_message, time_varying_ports
from .pattern import Pattern

DeriveBlock = Callable[[object], tuple[Program, Pattern]]
"""Derives the step of one block model: (its optimised program, its closed pattern)."""


def independent_blocks(model, declared: str) -> list[Block] | None:
    """The blocks of ``model`` to derive one by one, or None to derive it whole."""
    if model.kind != "linear" or input_port(model) or declared == "dense":
        return None
    try:
        blocks = find_blocks(model)
    except SymbolError:  # a state no measurement observes: the whole derivation copes
        return None
    return blocks if len(blocks) > 1 else None


def whole_size(model, spec, P0_pattern: str | None = None) -> int:
    """The size (states or measurements, the larger) of the largest part of ``model`` that
    filter ``spec`` derives at once (with the option ``P0_pattern``; None: the model's):
    its largest block for a blockwise family that splits the model, else all of it. A
    time-varying step with a dense pattern (or a model with inputs) is derived whole; a
    steady map is built from its non-zero constants, so its work follows the blocks."""
    if model.kind != "linear" or not spec.blockwise:
        return max(model.n, model.m)
    if spec.covariance:
        blocks = independent_blocks(model, P0_pattern or model.P0_pattern)
        return max(model.n, model.m) if blocks is None else max(map(block_size, blocks))
    return largest_block_size(model)


def block_key(block_model, declared: str):
    """What the derivation of a block depends on: its matrices with values substituted,
    its free parameters renamed by position with their declared domains (which its step
    checks), and the declared pattern."""
    placeholders = {p: sympy.Symbol(f"_parameter{i}") for i, p in enumerate(block_model.parameters)}
    matrices = tuple(sympy.ImmutableMatrix(block_model.matrix(k)).xreplace(placeholders)
                     for k in ("F", "G", "H", "Q", "R"))
    domains = tuple(declared_domain(p) for p in block_model.parameters)
    return declared, len(placeholders), matrices, domains


def blockwise_step(model, declared: str, derive_block: DeriveBlock
                   ) -> tuple[Program, Pattern] | None:
    """The time-varying ``step`` of ``model`` assembled from its blocks' steps and its
    closed pattern, or None when ``model`` is to be derived whole
    (:func:`independent_blocks`)."""
    blocks = independent_blocks(model, declared)
    if blocks is None:
        return None
    derived: dict[object, tuple[Program, Pattern]] = {}
    parts = []
    for block in blocks:
        key = block_key(block.model, declared)
        if key not in derived:
            derived[key] = derive_block(block.model)
        parts.append((block, *derived[key]))
    closed = _diagonal_pattern(model.n, [(b.states, pattern) for b, _, pattern in parts])
    inputs, outputs = time_varying_ports(model)
    whole = Program("step", inputs, outputs, doc=parts[0][1].doc)
    message = pattern_message(closed, declared)
    n = model.n
    body: list = [Check(whole.element("P", i, j), message, ZERO)
                  for i in range(n) for j in range(i, n) if not closed[i][j]]
    x_new: list[sympy.Expr] = [sympy.Integer(0)] * n
    P_new: list[sympy.Expr] = [sympy.Integer(0)] * (n * n)
    parameter_index = {p.name: i for i, p in enumerate(model.parameters)}
    temporaries = 0
    copied: dict[sympy.Symbol, sympy.Symbol] = {}
    for block, program, _ in parts:
        names = _port_names(program, whole, block, parameter_index)
        for st in program.body:
            if isinstance(st, Assign):
                names[st.target] = Temporary(f"t{temporaries}")
                temporaries += 1
        copied.update((new, old) for old, new in names.items())
        rows = {"states": block.states, "measurements": block.measurements}
        for st in program.body:
            if isinstance(st, Assign):
                body.append(Assign(names[st.target], st.expr.xreplace(names)))
            elif st.relation != ZERO:  # the block's zero checks are among the whole's
                text = (st.message.renumbered(rows) if isinstance(st.message, PivotMessage)
                        else st.message)
                body.append(replace(st, value=st.value.xreplace(names), message=text))
        results = program.results
        s = block.states
        for i, value in enumerate(results["x_new"]):
            x_new[s[i]] = value.xreplace(names)
        nb = len(s)
        for i in range(nb):
            for j in range(nb):
                P_new[s[i] * n + s[j]] = results["P_new"][i * nb + j].xreplace(names)
    # with free parameters the whole is optimised again: its temporaries are renumbered,
    # and the blocks share the parameters' expressions (sympy's order of its own names)
    shared = bool(model.parameters)
    step = whole.assembled(body, {"x_new": tuple(x_new), "P_new": tuple(P_new)},
                           optimize=shared, order_names=None if shared else copied)
    return step, closed


def _port_names(program: Program, whole: Program, block: Block,
                parameter_index: dict[str, int]) -> dict[sympy.Symbol, sympy.Symbol]:
    """The elements of ``program``'s ports (one block's) -> those of the whole model's."""
    s, k = block.states, block.measurements
    names: dict[sympy.Symbol, sympy.Symbol] = {}
    for i, si in enumerate(s):
        names[program.element("x", i)] = whole.element("x", si)
        for j in range(i, len(s)):
            names[program.element("P", i, j)] = whole.element("P", si, s[j])
    for j, kj in enumerate(k):
        names[program.element("z", j)] = whole.element("z", kj)
    for a, parameter in enumerate(block.model.parameters):
        names[program.element("p", a)] = whole.element("p", parameter_index[parameter.name])
    return names


def _diagonal_pattern(n: int, parts: Sequence[tuple[Sequence[int], Pattern]]) -> Pattern:
    """The n x n pattern holding each part's pattern on its states' rows and columns."""
    rows = [[False] * n for _ in range(n)]
    for states, pattern in parts:
        for a, i in enumerate(states):
            for b, j in enumerate(states):
                rows[i][j] = pattern[a][b]
    return tuple(tuple(row) for row in rows)
