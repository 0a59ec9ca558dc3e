"""The predictor's C run carries identical blocks in vector lanes too (derive.runs.blocks):
it starts from init's x_init as the scalar run, takes the two-step pass, and is bitwise
the scalar C99 run (-D DERIVE_VECTOR=0) under every build setting; both branches
compile with the strict flags. The smoother and the UDKF keep the scalar run (reasons in
derive.runs.blocks.LANE_KINDS and docs/performance.md)."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from test_perf_block_lanes import FLAGS, SCALAR, _data, _pair

from derive import catalog
from derive.emit import c_vector
from derive.generation import render_filter

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
MODELS = ("mpt3d_a", "gps_static")


@pytest.mark.parametrize("model_name", MODELS)
def test_the_predictor_run_starts_its_lanes_from_init(model_name):
    c = render_filter(catalog.load(model_name), "pred", "c")["pred.c"]
    assert f"#define {c_vector.SWITCH} 1" in c
    vector = c[c.index("#if DERIVE_VECTOR\n    double x_init"):]
    vector = vector[:vector.index("#else")]
    assert f"{model_name}_pred_init(x0, x_init);" in vector
    assert "x_init[0]" in vector.split("for (k = 0;")[0]


@needs_gcc
@pytest.mark.parametrize("flags", list(FLAGS))
@pytest.mark.parametrize("model_name", MODELS)
def test_the_predictor_vector_run_is_bitwise_the_scalar_run(tmp_path, model_name, flags):
    vector, scalar = _pair(tmp_path, model_name, "pred", FLAGS[flags])
    z, x0, _ = _data(model_name)
    for steps in (len(z), len(z) - 1, 1):   # odd, even, a single step
        got, want = vector.c.run(z[:steps], x0), scalar.c.run(z[:steps], x0)
        assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), steps


@needs_gcc
@pytest.mark.parametrize("model_name", MODELS)
@pytest.mark.parametrize("flags", [(), SCALAR, ("-march=native",), ("-march=native", *SCALAR)])
def test_both_predictor_branches_compile_with_the_strict_flags(tmp_path, model_name, flags):
    files = render_filter(catalog.load(model_name), "pred", "c")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    proc = subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror",
                           "-pedantic", *flags, "-c", str(tmp_path / "pred.c"),
                           "-o", str(tmp_path / "a.o")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("filter_name", ["rts", "udkf"])
def test_the_smoother_and_the_udkf_keep_the_scalar_run(filter_name):
    c = render_filter(catalog.load("mpt3d_a"), filter_name, "c")[f"{filter_name}.c"]
    assert c_vector.OPEN not in c
