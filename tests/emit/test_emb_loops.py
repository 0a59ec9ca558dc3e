"""The C run loops on the step printed once (derive.emit.c_loops): every statement of the
step appears once per file; run, run_tracks and step give the same bits (run_tracks' lanes
vectorised, under any contraction setting); --no-run and --no-run-tracks leave the
functions out and derive.build loads what is there. No speed is asserted."""

from __future__ import annotations

import collections
import re
import shutil
import subprocess

import numpy as np
import pytest
from conftest import AXIS_VALUES, axis_model

from derive import catalog, cli
from derive.apps.bench.costs import compile_size
from derive.build import build_c
from derive.emit import c_loops, c_printer
from derive.emit.c_loops import LANES, _element
from derive.errors import NumericalError
from derive.flops import count, count_c_function
from derive.generation import command_unit, render_filter
from derive.lowering import lower_program
from derive.pipeline import load_generated
from derive.runs.kinds import two_step_map

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

ONCE = [("mpt3d_a", "kf"), ("mpt3d_a", "lf"), ("mpt3d_a", "jklf"), ("mpt3d_a", "udkf"),
        ("mpt3d_a", "sskf"), ("mpt3d_a", "rts"), ("mpt3d_a", "fir"), ("mpt3d_a", "pred"),
        ("cv", "kf"), ("gnss_pseudorange", "ekf"), ("gnss_pseudorange", "ukf")]


def _distinct_step_lines(model_name: str, filter_name: str) -> list[tuple[str, str]]:
    """Statements of the step that no other program of the file prints, as (the line
    printed plainly, the line printed in the step body: elements strided)."""
    unit = command_unit(catalog.load(model_name), filter_name)
    step = lower_program(unit.programs["step"], use_fma=True).without_pattern_checks()
    others = [lower_program(p, use_fma=True) for name, p in unit.programs.items()
              if name != "step"]
    two = two_step_map(unit, True)
    others += [two] if two is not None else []
    elsewhere = {line for lp in others for element in (None, _element)
                 for line in c_printer.statements(lp, element=element)}
    return [(plain, strided) for plain, strided in zip(c_printer.statements(step),
                                                       c_printer.statements(step, element=_element))
            if plain.startswith("const double") and plain not in elsewhere
            and strided not in elsewhere]


@pytest.mark.parametrize("model_name, filter_name", ONCE)
def test_every_statement_of_the_step_is_printed_once_per_file(model_name, filter_name):
    lines = _distinct_step_lines(model_name, filter_name)
    assert lines, "no statement of the step to look for"
    c = render_filter(catalog.load(model_name), filter_name, "c")[f"{filter_name}.c"]
    counts = collections.Counter(line.strip() for line in c.splitlines())
    found = {strided: counts[strided] + (counts[plain] if plain != strided else 0)
             for plain, strided in lines}
    assert found == dict.fromkeys(found, 1)


# -- the same bits from step, run and run_tracks -------------------------------------------------

FLAGS = {"strict": (), "native": ("-O3", "-march=native"),
         "contract": ("-O3", "-march=native", "-ffp-contract=fast"),
         "gnu": ("-O3", "-march=native", "-std=gnu99")}
#: Enough tracks for two blocks of the widest lanes (AVX-512: 32) and a tail run by run.
TRACKS, STEPS = 2 * 32 + 5, 23


def _model(model_name: str):
    """A catalog model, or "axis": one MPT3D axis with free parameters (p = dt, sq2, sr2)."""
    return axis_model(values={}) if model_name == "axis" else catalog.load(model_name)


def _tracks(model_name: str, seed: int = 4, missing: bool = False):
    """(zs, x0s, P0s) of TRACKS tracks of a model, each with its own start."""
    model = _model(model_name)
    num = model.numeric(AXIS_VALUES if model.parameters else None)
    rng = np.random.default_rng(seed)
    n, m = len(num.x0), np.shape(num.H)[0]
    zs = rng.normal(size=(TRACKS, STEPS, m)) * 10
    if missing:
        zs[rng.random(zs.shape) < 0.2] = np.nan
    x0s = np.asarray(num.x0, float) + rng.normal(size=(TRACKS, n))
    P0s = np.repeat(np.asarray(num.P0, float)[None], TRACKS, axis=0) * (
        1 + rng.random(TRACKS))[:, None, None]
    return zs, x0s, P0s


CASES = [("mpt3d_b", "kf", {}), ("mpt3d_a", "kf", {}), ("mpt3d_b", "kf", {"missing": True}),
         ("mpt3d_a", "sskf", {}), ("mpt3d_b", "lf", {}), ("mpt3d_b", "jklf", {}),
         ("cv", "kf", {}), ("axis", "kf", {})]


@needs_gcc
@pytest.mark.parametrize("flags", list(FLAGS))
@pytest.mark.parametrize("model_name, filter_name, options", CASES)
def test_each_track_of_run_tracks_is_bitwise_its_own_run(tmp_path, model_name, filter_name,
                                                          options, flags):
    generated = load_generated(_model(model_name), filter_name, options, "c", tmp_path,
                               extra_cflags=FLAGS[flags])
    module = generated.c
    zs, x0s, P0s = _tracks(model_name, missing=options.get("missing", False))
    covariance = filter_name != "sskf"
    extra = ({"p": np.array([float(AXIS_VALUES[name]) for name in generated.unit.parameters])}
             if generated.unit.parameters else {})
    if covariance:
        xs, Ps = module.run_tracks(zs, x0s, P0s, **extra)
    else:
        xs = module.run_tracks(zs, x0s, **extra)
    for t in range(TRACKS):
        if covariance:
            x_run, P_run = module.run(zs[t], x0s[t], P0s[t], **extra)
            assert np.array_equal(Ps[t], P_run.reshape(Ps[t].shape)), t
        else:
            x_run = module.run(zs[t], x0s[t], **extra)
        assert np.array_equal(xs[t], x_run), t


@needs_gcc
@pytest.mark.parametrize("flags", ["strict", "contract"])
def test_run_is_bitwise_the_step_called_in_a_loop(tmp_path, flags):
    module = load_generated("mpt3d_a", "kf", {}, "c", tmp_path, extra_cflags=FLAGS[flags]).c
    zs, x0s, P0s = _tracks("mpt3d_a")
    xs, Ps = module.run(zs[0], x0s[0], P0s[0])
    x, P = x0s[0], P0s[0]
    for k in range(STEPS):
        x, P = module.step(x, P, zs[0, k])
        assert np.array_equal(x, xs[k]) and np.array_equal(P.reshape(-1), Ps[k].reshape(-1))


@needs_gcc
def test_a_failed_check_in_a_block_stops_run_tracks_as_it_stops_run(tmp_path):
    module = load_generated("mpt3d_b", "kf", {}, "c", tmp_path).c
    zs, x0s, P0s = _tracks("mpt3d_b")
    P0s[3] = -100 * np.eye(P0s.shape[1])      # S negative at the first step of track 3
    with pytest.raises(NumericalError, match="not positive") as run_error:
        module.run(zs[3], x0s[3], P0s[3])
    with pytest.raises(NumericalError, match="not positive") as tracks_error:
        module.run_tracks(zs, x0s, P0s)
    assert str(tracks_error.value).split(": ", 1)[1] == str(run_error.value).split(": ", 1)[1]


def _lane_loop_line(c: str) -> int:
    """The line number of the loop over a block's lanes (after the SIMD macro)."""
    lines = c.splitlines()
    return next(i + 2 for i, line in enumerate(lines) if line.strip() == "DERIVE_SIMD")


@needs_gcc
@pytest.mark.parametrize("model_name, filter_name", [("mpt3d_b", "kf"), ("mpt3d_a", "kf"),
                                                     ("mpt3d_a", "sskf")])
def test_the_compiler_vectorises_the_loop_over_the_lanes(tmp_path, model_name, filter_name):
    files = render_filter(catalog.load(model_name), filter_name, "c")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    c = files[f"{filter_name}.c"]
    proc = subprocess.run(["gcc", "-std=c99", "-O3", "-march=native", "-Wall", "-Wextra",
                           "-Werror", "-pedantic", "-fopt-info-vec-optimized", "-c",
                           str(tmp_path / f"{filter_name}.c"), "-o", str(tmp_path / "a.o")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    vectorised = {int(m) for m in re.findall(rf"{filter_name}\.c:(\d+):\d+: optimized: loop "
                                             "vectorized", proc.stderr)}
    assert _lane_loop_line(c) in vectorised, proc.stderr


@needs_gcc
@pytest.mark.parametrize("flags", [("-Wunknown-pragmas",), ("-fopenmp-simd",
                                   "-DDERIVE_SIMD=_Pragma(\"omp simd\")"), ("-fopenmp",),
                                   ("-DDERIVE_LANES=1",), ("-DDERIVE_LANES=3",)])
def test_the_loops_compile_with_the_strict_flags_however_simd_is_told(tmp_path, flags):
    files = render_filter(catalog.load("mpt3d_a"), "sskf", "c")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    proc = subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror",
                           "-pedantic", *flags, "-c", str(tmp_path / "sskf.c"), "-o",
                           str(tmp_path / "sskf.o")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# -- leaving functions out ----------------------------------------------------------------


def _prototypes(header: str) -> list[str]:
    return re.findall(r"^(?:int|void) (\w+)\(", header, flags=re.M)


def test_no_run_leaves_run_out_of_the_header_and_the_interface():
    model = catalog.load("mpt3d_b")
    both = render_filter(model, "kf", "c", {"run": False})
    assert _prototypes(both["kf.h"]) == ["mpt3d_b_kf_step", "mpt3d_b_kf_run_tracks"]
    assert '"mpt3d_b_kf_run"' not in both["kf.h"] and '"mpt3d_b_kf_run_tracks"' in both["kf.h"]
    assert "\nstatic int mpt3d_b_kf_run(" in both["kf.c"]   # run_tracks' last tracks
    neither = render_filter(model, "kf", "c", {"run": False, "run_tracks": False})
    assert _prototypes(neither["kf.h"]) == ["mpt3d_b_kf_step"]
    assert "_run" not in neither["kf.c"].split("*/", 1)[1]
    assert "_run" not in neither["kf.h"].split("derive-interface", 1)[1]


@needs_gcc
def test_build_loads_a_file_without_run(tmp_path):
    zs, x0s, P0s = _tracks("mpt3d_b")
    full = load_generated("mpt3d_b", "kf", {}, "c", tmp_path / "full").c
    tracks_only = load_generated("mpt3d_b", "kf", {"run": False}, "c", tmp_path / "t").c
    assert "run" not in tracks_only.functions
    for a, b in zip(tracks_only.run_tracks(zs, x0s, P0s), full.run_tracks(zs, x0s, P0s)):
        assert np.array_equal(a, b)
    assert cli.main(["generate", "mpt3d_b", "--filter", "kf", "--lang", "c", "--no-run",
                     "--no-run-tracks", "--out", str(tmp_path / "step")]) == 0
    written = sorted(p.name for p in (tmp_path / "step" / "mpt3d_b").iterdir())
    assert written == ["kf.c", "kf.h"]
    step_only = build_c(tmp_path / "step" / "mpt3d_b" / "kf.c", tmpdir=tmp_path / "cache")
    module = step_only["mpt3d_b_kf"]
    assert "run" not in module.functions and "run_tracks" not in module.functions
    x, P = module.step(x0s[0], P0s[0], zs[0, 0])
    assert np.array_equal(x, full.run(zs[0, :1], x0s[0], P0s[0])[0][0])


def test_the_lane_width_is_a_macro_the_build_may_set():
    c = render_filter(catalog.load("mpt3d_b"), "kf", "c")["kf.c"]
    assert f"#ifndef {LANES}" in c and f"t + {LANES} <= tracks" in c


# -- the bench's compile-size rows --------------------------------------------------------------


@needs_gcc
def test_the_bench_measures_generation_and_compilation_in_child_processes(tmp_path):
    rows = compile_size.compile_rows((2,), tmp_path)
    (row,) = rows
    assert row.case == "dense KF n=2 m=1" and not row.note
    for measured in (row.generate, row.compile):
        assert measured.seconds > 0 and measured.cpu_seconds > 0 and measured.peak_bytes > 0
    c_file = tmp_path / "dense2" / "dense2" / "kf.c"
    assert row.c_bytes == c_file.stat().st_size
    head, body, bars = compile_size.compile_table(rows)
    assert len(body) == 1 and len(body[0]) == len(head) and len(bars) == 3
    model = compile_size.dense_model(5)
    num = model.numeric()
    assert np.count_nonzero(num.F) == 25 and np.shape(num.H) == (1, 5)


@needs_gcc
def test_a_body_too_large_to_inline_is_called_unstrided_and_run_tracks_runs_each_track(
        tmp_path, monkeypatch):
    monkeypatch.setattr(c_loops, "INLINE_STATEMENTS", 10)   # mpt3d_b's KF: 32 statements
    generated = load_generated("mpt3d_b", "kf", {}, "c", tmp_path)
    c = generated.paths[".c"].read_text()
    assert "\nstatic int mpt3d_b_kf_step_body(" in c and " * s]" not in c
    assert LANES not in c and c.count("mpt3d_b_kf_step_body(") == 3   # defined; step, run
    zs, x0s, P0s = _tracks("mpt3d_b")
    xs, Ps = generated.c.run_tracks(zs, x0s, P0s)
    for t in range(TRACKS):
        x_run, P_run = generated.c.run(zs[t], x0s[t], P0s[t])
        assert np.array_equal(xs[t], x_run) and np.array_equal(Ps[t], P_run)


@needs_gcc
@pytest.mark.parametrize("model_name, filter_name", [("mpt3d_a", "kf"), ("mpt3d_a", "udkf"),
                                                     ("mpt3d_a", "sskf")])
def test_a_large_body_is_printed_in_parts_with_the_same_bits_and_count(
        tmp_path, monkeypatch, model_name, filter_name):
    zs, x0s, P0s = _tracks(model_name)
    whole = load_generated(model_name, filter_name, {}, "c", tmp_path / "whole").c
    monkeypatch.setattr(c_loops, "INLINE_STATEMENTS", 10)
    monkeypatch.setattr(c_loops, "PART_STATEMENTS", 3)
    parted = load_generated(model_name, filter_name, {}, "c", tmp_path / "parted")
    c = parted.paths[".c"].read_text()
    assert f"{model_name}_{filter_name}_step_body_part1(" in c
    assert count_c_function(c, f"{model_name}_{filter_name}_step") == count(
        parted.unit.programs["step"], "c")
    assert not re.findall(r"^(?:int|void) \w+_(?:body|part\d+)\(", c, flags=re.M)  # static
    if filter_name == "sskf":
        runs = (whole.run(zs[0], x0s[0]), parted.c.run(zs[0], x0s[0]))
    else:
        runs = (whole.run(zs[0], x0s[0], P0s[0]), parted.c.run(zs[0], x0s[0], P0s[0]))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)
