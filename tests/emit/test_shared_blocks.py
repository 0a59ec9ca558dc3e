"""derive.runs.shared: a step of identical blocks whose carried elements that read
no data start bitwise equal computes those statements once in the single-track Python run.
Its rows must be bitwise those of calling ``step`` once per step, whichever loop runs;
a failed check must give the full step's message; blocks that differ share nothing."""

from __future__ import annotations

import ast
import struct
from types import SimpleNamespace

import numpy as np
import pytest
import sympy
from _loop_ast import outside_raises, single_track_branch

from derive import catalog
from derive.errors import NumericalError
from derive.flops import count_lowered
from derive.generation import command_unit, render_filter
from derive.lowering import LoweredAssign, lower_program
from derive.model import LinearModel
from derive.pipeline import load_generated
from derive.reference import linear as reference
from derive.runs.shared import shared_step
from derive.structure import find_blocks
from derive.trees import tree_vars

CATALOG = [("mpt3d_a", "kf"), ("mpt3d_a", "lf"), ("mpt3d_a", "jklf"), ("gsm2d_a", "kf"),
           ("gps_static", "ikf"), ("gps_static", "kf")]


def _stepped(module, zs, x0, P0, p=None):
    """``step`` called once per step: the full step, every block computed."""
    x, P = list(x0), list(np.asarray(P0).reshape(-1))
    xs, Ps = [], []
    for z in zs:
        x, P = module.step(x, P, z) if p is None else module.step(x, P, z, p)
        xs.append(x)
        Ps.append(P)
    n = len(x0)
    return np.array(xs), np.array(Ps).reshape(-1, n, n)


def _recording_struct(module) -> list[str]:
    """Replace the module's ``struct`` by one that records each row format the run packs
    (the shared loop packs fewer distinct values per row than the full one)."""
    formats: list[str] = []

    def make(fmt: str):
        formats.append(fmt)
        return struct.Struct(fmt)

    module.struct = SimpleNamespace(Struct=make)
    return formats


def _block_starts(model, rng, equal: bool) -> np.ndarray:
    """A symmetric positive definite P0 of ``model``'s blocks: the same block on every axis
    (``equal``) or a different one each."""
    blocks = find_blocks(model)
    P0 = np.zeros((model.n, model.n))
    A = rng.normal(size=(len(blocks[0].states),) * 2)
    for block in blocks:
        if not equal:
            A = rng.normal(size=A.shape)
        s = block.states
        P0[np.ix_(s, s)] = A @ A.T + np.eye(len(s))
    return P0


@pytest.mark.parametrize("model_name, name", CATALOG)
@pytest.mark.parametrize("equal", [True, False])
def test_the_run_is_step_by_step_bitwise_whichever_loop_runs(model_name, name, equal):
    model = catalog.load(model_name)
    module = load_generated(model_name, name, lang="python").python
    formats = _recording_struct(module)
    rng = np.random.default_rng(17)
    zs = rng.normal(size=(400, model.m)) * 3.0
    x0 = rng.normal(size=model.n)
    P0 = _block_starts(model, rng, equal)
    xs, Ps = module.run(zs, x0, P0)
    xr, Pr = _stepped(module, zs, x0, P0)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)
    # the equal start took the shared loop (fewer distinct values per row: one block's
    # covariance), the other the full one (every block's)
    assert len(formats) == 1
    kept = struct.calcsize(formats[0]) // 8
    full = model.n + sum(len(b.states) * (len(b.states) + 1) // 2 for b in find_blocks(model))
    assert (kept < full) if equal else (kept >= full)


def test_the_catalog_start_takes_the_shared_loop_and_matches_the_reference():
    """mpt3d_a from its catalog start (P0 = 0: equal blocks) against the NumPy reference."""
    model = catalog.load("mpt3d_a")
    num = model.numeric()
    module = load_generated("mpt3d_a", "kf", lang="python").python
    formats = _recording_struct(module)
    zs = np.random.default_rng(3).normal(size=(500, 3))
    xs, Ps = module.run(zs, num.x0, num.P0)
    assert struct.calcsize(formats[0]) // 8 < 6 + 21
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)
    assert np.max(np.abs(xs - xr)) <= 1e-12 * np.max(np.abs(xr))
    assert np.max(np.abs(Ps - Pr)) <= 1e-12 * np.max(np.abs(Pr))


def test_a_signed_zero_is_not_equal():
    """The start is compared bit for bit: -0.0 and 0.0 blocks take the full loop (whose
    results, here, are the same)."""
    module = load_generated("mpt3d_a", "kf", lang="python").python
    formats = _recording_struct(module)
    P0 = np.zeros((6, 6))
    P0[2, 2] = -0.0
    zs = np.random.default_rng(4).normal(size=(50, 3))
    xs, Ps = module.run(zs, np.zeros(6), P0)
    assert struct.calcsize(formats[0]) // 8 == 16
    xr, Pr = _stepped(module, zs, np.zeros(6), P0)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)


@pytest.mark.parametrize("later_block", [-10.0, -11.0])
def test_a_failed_shared_check_gives_the_full_steps_message(later_block):
    """Blocks starting indefinite fail the first pivot at step 0: the shared loop (equal
    blocks) and the full loop (the later blocks differ) raise the same message."""
    module = load_generated("mpt3d_a", "kf", lang="python").python
    P0 = np.diag([-10.0, -10.0] + [later_block] * 4)
    with pytest.raises(NumericalError) as raised:
        module.run(np.zeros((5, 3)), np.zeros(6), P0)
    assert str(raised.value).startswith(
        "step 0: S is not positive definite: pivot 0 of its LDL^T factorisation")


def _cv_axes(axes: int, noise: tuple[int, ...] | None = None) -> LinearModel:
    """``axes`` constant-velocity axes, block diagonal, P0 pattern zero; dt, q and r free
    runtime parameters (the same elements of p in every block); axis a's process noise is
    ``noise[a]`` q (default: q on every axis, identical axes)."""
    dt, q, r = sympy.symbols("dt q r", real=True)  # no declared domain: no domain checks
    F1 = sympy.Matrix([[1, dt], [0, 1]])
    G1 = sympy.Matrix([[dt**2 / 2], [dt]])
    states = [f"{name}{a}" for a in range(axes) for name in ("s", "v")]
    return LinearModel(
        "cv_axes", states, [f"z{a}" for a in range(axes)],
        F=sympy.diag(*[F1] * axes), G=sympy.diag(*[G1] * axes),
        H=sympy.diag(*[sympy.Matrix([[1, 0]])] * axes),
        Q=q * sympy.diag(*(noise or (1,) * axes)), R=r * sympy.eye(axes),
        P0=sympy.zeros(2 * axes, 2 * axes), P0_pattern="zero", parameters=[dt, q, r])


def test_shared_parameters_are_shared_and_counts_unchanged():
    """Three axes reading the same free parameters (dt, q, r): the covariance of the first
    axis serves all three, bitwise; what it drops is the other axes' statements that read
    no data."""
    model = _cv_axes(3)
    module = load_generated(model, "kf", lang="python").python
    formats = _recording_struct(module)
    rng = np.random.default_rng(8)
    zs, x0 = rng.normal(size=(200, 3)), rng.normal(size=6)
    P0 = np.kron(np.eye(3), [[2.0, 0.3], [0.3, 1.0]])
    p = [0.1, 0.02, 0.5]
    xs, Ps = module.run(zs, x0, P0, p)
    xr, Pr = _stepped(module, zs, x0, P0, p)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)
    assert struct.calcsize(formats[0]) // 8 < 6 + 3 * 3
    one = command_unit(_cv_axes(1), "kf").programs["step"]
    three = command_unit(model, "kf").programs["step"]
    lowered = lower_program(three).without_pattern_checks()
    shared = shared_step(lowered, (("x", "x_new"), ("P", "P_new")))
    assert shared is not None
    block = lower_program(one).without_pattern_checks()
    # the two later axes drop every statement of theirs that reads no data (those of the
    # parameters alone are computed once for all axes already)
    data, parameters_alone = _statements_reading(block)
    assert shared.dropped == 2 * (len(block.body) - data - parameters_alone)
    assert len(shared.program.body) + shared.dropped == len(lowered.body)


def _statements_reading(lowered) -> tuple[int, int]:
    """Statements of a one-block step that read x or z (directly or through a statement
    that does), and statements that read the parameters alone."""
    data: set[str] = set()
    alone: set[str] = set()
    reading_data = reading_parameters_alone = 0
    for st in lowered.body:
        names = {v.base if v.index is not None else v.name for v in tree_vars(st.tree)}
        if names & ({"x", "z"} | data):
            reading_data += 1
            if isinstance(st, LoweredAssign):
                data.add(st.target)
        elif names <= {"p"} | alone:
            reading_parameters_alone += 1
            alone.add(st.target)
    return reading_data, reading_parameters_alone


def test_blocks_with_their_own_noise_share_nothing():
    """Axes with different process noise are not identical blocks: of three axes with
    noise q, 2q, q only the first and third share, and the second's covariance is its own."""
    model = _cv_axes(3, noise=(1, 2, 1))
    text = render_filter(model, "kf", "python", {})["kf.py"]
    condition = next(line for line in text.splitlines() if "tobytes() ==" in line)
    # the third axis's P elements (flat 28, 29, 35 of the 6 x 6) against the first's
    assert "[28, 29, 35]" in condition and "[0, 1, 7]" in condition
    module = load_generated(model, "kf", lang="python").python
    rng = np.random.default_rng(9)
    zs = rng.normal(size=(300, 3))
    P0 = np.kron(np.eye(3), [[1.0, 0.1], [0.1, 2.0]])
    p = [0.1, 0.02, 0.5]
    xs, Ps = module.run(zs, np.zeros(6), P0, p)
    xr, Pr = _stepped(module, zs, np.zeros(6), P0, p)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)
    assert not np.array_equal(Ps[:, 0:2, 0:2], Ps[:, 2:4, 2:4])
    np.testing.assert_array_equal(Ps[:, 0:2, 0:2], Ps[:, 4:6, 4:6])


@pytest.mark.parametrize("model_name, name", CATALOG)
def test_the_shared_loop_does_the_operations_of_the_shared_step(model_name, name):
    """The shared loop's float operators are those of the step with its shared statements
    once (one binary operator per counted add, sub, mul and div), fewer than the full
    loop's, which does the whole step's."""
    unit = command_unit(catalog.load(model_name), name)
    state = tuple(port for port, _ in unit.carried)
    lowered = lower_program(unit.programs["step"], state_ports=state).without_pattern_checks()
    shared = shared_step(lowered, unit.carried)
    assert shared is not None
    text = render_filter(catalog.load(model_name), name, "python", {})[f"{name}.py"]
    branch = single_track_branch(text)
    shared_loop = next(node for node in next(
        node for node in branch.body if isinstance(node, ast.If)).body
        if isinstance(node, ast.For))
    full_loop = next(node for node in branch.body if isinstance(node, ast.For))
    for loop, program in ((shared_loop, shared.program), (full_loop, lowered)):
        operators = [type(node.op) for node in outside_raises(loop)
                     if isinstance(node, ast.BinOp)]
        counted = count_lowered(program)
        assert (operators.count(ast.Add), operators.count(ast.Sub), operators.count(ast.Mult),
                operators.count(ast.Div)) == (counted.add, counted.sub, counted.mul,
                                              counted.div)
    assert count_lowered(shared.program).flops < count_lowered(lowered).flops

