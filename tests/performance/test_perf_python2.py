"""Issue 16's Python bar (derive.emit.python_loop): per step the single-track loop builds
no container (each step's row is packed into bytes at once, the inputs are read element
by element from their doubles), does exactly the operations the header counts, and still
equals stepping bit for bit; the bench's limit (the same loop keeping nothing) keeps the
operations and the checks."""

from __future__ import annotations

import ast

import numpy as np
import pytest
from _backend_kf import kf_unit
from _loop_ast import outside_raises, single_track_branch

from derive import catalog
from derive.apps.bench import run as bench_run
from derive.apps.bench.cases import Case, Skip, make_data
from derive.apps.bench.machine.python_floor import keeping_nothing
from derive.build import load_python
from derive.errors import NumericalError
from derive.filters import derive_unit
from derive.flops import count
from derive.generation import render_filter
from derive.pipeline import load_units

CASES = [("mpt3d_b", "kf", {}), ("mpt3d_a", "kf", {}), ("mpt3d_a", "lf", {}),
         ("mpt3d_a", "sskf", {}), ("ca", "kf", {"joseph": True}),
         ("mpt3d_a", "kf", {"latency_schedule": True}), ("gnss_pseudorange", "ekf", {}),
         ("gnss_pseudorange", "ukf", {})]


def _single_track_loop(text: str) -> ast.For:
    """The for loop of ``run``'s branch ``if not track:``."""
    return next(node for node in single_track_branch(text).body if isinstance(node, ast.For))


def _text(model, name, options) -> str:
    return render_filter(catalog.load(model), name, "python", options)[f"{name}.py"]


@pytest.mark.parametrize("model, name, options", CASES)
def test_a_step_of_the_loop_builds_no_tuple_list_or_row_list(model, name, options):
    """The row is packed into bytes (one call), not a tuple extended into a list of floats;
    the inputs come from an array of doubles, not from a list made by ``tolist``."""
    loop = _single_track_loop(_text(model, name, options))
    built = [node for node in outside_raises(loop)
             if isinstance(node, ast.Tuple | ast.List) and isinstance(node.ctx, ast.Load)]
    assert not built, (model, name, [ast.unparse(node) for node in built])
    assert "tolist" not in ast.unparse(loop.iter)
    keeps = [node for node in loop.body if isinstance(node, ast.Expr)]
    assert [ast.unparse(node.value.func) for node in keeps] == ["keep"]
    assert ast.unparse(keeps[0].value.args[0].func) == "pack"


@pytest.mark.parametrize("model, name, options", CASES)
def test_the_loop_does_the_operations_the_header_counts(model, name, options):
    """One binary operator per counted add, sub, mul and div of the step (the operations of
    a raise are an error path), and nothing else in float arithmetic."""
    loop = _single_track_loop(_text(model, name, options))
    operators = [type(node.op) for node in outside_raises(loop)
                 if isinstance(node, ast.BinOp)]
    counted = count(derive_unit(catalog.load(model), name, options).programs["step"],
                    "python")
    assert operators.count(ast.Add) == counted.add
    assert operators.count(ast.Sub) == counted.sub
    assert operators.count(ast.Mult) == counted.mul
    assert operators.count(ast.Div) == counted.div
    assert len(operators) == counted.add + counted.sub + counted.mul + counted.div


def _stepped(module, zs, x0, P0, p_rows):
    x, P = list(x0), list(np.asarray(P0).reshape(-1))
    xs, Ps = [], []
    for z, p in zip(zs, p_rows, strict=True):
        x, P = module.step(x, P, z, p)
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps).reshape(len(zs), len(x0), len(x0))


def test_inputs_of_several_elements_and_a_parameter_row_per_step_are_stepped_bitwise():
    """Two measurements and three parameters per step through one zip of repeated
    iterators: each step gets its own row's elements, in order."""
    module = load_units([kf_unit(axes=2)], "python")[0].python
    rng = np.random.default_rng(16)
    steps = 250
    zs, x0 = rng.normal(size=(steps, 2)), rng.normal(size=4)
    p_rows = np.column_stack([rng.uniform(0.05, 0.5, steps), rng.uniform(0.01, 0.1, steps),
                              rng.uniform(0.1, 1.0, steps)])
    P0 = np.diag([2.0, 1.0, 3.0, 0.5]) + 0.1
    xs, Ps = module.run(zs, x0, P0, p_rows)
    xr, Pr = _stepped(module, zs, x0, P0, p_rows)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)
    # a transposed (not C-contiguous) zs is read in its logical order
    xt, _ = module.run(np.ascontiguousarray(zs.T).T, x0, P0, p_rows)
    np.testing.assert_array_equal(xt, xr)


def test_a_failed_check_names_its_own_step():
    """The step index of the error is counted from the bytes kept so far (no counter per
    step): a negative r in row 7 makes S negative there, and the message says step 7."""
    module = load_units([kf_unit(axes=2)], "python")[0].python
    rng = np.random.default_rng(17)
    steps = 20
    p_rows = np.column_stack([np.full(steps, 0.1), np.full(steps, 0.05), np.full(steps, 0.5)])
    p_rows[7, 2] = -1e9
    with pytest.raises(NumericalError, match=r"^step 7: S is not positive definite"):
        module.run(rng.normal(size=(steps, 2)), np.zeros(4), np.eye(4), p_rows)


def test_the_bench_limit_keeps_the_operations_and_the_checks(tmp_path):
    """derive.apps.bench.machine.python_floor: the generated loop without its keeping statement
    runs, returns nothing, and its check still raises at its step."""
    path = tmp_path / "kf.py"
    path.write_text(_text("mpt3d_b", "kf", {}))
    module = load_python(path)
    floor = keeping_nothing(module.run)
    zs = np.random.default_rng(3).normal(size=(50, 1))
    assert floor(zs, np.zeros(2), np.eye(2)) == (None, None)
    with pytest.raises(NumericalError, match=r"^step 0: S is not positive definite"):
        floor(zs, np.zeros(2), -np.eye(2))


def test_the_bench_limit_needs_a_single_track_loop(tmp_path):
    path = tmp_path / "udkf.py"
    path.write_text(_text("mpt3d_b", "udkf", {}))
    with pytest.raises(Skip, match="no single-track loop"):
        keeping_nothing(load_python(path).run)


def test_the_bench_prints_the_limit_beside_the_python_bar(tmp_path):
    """The generated Python row of a case carries its loop keeping nothing (seconds per
    step, timed as the row); the Python bar's note names it."""
    case = Case("kf", "mpt3d_b", 3)
    floor = bench_run._python_floor(case, make_data(case, 20), tmp_path, 20, 1)
    assert floor is not None and floor > 0.0
    row = bench_run.Row(case.label, "generated Python", None, None, None, floor=floor)
    assert "keeping nothing" in bench_run._floor_note(row)
    assert bench_run._floor_note(None) == ""
