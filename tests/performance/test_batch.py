"""derive.batch.run_tracks: tracks split across threads or Dask chunks give each track
bitwise its own run; shapes are checked before any work; Dask is imported only when a
Dask array is given. No speed is asserted."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest
import sympy

from derive import LinearModel, batch, cli
from derive.apps.bench.run import BenchResult, Settings
from derive.apps.bench.throughput import scaling
from derive.apps.bench.throughput.batch import make_batch
from derive.errors import ModelError, NumericalError, ShapeError
from derive.pipeline import load_generated

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

TRACKS, STEPS = 20_000, 50


@pytest.fixture(scope="module")
def kf(tmp_path_factory):
    """mpt3d_b's KF written and compiled: its Kernel and its loaded wrappers."""
    generated = load_generated("mpt3d_b", "kf", None, "c", tmp_path_factory.mktemp("kf"))
    kernel = batch.Kernel(str(generated.paths[".c"]))
    return kernel, generated.c


@pytest.fixture(scope="module")
def tracks():
    """(zs, x0s, P0s): TRACKS simulated tracks, each with its own start."""
    b = make_batch(TRACKS, STEPS, seed=11)
    rng = np.random.default_rng(3)
    x0s = b.x0 + rng.normal(size=(TRACKS, len(b.x0)))
    P0s = b.P0 * rng.uniform(0.5, 2.0, size=(TRACKS, 1, 1))
    return b.zs, x0s, P0s


@pytest.fixture(scope="module")
def whole(kf, tracks):
    """The generated run_tracks over all tracks in one call."""
    return kf[1].run_tracks(*tracks)


def _assert_own_runs(module, tracks, xs, Ps, which):
    zs, x0s, P0s = tracks
    for t in which:
        x1, P1 = module.run(zs[t], x0s[t], P0s[t])
        np.testing.assert_array_equal(xs[t], x1)
        np.testing.assert_array_equal(Ps[t], P1)


@pytest.mark.parametrize("workers", [1, 2, 3, 7])
def test_threads_give_each_track_its_own_run_bitwise(kf, tracks, whole, workers):
    kernel, module = kf
    xs, Ps = batch.run_tracks(kernel, *tracks, workers=workers)
    np.testing.assert_array_equal(xs, whole[0])
    np.testing.assert_array_equal(Ps, whole[1])
    edges = {a for a, _ in batch.split(TRACKS, workers)} | {b - 1 for _, b in
                                                              batch.split(TRACKS, workers)}
    _assert_own_runs(module, tracks, xs, Ps, sorted(edges | {1, 2, 3, 4, 5}))


def test_split_is_contiguous_uneven_and_never_empty():
    assert batch.split(10, 3) == [(0, 3), (3, 6), (6, 10)]
    assert batch.split(2, 5) == [(0, 1), (1, 2)]
    assert batch.split(0, 4) == []


def test_a_loaded_module_or_a_path_is_a_kernel_too(kf, tracks, whole):
    kernel, module = kf
    xs, _ = batch.run_tracks(module, *tracks, workers=2)
    np.testing.assert_array_equal(xs, whole[0])
    xs, _ = batch.run_tracks(kernel.path, *tracks, workers=2)
    np.testing.assert_array_equal(xs, whole[0])


def test_a_shared_start_equals_it_repeated_and_covariances_may_be_left_out(kf, tracks):
    kernel, module = kf
    zs, x0s, P0s = tracks
    xs, Ps = batch.run_tracks(kernel, zs, x0s[0], P0s[0], workers=3)
    rep_xs, rep_Ps = module.run_tracks(zs, np.repeat(x0s[:1], TRACKS, 0),
                                       np.repeat(P0s[:1], TRACKS, 0))
    np.testing.assert_array_equal(xs, rep_xs)
    np.testing.assert_array_equal(Ps, rep_Ps)
    xs, Ps = batch.run_tracks(kernel, zs, x0s[0], P0s[0], workers=3, with_covariance=False)
    assert Ps is None
    np.testing.assert_array_equal(xs, rep_xs)


def test_parameter_rows_are_shared_by_every_track(tmp_path):
    dt, q = sympy.symbols("dt q")
    model = LinearModel("freeaxis", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[q]],
                        [[0.25]], G=[[dt ** 2 / 2], [dt]], x0=[0, 1], P0=[[4, 0.5], [0.5, 1]],
                        parameters=["dt", "q"])
    module = load_generated(model, "kf", None, "c", tmp_path).c
    rng = np.random.default_rng(2)
    steps, count = 30, 11
    rows = np.column_stack([rng.uniform(0.1, 1.0, steps), rng.uniform(0.01, 0.1, steps)])
    zs = rng.normal(size=(count, steps, 1))
    x0s, P0s = rng.normal(size=(count, 2)), np.stack([np.eye(2) * (1 + t) for t in range(count)])
    xs, Ps = batch.run_tracks(module, zs, x0s, P0s, rows, workers=3)
    for t in range(count):
        x1, P1 = module.run(zs[t], x0s[t], P0s[t], rows)
        np.testing.assert_array_equal(xs[t], x1)
        np.testing.assert_array_equal(Ps[t], P1)
    with pytest.raises(ModelError, match="p is required"):
        batch.run_tracks(module, zs, x0s, P0s)
    with pytest.raises(ShapeError, match=r"p must have shape .*shared by every track.*\(3,\)"):
        batch.run_tracks(module, zs, x0s, P0s, np.ones(3))


@pytest.mark.parametrize("args, error, text", [
    (lambda zs, x0, P0: (zs[0, 0], x0, P0), ShapeError, r"zs must have shape \(tracks, steps"),
    (lambda zs, x0, P0: (zs[:, :, None], x0, P0), ShapeError, r"zs must have shape"),
    (lambda zs, x0, P0: (zs, x0[:-1], P0), ShapeError,
     r"x0s must have shape \(20000, 2\) \(one per track\) or \(2,\) \(shared\), got \(19999, 2\)"),
    (lambda zs, x0, P0: (zs, x0, P0[:, :1]), ShapeError,
     r"P0s must have shape .*got \(20000, 1, 2\)"),
    (lambda zs, x0, P0: (zs, x0, None), ModelError, r"P0s is required"),
    (lambda zs, x0, P0: (zs, x0, P0, [1.0]), ModelError, r"takes no parameters p"),
])
def test_bad_shapes_are_refused_naming_the_argument(kf, tracks, args, error, text):
    with pytest.raises(error, match=text):
        batch.run_tracks(kf[0], *args(*tracks), workers=2)


@pytest.mark.parametrize("workers", [0, -1, 1.5, True])
def test_workers_must_be_a_positive_integer(kf, tracks, workers):
    with pytest.raises(ModelError, match="workers must be an integer >= 1"):
        batch.run_tracks(kf[0], *tracks, workers=workers)


def test_a_kernel_of_another_type_is_refused():
    with pytest.raises(ModelError, match="expected a derive.batch.Kernel or the path"):
        batch.run_tracks(42, np.zeros((2, 3, 1)), np.zeros(2), np.eye(2))


def test_a_failed_check_names_the_slice_of_tracks(kf, tracks):
    zs, x0s, P0s = (a[:20] for a in tracks)
    P0s = P0s.copy()
    P0s[13] = -100 * np.eye(2)
    with pytest.raises(NumericalError, match=r"^tracks 13 to 19: .*S is not positive"):
        batch.run_tracks(kf[0], zs, x0s, P0s, workers=3)


def test_dask_is_imported_only_for_a_dask_array():
    code = ("import sys, numpy as np\nimport derive.batch\n"
            "assert 'dask' not in sys.modules, 'dask imported'\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_dask_arrays_give_the_numpy_result_bitwise(kf, tracks, whole):
    da = pytest.importorskip("dask.array")
    zs, x0s, P0s = tracks
    chunks = (7_000, -1, -1)          # uneven: 7,000 + 7,000 + 6,000 tracks
    xd, Pd = batch.run_tracks(kf[0], da.from_array(zs, chunks=chunks), x0s,
                              da.from_array(P0s, chunks=(3_000, -1, -1)))
    xs, Ps = da.compute(xd, Pd, scheduler="threads")
    np.testing.assert_array_equal(xs, whole[0])
    np.testing.assert_array_equal(Ps, whole[1])
    xd, none = batch.run_tracks(kf[0].path, da.from_array(zs, chunks=chunks), x0s, P0s,
                                with_covariance=False)
    assert none is None
    np.testing.assert_array_equal(xd.compute(scheduler="sync"), whole[0])


def test_dask_refuses_workers_and_a_loaded_module(kf, tracks):
    da = pytest.importorskip("dask.array")
    zs = da.from_array(tracks[0], chunks=(5_000, -1, -1))
    with pytest.raises(ModelError, match="workers= is for NumPy inputs"):
        batch.run_tracks(kf[0], zs, *tracks[1:], workers=2)
    with pytest.raises(ModelError, match="expected a derive.batch.Kernel or the path"):
        batch.run_tracks(kf[1], zs, *tracks[1:])
    with pytest.raises(ShapeError, match=r"x0s must have shape"):
        batch.run_tracks(kf[0], zs, tracks[1][:-1], tracks[2])


def test_a_two_worker_local_cluster_gives_the_numpy_result_bitwise(kf, tracks, whole):
    da = pytest.importorskip("dask.array")
    distributed = pytest.importorskip("distributed")
    zs, x0s, P0s = tracks
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster):
        xd, Pd = batch.run_tracks(kf[0], da.from_array(zs, chunks=(6_001, -1, -1)),
                                  da.from_array(x0s, chunks=(6_001, -1)), P0s)
        xs, Ps = da.compute(xd, Pd)
    np.testing.assert_array_equal(xs, whole[0])
    np.testing.assert_array_equal(Ps, whole[1])


def test_the_bench_measures_threads_and_dask_with_one_and_two_workers(tmp_path):
    pytest.importorskip("distributed")
    rows = scaling.scaling_rows(250, 6, tmp_path, repeats=1, chunk=100)
    assert [(r.implementation, r.workers) for r in rows] == [
        ("threads", 1), ("threads", 2), ("Dask LocalCluster", 1), ("Dask LocalCluster", 2)]
    for r in rows:
        assert r.bitwise is True and r.track_steps_per_second > 0, r
    result = BenchResult(Settings(scale_tracks=250, scale_steps=6), {}, scale=rows)
    _, _, lines = scaling.scaling_table(rows)
    assert [line.split(":")[0] for line in lines] == [
        "scaling of threads from 1 to 2 workers",
        "scaling of Dask LocalCluster from 1 to 2 workers",
        "bar"]   # the batch on both cores, >= 6e8 track-steps/s
    assert result.as_json()["scale"][2]["implementation"] == "Dask LocalCluster"


def test_simulated_chunks_are_the_same_bits_however_made():
    whole = np.concatenate([scaling.simulated_chunk(a, b, 5) for a, b in scaling.chunks(7, 3)])
    assert [(a, b) for a, b in scaling.chunks(7, 3)] == [(0, 3), (3, 6), (6, 7)]
    np.testing.assert_array_equal(whole[3:6], scaling.simulated_chunk(3, 6, 5))


@pytest.mark.parametrize("option", ["--scale-tracks=-1", "--scale-steps=0"])
def test_bench_scale_options_are_checked(option, capsys):
    assert cli.main(["bench", "--quick", option]) == 2
    assert "must be >=" in capsys.readouterr().err


def test_the_bench_skips_dask_rows_without_dask(tmp_path, monkeypatch):
    for name in ("dask", "dask.array", "distributed"):
        monkeypatch.setitem(sys.modules, name, None)   # import raises ImportError
    rows = scaling.scaling_rows(30, 4, tmp_path, repeats=1)
    assert [r.bitwise for r in rows[:2]] == [True, True]
    for r in rows[2:]:
        assert r.track_steps_per_second is None
        assert r.note == ("skipped: dask[array] and distributed are not installed (the [dask] "
                          "extra)")
