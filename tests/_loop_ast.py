"""The single-track loop of a generated Python ``run``, read with ``ast``: for the tests of
its operations (derive.emit.python_loop, derive.runs.shared)."""

from __future__ import annotations

import ast


def single_track_branch(text: str) -> ast.If:
    """The branch ``if not track:`` of the ``run`` function in generated Python ``text``."""
    run = next(node for node in ast.parse(text).body
               if isinstance(node, ast.FunctionDef) and node.name == "run")
    return next(node for node in run.body if isinstance(node, ast.If) and
                ast.unparse(node.test) == "not track")


def outside_raises(loop: ast.For) -> list[ast.AST]:
    """Every node of the loop's body but those of its raise statements (an error path)."""
    found, stack = [], list(loop.body)
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Raise):
            continue
        found.append(node)
        stack.extend(ast.iter_child_nodes(node))
    return found
