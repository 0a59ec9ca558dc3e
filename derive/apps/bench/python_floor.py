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

from .cases import Case, Data, Skip
from .generated import load, python_runner

#: The name of the stripped run in the namespace it is compiled in.
FLOOR_NAME = "run_keeping_nothing"


def _is_single_track_branch(node: ast.stmt) -> bool:
    """``if not track:``, the branch of one track."""
    return isinstance(node, ast.If) and isinstance(node.test, ast.UnaryOp) and \
        isinstance(node.test.op, ast.Not) and isinstance(node.test.operand, ast.Name) and \
        node.test.operand.id == "track"


def keeping_nothing(run_function):
    """``run_function`` (a generated ``run``) with its single-track loop keeping nothing:
    the loop's bare-expression statements dropped and the branch returning ``(None,
    None)`` after the loop (where run returns its arrays: the runners index its result).
    Raises :class:`Skip` when the run has no such loop."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(run_function)))
    function = tree.body[0]
    branch = next((node for node in function.body if _is_single_track_branch(node)), None)
    loops = [k for k, node in enumerate(branch.body) if isinstance(node, ast.For)] \
        if branch is not None else []
    if not loops:
        raise Skip("the generated run has no single-track loop")
    loop = branch.body[loops[-1]]
    loop.body = [node for node in loop.body if not isinstance(node, ast.Expr)]
    branch.body = branch.body[:loops[-1] + 1] + [
        ast.Return(ast.Tuple([ast.Constant(None)] * 2, ast.Load()))]
    function.name = FLOOR_NAME
    namespace = dict(run_function.__globals__)
    exec(compile(ast.fix_missing_locations(tree), "<keeping nothing>", "exec"), namespace)
    return namespace[FLOOR_NAME]


def python_floor(case: Case, data: Data, workdir: Path):
    """``run(steps)`` of the generated Python's single-track loop keeping nothing, over
    every copy (as the generated Python row runs)."""
    module = load(case, workdir, "python").python
    return python_runner(SimpleNamespace(run=keeping_nothing(module.run)), case, data)
