"""The C run carrying a step's identical blocks in the lanes of one vector
(derive.runs.blocks, derive.emit.c_lanes): the same bits as the scalar C99 run
(-D DERIVE_VECTOR=0) under every build setting, the same status when a check fails, both
branches compiled by the strict flags, and the header's counts those of the scalar
operations. No speed is asserted (derive bench prints it)."""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import replace

import numpy as np
import pytest
import sympy
from conftest import AXIS_VALUES, LinearModel, dt, sq2, sr2

from derive import catalog
from derive.emit import c_vector
from derive.emit.render import _lowered
from derive.errors import NumericalError
from derive.flops import count_lowered
from derive.generation import command_unit, render_filter
from derive.lowering import LoweredAssign
from derive.pipeline import load_generated
from derive.runs import blocks, kinds
from derive.structure import find_blocks
from derive.trees import Const, Op

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SCALAR = ("-DDERIVE_VECTOR=0",)
#: Build settings: the strict flags with AVX (vector registers that hold four doubles, so
#: the vector run compiles; no hardware fma: a product and a sum), the native target (the
#: hardware's vector fma), contraction asked for on the command line, GNU C, and a
#: DERIVE_FMA of the build's own (the vector fma lane by lane).
FLAGS = {"plain": ("-mavx",), "native": ("-O3", "-march=native"),
         "contract": ("-O3", "-march=native", "-ffp-contract=fast"),
         "gnu": ("-O3", "-march=native", "-std=gnu99"),
         "own_fma": ("-O2", "-march=native", "-DDERIVE_FMA(a,b,c)=fma((a),(b),(c))")}
#: Filters whose run carries identical blocks (three axes: mpt3d_a, gps_static):
#: time-varying, information, joint and steady-state kinds, with and without the
#: two-step pass.
CASES = [("mpt3d_a", "kf"), ("mpt3d_a", "sskf"), ("mpt3d_a", "jklf"), ("mpt3d_a", "sslf"),
         ("gps_static", "kf"), ("gps_static", "sskf"), ("gps_static", "lf"),
         ("gps_static", "ikf")]
STEPS = 157   # odd: the steady filters' two-step pass and its last single step


def _data(model_name: str, seed: int = 5):
    num = catalog.load(model_name).numeric()
    rng = np.random.default_rng(seed)
    n, m = len(num.x0), np.shape(num.H)[0]
    z = rng.normal(size=(STEPS, m)) * 10
    x0 = np.asarray(num.x0, float) + rng.normal(size=n)
    P0 = np.asarray(num.P0, float) * (1 + rng.random())
    return z, x0, P0


def _run(module, covariance: bool, z, x0, P0):
    if covariance:
        xs, Ps = module.run(z, x0, P0)
        return [xs, Ps]
    return [module.run(z, x0)]


def _pair(tmp_path, model_name, filter_name, flags=()):
    """(vector build, scalar build) of one filter."""
    vector = load_generated(model_name, filter_name, {}, "c", tmp_path / "vector",
                            extra_cflags=flags)
    scalar = load_generated(model_name, filter_name, {}, "c", tmp_path / "scalar",
                            extra_cflags=flags + SCALAR)
    return vector, scalar


@pytest.mark.parametrize("model_name, filter_name", CASES)
def test_the_run_of_identical_blocks_is_emitted_in_vector_lanes(model_name, filter_name):
    c = render_filter(catalog.load(model_name), filter_name, "c")[f"{filter_name}.c"]
    assert f"#define {c_vector.SWITCH} 1" in c
    assert re.search(r"\n#if DERIVE_VECTOR\n.*?#else\n.*?#endif\n}", c,
                     flags=re.S)


@needs_gcc
@pytest.mark.parametrize("flags", list(FLAGS))
@pytest.mark.parametrize("model_name, filter_name", CASES)
def test_the_vector_run_is_bitwise_the_scalar_run(tmp_path, model_name, filter_name, flags):
    vector, scalar = _pair(tmp_path, model_name, filter_name, FLAGS[flags])
    assert f"#define {c_vector.SWITCH} 1" in (
        tmp_path / "vector" / model_name / f"{filter_name}.c").read_text()
    covariance = "P0" in {a.name for a in vector.c.functions["run"].arguments}
    z, x0, P0 = _data(model_name)
    got = _run(vector.c, covariance, z, x0, P0)
    want = _run(scalar.c, covariance, z, x0, P0)
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))


@needs_gcc
@pytest.mark.parametrize("failing", [(1,), (2, 1), (0, 2)])
def test_a_failed_check_returns_the_scalar_runs_status(tmp_path, failing):
    vector, scalar = _pair(tmp_path, "mpt3d_a", "kf")
    z, x0, P0 = _data("mpt3d_a")
    for axis in failing:  # S of these axes negative at the first step
        P0[2 * axis:2 * axis + 2, 2 * axis:2 * axis + 2] = -100 * np.eye(2)
    errors = []
    for module in (vector.c, scalar.c):
        with pytest.raises(NumericalError, match="not positive") as error:
            module.run(z, x0, P0)
        errors.append(str(error.value))
    assert errors[0] == errors[1]
    assert f"pivot {min(failing)} " in errors[0]


@needs_gcc
@pytest.mark.parametrize("model_name, filter_name", CASES)
@pytest.mark.parametrize("flags", [(), SCALAR, ("-march=native",), ("-march=native", *SCALAR),
                                   ("-march=x86-64",)])
def test_both_branches_compile_with_the_strict_flags(tmp_path, model_name, filter_name, flags):
    files = render_filter(catalog.load(model_name), filter_name, "c")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    proc = subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror",
                           "-pedantic", *flags, "-c", str(tmp_path / f"{filter_name}.c"),
                           "-o", str(tmp_path / "a.o")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def _steps(model_name: str, filter_name: str):
    """(the step as the header counts it, the step the run loop executes: without the
    zero checks of P, which run makes once on P0)."""
    unit = command_unit(catalog.load(model_name), filter_name)
    step = _lowered(unit, True)["step"]
    return step, step.without_pattern_checks()


def _split(model_name: str, filter_name: str):
    step = _steps(model_name, filter_name)[1]
    return step, blocks.split(step)


@pytest.mark.parametrize("model_name, filter_name", CASES)
def test_the_counts_are_the_scalar_operations_of_every_block(model_name, filter_name):
    step, lanes = _split(model_name, filter_name)
    assert lanes is not None
    block = count_lowered(lanes.block).as_dict()
    assert {kind: lanes.lanes * value for kind, value in block.items()} == \
        count_lowered(step).as_dict()
    c = render_filter(catalog.load(model_name), filter_name, "c")[f"{filter_name}.c"]
    header_step = _steps(model_name, filter_name)[0]
    assert f"operations per call of step (C99, fma through DERIVE_FMA and DERIVE_FNMA): " \
           f"{count_lowered(header_step).summary()}" in c
    assert f"run: the {lanes.lanes} identical blocks of the step in the lanes" in c


def test_the_lanes_pass_marks_the_run_with_every_calls_blocks():
    """derive.runs.blocks.in_lanes on mpt3d_a's steady filter (its two-step pass: step and
    pass in one loop, the step again for an odd last step): each call's blocks are the
    model's blocks, the vector the next power of two wide, every carried element in one
    lane of one carried vector; a run kind it does not serve is left unmarked."""
    model = catalog.load("mpt3d_a")
    unit = command_unit(model, "sskf")
    lowered = _lowered(unit, True)
    two = kinds.two_step_map(unit, True)
    run = kinds.two_steps(kinds.stepping(unit, lowered), unit)
    laned = blocks.in_lanes(run, unit.kind, lowered | {"pass": two})
    count = len(find_blocks(model))
    assert laned.lanes.width == 1 << (count - 1).bit_length()
    assert {name: split.lanes for name, split in laned.lanes.blocks} == \
        {"step": count, "pass": count}
    held = sorted(g for _, table in laned.lanes.carried for g in table)
    assert held == list(range(unit.n))
    assert [len(outputs) for _, outputs in laned.lanes.sources] == \
        [len(laned.lanes.carried)] * 2
    assert blocks.in_lanes(run, "smoother", lowered | {"pass": two}) is None


def test_blocks_that_differ_in_one_constant_are_not_put_in_lanes():
    step, lanes = _split("mpt3d_a", "sskf")
    assert lanes is not None and lanes.lanes == 3
    body = list(step.body)
    last = max(i for i, s in enumerate(body) if isinstance(s, LoweredAssign))

    def bumped(tree):
        if isinstance(tree, Const):
            return Const(np.nextafter(tree.value, np.inf))
        if isinstance(tree, Op):
            return Op(tree.kind, tuple(bumped(a) for a in tree.args))
        return tree

    body[last] = LoweredAssign(body[last].target, bumped(body[last].tree))
    assert blocks.split(replace(step, body=tuple(body))) is None


@pytest.mark.parametrize("model_name, filter_name", [("mpt3d_b", "kf"), ("cv", "sskf"),
                                                     ("gsm2d_a", "kf"), ("gsm2d_a", "sskf")])
def test_fewer_than_three_blocks_keep_the_scalar_run(model_name, filter_name):
    assert _split(model_name, filter_name)[1] is None
    c = render_filter(catalog.load(model_name), filter_name, "c")[f"{filter_name}.c"]
    assert c_vector.OPEN not in c


def _three_axes_with_parameters():
    """Three MPT3D axes with the free parameters dt, sq2, sr2 (p) and P0 pattern zero:
    the blocks share the statements of the parameters alone (0.25 dt^2 sq2, ...)."""
    F, G, H = sympy.zeros(6, 6), sympy.zeros(6, 3), sympy.zeros(3, 6)
    for a in range(3):
        F[2 * a, 2 * a] = F[2 * a + 1, 2 * a + 1] = 1
        F[2 * a, 2 * a + 1] = dt
        G[2 * a, a], G[2 * a + 1, a] = dt / 2, 1
        H[a, 2 * a], H[a, 2 * a + 1] = 1, dt
    return LinearModel("axes3", ["s1", "v1", "s2", "v2", "s3", "v3"], ["z1", "z2", "z3"],
                       F.tolist(), H.tolist(), (sq2 * sympy.eye(3)).tolist(),
                       (sr2 * sympy.eye(3)).tolist(), G=G.tolist(), values={},
                       P0_pattern="zero", parameters=[dt, sq2, sr2])


@needs_gcc
@pytest.mark.parametrize("flags", ["plain", "native"])
def test_blocks_sharing_statements_of_the_parameters_are_bitwise_the_scalar_run(tmp_path,
                                                                                flags):
    model = _three_axes_with_parameters()
    lanes = blocks.split(_lowered(command_unit(model, "kf"), True)["step"]
                              .without_pattern_checks())
    assert lanes is not None and lanes.lanes == 3 and lanes.shared
    runs = []
    for where, extra in (("vector", ()), ("scalar", SCALAR)):
        generated = load_generated(model, "kf", {}, "c", tmp_path / where,
                                   extra_cflags=FLAGS[flags] + extra)
        rng = np.random.default_rng(8)
        p = np.array([float(AXIS_VALUES[name]) for name in generated.unit.parameters])
        runs.append(generated.c.run(rng.normal(size=(STEPS, 3)) * 10, rng.normal(size=6),
                               np.eye(6) * 2.0, p=p))
    for a, b in zip(*runs):
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))
