"""Generation linear in the blocks (derive.filters.blockwise): a model of k independent
axes costs exactly k times one axis, filters like the NumPy reference, is the whole-model
derivation up to naming and order, and generates at 120 axes (a hang guard, not a speed
assertion: the times are printed by ``derive bench``)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from derive import LinearModel, catalog
from derive.apps.bench.costs.generation_scaling import (
    generation_bars,
    generation_rows,
    generation_table,
)
from derive.emit.python_printer import python_function
from derive.filters import FILTERS, available, derive_unit
from derive.filters.blockwise import independent_blocks
from derive.filters.kf import _time_varying_step, kf_update
from derive.filters.lf import lf_update
from derive.flops import count
from derive.modelfile import MAX_BLOCK_SIZE, MAX_STATES, load_model_file
from derive.options import validate
from derive.pipeline import load_generated
from derive.staging import PivotMessage
from derive.statements import PRESENT, ZERO, Check

ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD = 240  # seconds for one 120-axis generation; it takes a few on an idle machine
TIME_VARYING = ("kf", "lf", "jklf", "ikf")
STEADY = ("sskf", "sslf", "jssklf", "pred")


def axes(k: int, model: str = "cv") -> LinearModel:
    """``k`` copies of one catalog axis, block diagonal (the axes share its symbols)."""
    axis = catalog.load(model)
    return LinearModel.compose(f"{model}_x{k}", [axis] * k, [f"_{i}" for i in range(k)])


def _counts(unit) -> dict[tuple[str, str], dict[str, int]]:
    programs = dict(unit.programs)
    if unit.lookahead is not None:
        programs["lookahead"] = unit.lookahead
    return {(name, lang): count(prog, lang).as_dict()
            for name, prog in programs.items() for lang in ("python", "c")}


def _zero_checks(program) -> int:
    return sum(1 for c in program.body if isinstance(c, Check) and c.relation == ZERO)


@pytest.mark.parametrize("name", TIME_VARYING + STEADY)
@pytest.mark.parametrize("k", [2, 7])
def test_k_axes_cost_exactly_k_times_one_axis(name, k):
    """Every kind of operation k times one axis's; the comparisons also hold the zero
    checks of P's entries between the axes (those outside the closed pattern)."""
    axis = derive_unit(catalog.load("cv"), name)
    unit = derive_unit(axes(k), name)
    n, nb = unit.n, axis.n
    between = (n * (n + 1) - k * nb * (nb + 1)) // 2 if FILTERS[name].covariance else 0
    assert "step" in axis.programs and _zero_checks(axis.programs["step"]) == 0
    assert _zero_checks(unit.programs["step"]) == between
    expected = {key: {kind: k * v for kind, v in kinds.items()}
                for key, kinds in _counts(axis).items()}
    for lang in ("python", "c"):
        expected["step", lang]["cmp"] += between
    assert _counts(unit) == expected


@pytest.mark.parametrize("name", TIME_VARYING)
def test_different_blocks_cost_the_sum_of_their_counts(name):
    blocks = [catalog.load(m) for m in ("cv", "ca", "cv")]
    model = LinearModel.compose("mixed", blocks, ["_a", "_b", "_c"])
    expected = Counter()
    for block in blocks:
        for lang in ("python", "c"):
            expected.update({(lang, kind): v for kind, v in
                             count(derive_unit(block, name).programs["step"], lang)
                             .as_dict().items()})
    step = derive_unit(model, name).programs["step"]
    got = Counter()
    for lang in ("python", "c"):
        got.update({(lang, kind): v for kind, v in count(step, lang).as_dict().items()})
        expected[lang, "cmp"] += _zero_checks(step)  # P's entries between the blocks
    n = model.n
    assert _zero_checks(step) == (n * (n + 1) - sum(b.n * (b.n + 1) for b in blocks)) // 2
    assert +got == +expected


def _checked_like(whole, step, model):
    """The whole derivation with the NaN checks of z that the unit appends to each step
    without the option missing (derive.filters.unit.checked_measurements), in the step's
    words, so both programs carry the same checks."""
    present = [c for c in step.body if isinstance(c, Check) and c.relation == PRESENT]
    return (whole.with_presence_checks("z", model.measurements, present[0].message)
            if present else whole)


def test_blockwise_step_is_the_whole_derivation_up_to_naming_and_order():
    """The same operations, checks, pattern and outputs as deriving the whole model at
    once (the path every model took before): counts by kind, the zero checks' elements,
    the pivot messages, and the step's values on random inputs (1e-14 relative)."""
    model = LinearModel.compose("mixed", [catalog.load(m) for m in ("ca", "cv")],
                                ["_a", "_b"])
    step = derive_unit(model, "kf").programs["step"]
    whole, _ = _time_varying_step(model, lambda *a: kf_update(*a), "Kalman filter",
                                  model.P0_pattern)
    whole = _checked_like(whole, step, model)
    for lang in ("python", "c"):
        assert count(step, lang) == count(whole, lang)

    def checks(program):
        zero = sorted(str(c.value) for c in program.body
                      if isinstance(c, Check) and c.relation == ZERO)
        pivots = sorted(str(c.message) for c in program.body
                        if isinstance(c, Check) and c.relation not in (ZERO, PRESENT))
        return zero, pivots

    assert checks(step) == checks(whole)
    assert len(checks(step)[1]) == model.m  # one pivot per measurement, named globally
    rng = np.random.default_rng(3)
    A = rng.normal(size=(model.n, model.n))
    inputs = (rng.normal(size=model.n), A @ A.T + np.eye(model.n), rng.normal(size=model.m))
    mask = np.array(derive_unit(model, "kf").programs["step"].results["P_new"]) != 0
    inputs = (inputs[0], np.where(mask.reshape(model.n, model.n), inputs[1], 0.0), inputs[2])
    outs = [_python_step(prog)(*inputs) for prog in (step, whole)]
    for a, b in zip(*outs):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)


def _python_step(program):
    function = python_function(program)

    def call(x, P, z):
        return [np.asarray(v, dtype=float) for v in function(list(x), list(np.ravel(P)),
                                                               list(z))]
    return call


def test_pivot_messages_name_the_row_of_the_whole_model():
    message = PivotMessage("S", 1, "LDL^T", "measurements")
    assert str(message) == ("S is not positive definite: pivot 1 of its LDL^T "
                            "factorisation is not positive")
    assert message.renumbered({"measurements": (4, 9), "states": (0, 1)}).pivot == 9
    assert PivotMessage("S", 1, "LDL^T").renumbered({"measurements": (4, 9)}).pivot == 1


def test_models_that_do_not_split_are_derived_whole():
    assert independent_blocks(catalog.load("mpt3d_b"), "zero") is None
    assert independent_blocks(axes(3), "dense") is None
    assert len(independent_blocks(axes(3), "zero")) == 3


@pytest.mark.parametrize("name", TIME_VARYING + ("sskf", "sslf", "jssklf"))
def test_blockwise_filters_match_the_numpy_reference(name):
    """Three different blocks (one of them twice): the generated Python run against the
    family's NumPy reference, 1e-12 relative over 60 steps."""
    blocks = [catalog.load(m) for m in ("cv", "ca", "cv")]
    model = LinearModel.compose("mixed", blocks, ["_a", "_b", "_c"])
    generated = load_generated(model, name, None, "python")
    zs = np.random.default_rng(11).normal(size=(60, model.m))
    num = model.numeric()
    spec = FILTERS[name]
    ref_xs, ref_Ps = spec.reference(model, zs, validate(name))
    if spec.covariance:
        xs, Ps = generated.python.run(zs, num.x0, num.P0)
        np.testing.assert_allclose(np.asarray(Ps), ref_Ps, rtol=1e-12,
                                   atol=1e-12 * np.abs(ref_Ps).max())
    else:
        xs = generated.python.run(zs, num.x0)
    np.testing.assert_allclose(np.asarray(xs), ref_xs, rtol=1e-12,
                               atol=1e-12 * np.abs(ref_xs).max())


def test_bench_generation_rows_measure_a_process_each():
    """The bench part (derive.apps.bench.costs.generation_scaling) on two tiny models: times,
    peak memory and the step's flops, which are the unit's own count."""
    rows = generation_rows(axes=(2,), filters=("kf",), dense=False)
    assert [(r.model, r.filter, r.states) for r in rows] == [("2 CV axes", "kf", 4)]
    row = rows[0]
    assert row.note == "" and row.seconds > 0 and row.cpu_seconds > 0 and row.peak_bytes > 0
    expected = count(derive_unit(axes(2, "mpt3d_b"), "kf").programs["step"], "c").flops
    assert row.flops == expected
    head, body = generation_table(rows)
    assert len(body[0]) == len(head)
    bars = generation_bars(rows)
    assert [b[0].split(" for ")[0] for b in bars] == ["generating kf"]


# -- model files: states bounded by the part a filter derives at once --------------------

def _cli(args, cwd, timeout=HANG_GUARD):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DERIVE_PROGRESS", None)
    return subprocess.run([sys.executable, "-m", "derive", "generate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env,
                          stdin=subprocess.DEVNULL)


def _axes_file(path: Path, k: int) -> Path:
    blocks = ", ".join(f'{{ model = "mpt3d_b", suffix = "_{i}" }}' for i in range(k))
    path.write_text(f'[model]\nname = "{path.stem}"\n[compose]\nblocks = [{blocks}]\n')
    return path


def _one_line_refusal(result, *words):
    assert result.returncode == 2, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, lines
    for word in words:
        assert word in lines[0], lines[0]


LARGE = ("kf", "lf", "sskf")
"""The filters generated at 120 axes: before block-by-block derivation the KF took minutes,
the LF longer."""


@pytest.fixture(scope="module")
def axes_120(tmp_path_factory):
    """One ``derive generate`` of a model file of 120 constant-velocity axes (n = 240)
    with every filter of LARGE, in a subprocess: a hang guard (not a speed assertion) of
    HANG_GUARD seconds a filter."""
    k = 120  # the issue's case: n = 240
    assert k * catalog.load("mpt3d_b").n <= MAX_STATES
    tmp = tmp_path_factory.mktemp("axes_120")
    path = _axes_file(tmp / "axes.toml", k)
    filters = [arg for name in LARGE for arg in ("--filter", name)]
    result = _cli([path.name, *filters, "--out", "out"], tmp, len(LARGE) * HANG_GUARD)
    return result, tmp / "out" / "axes"


@pytest.mark.parametrize("name", LARGE)
def test_a_model_file_of_120_axes_generates(axes_120, name):
    result, out = axes_120
    assert result.returncode == 0, result.stderr
    assert sorted(p.suffix for p in out.glob(f"{name}.*")) == [".c", ".h", ".py"]
    assert "n: 240 (states)" in (out / f"{name}.py").read_text()


def test_a_model_file_is_bounded_by_the_part_derived_at_once(tmp_path):
    """Over MAX_BLOCK_SIZE states in one part: a filter derived whole (udkf), a dense P0
    pattern, are refused in one line; unnamed, they are left out of "all that apply"."""
    k = MAX_BLOCK_SIZE // 2 + 1
    path = _axes_file(tmp_path / "axes.toml", k)
    _one_line_refusal(_cli([path.name, "--filter", "udkf", "--out", "o1"], tmp_path),
                      "axes.toml: filter 'udkf'", f"{2 * k} states",
                      "derives the model whole", f"limit of {MAX_BLOCK_SIZE}")
    _one_line_refusal(_cli([path.name, "--filter", "kf", "--P0-pattern", "dense", "--out",
                            "o2"], tmp_path),
                      "axes.toml: filter 'kf'", "P0 pattern dense", f"limit of {MAX_BLOCK_SIZE}")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    # which filters are written is the claim, not their languages: the Python alone
    result = _cli([path.name, "--lang", "python", "--out", "all"], tmp_path)
    assert result.returncode == 0, result.stderr
    written = {p.stem for p in (tmp_path / "all" / "axes").glob("*.py")}
    model = load_model_file(path)
    assert written == {name for name in available(model) if FILTERS[name].blockwise}
    assert {"udkf", "rts", "fir"}.isdisjoint(written)


def test_a_coupled_block_larger_than_the_bound_is_refused_when_loaded(tmp_path):
    n = MAX_BLOCK_SIZE + 1
    F = [[1 if j in (i, i + 1) else 0 for j in range(n)] for i in range(n)]
    H = [[1 if j == i else 0 for j in range(n)] for i in range(n)]
    Q = H
    names = ", ".join(f'"s{i}"' for i in range(n))
    measured = ", ".join(f'"z{i}"' for i in range(n))
    path = tmp_path / "chain.toml"
    path.write_text(f'[model]\nname = "chain"\nstates = [{names}]\nmeasurements = [{measured}]\n'
                    f"[discrete]\nF = {F}\nH = {H}\nQ = {Q}\nR = {Q}\n")
    _one_line_refusal(_cli([path.name, "--filter", "sskf", "--out", "out"], tmp_path),
                      "chain.toml: [model] states", f"largest independent block has {n}",
                      f"limit of {MAX_BLOCK_SIZE}")


@pytest.mark.parametrize("name, options", [
    ("kf", {"missing": True}), ("kf", {"joseph": True}), ("lf", {"missing": True})])
def test_options_give_the_whole_derivations_counts(name, options):
    model = LinearModel.compose("mixed", [catalog.load(m) for m in ("ca", "cv", "ca")],
                                ["_a", "_b", "_c"])
    update = kf_update if name == "kf" else lf_update
    whole, _ = _time_varying_step(model, lambda *a: update(*a, **{
        k: v for k, v in options.items() if k in ("missing", "joseph")}), "filter",
        model.P0_pattern)
    step = derive_unit(model, name, options).programs["step"]
    whole = _checked_like(whole, step, model)
    for lang in ("python", "c"):
        assert count(step, lang) == count(whole, lang)


def test_blocks_sharing_free_parameters_share_them_as_before():
    """Free parameters shared by the blocks: the assembled step is optimised as a whole,
    so the parameters' expressions are computed once (fewer flops than k times one block),
    exactly the whole derivation's counts, and the same values."""
    def axis(name, q):
        return LinearModel(name, ["s", "v"], ["z"], [[1, "dt"], [0, 1]], [[1, 0]], [[q]],
                           [["r"]], G=[["dt**2/2"], ["dt"]], P0_pattern="zero",
                           parameters=["dt", q, "r"])

    model = LinearModel.compose("shared", [axis("a", "q"), axis("b", "q2"), axis("a", "q")],
                                ["_a", "_b", "_c"])
    step = derive_unit(model, "kf").programs["step"]
    whole, _ = _time_varying_step(model, lambda *a: kf_update(*a), "filter", "zero")
    whole = _checked_like(whole, step, model)
    one = derive_unit(axis("a", "q"), "kf").programs["step"]
    assert count(step, "c") == count(whole, "c")
    assert count(step, "c").flops < 3 * count(one, "c").flops
    rng = np.random.default_rng(1)
    P = np.zeros((model.n, model.n))
    for b in range(3):
        A = rng.normal(size=(2, 2))
        P[2 * b:2 * b + 2, 2 * b:2 * b + 2] = A @ A.T + np.eye(2)
    args = (list(rng.normal(size=model.n)), list(P.ravel()), list(rng.normal(size=model.m)),
            list(rng.uniform(0.01, 1.0, size=len(model.parameters))))
    for a, b in zip(python_function(step)(*args), python_function(whole)(*args)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)
