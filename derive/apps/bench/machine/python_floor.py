"""The limit of the generated Python run on this machine: the same single-track loop
keeping nothing.

The generated ``run`` is taken from its module and its single-track loop (the branch
``if not track:`` that ``derive.emit.python_loop`` writes) is stripped of what keeps each
step's row (the statements of the loop body that are bare expressions: the pack and
append) and of what builds the arrays after the loop. What remains is the step's own
float operations, its checks and the iteration over the inputs: the time no change of how
the rows are kept can go below, measured in the same run as the generated Python row and
printed beside the Python bar.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from pathlib import Path
from types import SimpleNamespace

from ..cases import Case, Data, Skip
from ..generated import load, python_runner

#: The name of the stripped run in the namespace it is compiled in.
FLOOR_NAME = "run_keeping_nothing"


def _is_single_track_branch(node: ast.stmt) -> bool:
    """``if not track:``, the branch of one track."""
    return isinstance(node, ast.If) and isinstance(node.test, ast.UnaryOp) and \
        isinstance(node.test.op, ast.Not) and isinstance(node.test.operand, ast.Name) and \
        node.test.operand.id == "track"


def keeping_nothing(run_function):
    """``run_function`` (a generated ``run``) with its single-track loops keeping nothing:
    each loop's bare-expression statements dropped and its block returning ``(None,
    None)`` after the loop (where run returns its arrays: the runners index its result).
    The loops are the branch's own and those of an ``if`` in it (the loop that computes
    what identical blocks share once, derive.runs.shared). Raises :class:`Skip`
    when the run has no such loop."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(run_function)))
    function = tree.body[0]
    branch = next((node for node in function.body if _is_single_track_branch(node)), None)
    blocks = [branch] + [node for node in branch.body if isinstance(node, ast.If)] \
        if branch is not None else []
    stripped = [_strip_loop(block) for block in blocks]
    if not any(stripped):
        raise Skip("the generated run has no single-track loop")
    function.name = FLOOR_NAME
    namespace = dict(run_function.__globals__)
    exec(compile(ast.fix_missing_locations(tree), "<keeping nothing>", "exec"), namespace)
    return namespace[FLOOR_NAME]


def _strip_loop(block: ast.If) -> bool:
    """Strip the last loop of ``block``'s body (see :func:`keeping_nothing`); False when it
    has none."""
    loops = [k for k, node in enumerate(block.body) if isinstance(node, ast.For)]
    if not loops:
        return False
    loop = block.body[loops[-1]]
    loop.body = [node for node in loop.body if not isinstance(node, ast.Expr)]
    block.body = block.body[:loops[-1] + 1] + [
        ast.Return(ast.Tuple([ast.Constant(None)] * 2, ast.Load()))]
    return True


def python_floor(case: Case, data: Data, workdir: Path):
    """``run(steps)`` of the generated Python's single-track loop keeping nothing, over
    every copy (as the generated Python row runs)."""
    module = load(case, workdir, "python").python
    return python_runner(SimpleNamespace(run=keeping_nothing(module.run)), case, data)
