"""Issue 16's batch bar (branch perf-batch): run_tracks' blocks prefetch the next block's
contiguous rows (or each lane's rows) and swap their state arrays, with each track bitwise
its own run either way; float kernels get twice the lanes of double ones; derive.batch
splits the tracks at multiples of 64 into cache-line-aligned outputs, or writes the
caller's own (``out=``, checked before any work); the bench prints this machine's
memory-traffic bound and compute ceiling beside the batch's figure. No speed is
asserted."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from derive import aligned, batch, catalog
from derive.apps.bench.throughput import scaling
from derive.apps.bench.throughput.batch import copy_bandwidth, make_batch
from derive.emit import c_loops
from derive.errors import DtypeError, ModelError, ShapeError
from derive.generation import render_filter
from derive.pipeline import load_generated

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

NATIVE = ("-O3", "-march=native")
#: The widest default lanes: float32 in four AVX-512 registers.
WIDEST = max(c_loops.lanes(c_loops.INTERLEAVE, 4).values())
#: Three blocks of the widest lanes (so a block prefetches the next one) and a tail; an odd
#: number of steps (the two-step pass of a steady-state filter ends with one step).
TRACKS, STEPS = 3 * WIDEST + 5, 23


def _tracks(model_name: str, dtype=np.float64, tracks: int = TRACKS, seed: int = 8):
    num = catalog.load(model_name).numeric()
    rng = np.random.default_rng(seed)
    n, m = len(num.x0), np.shape(num.H)[0]
    zs = (rng.normal(size=(tracks, STEPS, m)) * 10).astype(dtype)
    x0s = (np.asarray(num.x0, float) + rng.normal(size=(tracks, n))).astype(dtype)
    P0s = (np.repeat(np.asarray(num.P0, float)[None], tracks, axis=0)
           * (1 + rng.random(tracks))[:, None, None]).astype(dtype)
    return zs, x0s, P0s


def _lane_counts(c: str) -> list[int]:
    """The DERIVE_LANES a .c file defines, one per target, in order."""
    return [int(n) for n in re.findall(rf"#define {c_loops.LANES} (\d+)", c)]


# -- the C: prefetching, swapped state, lanes -----------------------------------------------


def test_a_block_prefetches_the_next_blocks_rows_and_swaps_its_state_arrays():
    c = render_filter(catalog.load("mpt3d_b"), "kf", "c")["kf.c"]
    tracks = c[c.index("_run_tracks(size_t steps"):]
    for array, size in (("z", 1), ("xs", 2), ("Ps", 4)):
        assert (f"({array} + (t + {c_loops.LANES}) * steps * {size}) + {c_loops.LINE} * i"
                in tracks), array
    assert f"#define {c_loops.AHEAD_BYTES} {c_loops.AHEAD_BYTES_DEFAULT}" in c
    assert "x_b = x_new_b;" in tracks and "P_b = P_new_b;" in tracks
    assert "x_b[i] = x_new_b[i]" not in tracks and "P_b[i] = P_new_b[i]" not in tracks


@needs_gcc
@pytest.mark.parametrize("ahead", [(), (f"-D{c_loops.AHEAD_BYTES}=0",)],
                         ids=["next block", "each lane's rows"])
@pytest.mark.parametrize("model_name, filter_name", [("mpt3d_b", "kf"), ("mpt3d_a", "kf"),
                                                     ("mpt3d_a", "sskf")])
def test_each_track_is_bitwise_its_own_run_whichever_rows_are_prefetched(
        tmp_path, model_name, filter_name, ahead):
    module = load_generated(model_name, filter_name, {}, "c", tmp_path,
                            extra_cflags=NATIVE + ahead).c
    zs, x0s, P0s = _tracks(model_name)
    if filter_name == "sskf":
        results = [(module.run_tracks(zs, x0s), None)]
    else:
        results = [module.run_tracks(zs, x0s, P0s),
                   (module.run_tracks(zs, x0s, P0s, with_covariance=False)[0], None)]
    for xs, Ps in results:
        for t in range(TRACKS):
            if filter_name == "sskf":
                assert np.array_equal(xs[t], module.run(zs[t], x0s[t])), t
                continue
            x_run, P_run = module.run(zs[t], x0s[t], P0s[t])
            assert np.array_equal(xs[t], x_run), t
            if Ps is not None:
                assert np.array_equal(Ps[t], P_run.reshape(Ps[t].shape)), t


def test_float_kernels_have_twice_the_lanes_of_double_ones():
    model = catalog.load("mpt3d_b")
    double = _lane_counts(render_filter(model, "kf", "c")["kf.c"])
    single = _lane_counts(render_filter(model, "kf", "c", {"precision": "float"})["kf.c"])
    assert len(double) == len(c_loops.REGISTER_BYTES)
    assert single == [2 * lanes for lanes in double]


@needs_gcc
def test_a_float_kernel_in_its_wider_lanes_gives_each_track_its_own_run(tmp_path):
    module = load_generated("mpt3d_b", "kf", {"precision": "float"}, "c", tmp_path,
                            extra_cflags=NATIVE).c
    zs, x0s, P0s = _tracks("mpt3d_b", np.float32)
    xs, Ps = module.run_tracks(zs, x0s, P0s)
    assert xs.dtype == np.float32
    for t in range(TRACKS):
        x_run, P_run = module.run(zs[t], x0s[t], P0s[t])
        assert np.array_equal(xs[t], x_run) and np.array_equal(Ps[t], P_run), t


# -- derive.batch: slices, aligned outputs, out= ---------------------------------------------


@pytest.mark.parametrize("tracks, parts", [(1000, 2), (1000, 3), (10**6, 2), (200, 3),
                                           (4 * 64 + 1, 4)])
def test_threads_slices_start_at_multiples_of_64_tracks(tracks, parts):
    multiple = batch.TRACK_MULTIPLE
    slices = batch.split(tracks, parts, multiple)
    assert len(slices) == parts
    assert slices[0][0] == 0 and slices[-1][1] == tracks
    assert all(b == c for (_, b), (c, _) in zip(slices, slices[1:]))
    assert all(a % multiple == 0 for a, _ in slices)
    sizes = [b - a for a, b in slices]
    assert max(sizes) - min(sizes) <= multiple


def test_too_few_tracks_for_the_multiple_are_split_evenly():
    assert batch.split(100, 2, batch.TRACK_MULTIPLE) == batch.split(100, 2)
    assert batch.split(20, 3, batch.TRACK_MULTIPLE) == [(0, 6), (6, 13), (13, 20)]


@pytest.fixture(scope="module")
def kf(tmp_path_factory):
    """mpt3d_b's KF written and compiled: its Kernel and its loaded wrappers."""
    generated = load_generated("mpt3d_b", "kf", None, "c", tmp_path_factory.mktemp("kf"))
    return batch.Kernel(str(generated.paths[".c"])), generated.c


@needs_gcc
@pytest.mark.parametrize("workers", [2, 3])
def test_new_outputs_are_aligned_and_each_slice_edge_is_its_own_run(kf, workers):
    kernel, module = kf
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=1000)
    xs, Ps = batch.run_tracks(kernel, zs, x0s, P0s, workers=workers)
    assert xs.ctypes.data % aligned.ALIGNMENT == 0 and Ps.ctypes.data % aligned.ALIGNMENT == 0
    edges = {t for a, b in batch.split(1000, workers, batch.TRACK_MULTIPLE)
             for t in (a - 1, a, b - 1) if t >= 0}
    for t in sorted(edges):
        x_run, P_run = module.run(zs[t], x0s[t], P0s[t])
        assert np.array_equal(xs[t], x_run) and np.array_equal(Ps[t], P_run), t


def test_an_aligned_empty_array_starts_on_a_cache_line():
    for count in (1, 3, 1000):
        array = aligned.aligned_empty((count, 7), np.float32)
        assert array.shape == (count, 7) and array.dtype == np.float32
        assert array.flags.c_contiguous and array.ctypes.data % aligned.ALIGNMENT == 0


@needs_gcc
def test_the_callers_outputs_are_written_and_returned(kf):
    kernel, _ = kf
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=300)
    fresh_xs, fresh_Ps = batch.run_tracks(kernel, zs, x0s, P0s, workers=2)
    out = (np.full_like(fresh_xs, np.nan), np.full_like(fresh_Ps, np.nan))
    xs, Ps = batch.run_tracks(kernel, zs, x0s, P0s, workers=2, out=out)
    assert xs is out[0] and Ps is out[1]
    assert np.array_equal(xs, fresh_xs) and np.array_equal(Ps, fresh_Ps)
    again = batch.run_tracks(kernel, zs[::-1], x0s, P0s, workers=3, out=(xs, Ps))
    assert np.array_equal(again[0], batch.run_tracks(kernel, zs[::-1], x0s, P0s)[0])
    only_x = np.full_like(fresh_xs, np.nan)
    xs, Ps = batch.run_tracks(kernel, zs, x0s, P0s, with_covariance=False,
                              out=(only_x, None))
    assert xs is only_x and Ps is None and np.array_equal(xs, fresh_xs)


@needs_gcc
def test_a_filter_without_P0_takes_out_as_one_array(tmp_path):
    kernel = batch.Kernel(str(load_generated("mpt3d_a", "sskf", None, "c", tmp_path)
                              .paths[".c"]))
    zs, x0s, _ = _tracks("mpt3d_a", tracks=150)
    out = np.full((150, STEPS, x0s.shape[1]), np.nan)
    assert batch.run_tracks(kernel, zs, x0s, workers=2, out=out) is out
    assert np.array_equal(out, batch.run_tracks(kernel, zs, x0s))
    with pytest.raises(ModelError, match="out must be one array xs for a filter without P0"):
        batch.run_tracks(kernel, zs, x0s, out=(out, None))
    shape = re.escape(str((150, STEPS, x0s.shape[1])))
    with pytest.raises(ShapeError, match=f"out xs must have shape {shape}"):
        batch.run_tracks(kernel, zs, x0s, out=out[:, 1:])


def _bad_outs(xs, Ps):
    """(out, with_covariance, error, message) for outputs the batch refuses."""
    return [
        (xs, True, ModelError, r"out must be a pair \(xs, Ps\)"),
        ((xs, None), True, ModelError, r"out's Ps must be an array .*with_covariance is True"),
        ((xs, Ps), False, ModelError, r"out's Ps must be None: with_covariance is False"),
        ((xs[:, :-1], Ps), True, ShapeError, "out xs must have shape "
         + re.escape(f"{xs.shape}, got {xs[:, :-1].shape}")),
        ((xs, Ps.reshape(300, STEPS, 4)), True, ShapeError,
         "out Ps must have shape " + re.escape(str(Ps.shape))),
        ((xs.astype(np.float32), Ps), True, DtypeError, r"out xs is float32, but this kernel "
                                                        r"writes float64"),
        ((np.asfortranarray(xs), Ps), True, ShapeError, r"out xs must be C-contiguous"),
        ((xs.tolist(), Ps), True, ModelError, r"out xs must be a NumPy array, got list"),
        ((np.broadcast_to(xs[:1], xs.shape), Ps), True, ShapeError, "C-contiguous"),
        ((_read_only(xs), Ps), True, ModelError, r"out xs is read-only"),
    ]


def _read_only(array):
    array = array.copy()
    array.flags.writeable = False
    return array


@needs_gcc
def test_bad_outputs_are_refused_naming_the_array_before_any_work(kf):
    kernel, _ = kf
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=300)
    xs, Ps = np.zeros((300, STEPS, 2)), np.zeros((300, STEPS, 2, 2))
    for out, covariance, error, message in _bad_outs(xs, Ps):
        with pytest.raises(error, match=message):
            batch.run_tracks(kernel, zs, x0s, P0s, with_covariance=covariance, out=out)
    assert not xs.any() and not Ps.any()


@needs_gcc
def test_outputs_sharing_memory_with_an_input_or_each_other_are_refused(kf):
    kernel, _ = kf
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=300)
    size = 300 * STEPS
    one = np.zeros(size * 6)                     # xs then Ps in one buffer: no overlap
    batch.run_tracks(kernel, zs, x0s, P0s, out=(one[:size * 2].reshape(300, STEPS, 2),
                                                one[size * 2:].reshape(300, STEPS, 2, 2)))
    overlapping = np.zeros(size * 4 + 10)
    with pytest.raises(ModelError, match="out Ps shares memory with xs"):
        batch.run_tracks(kernel, zs, x0s, P0s,
                         out=(overlapping[:size * 2].reshape(300, STEPS, 2),
                              overlapping[10:].reshape(300, STEPS, 2, 2)))
    shared = np.zeros(size * 3)
    zs_inside = shared[:size].reshape(300, STEPS, 1)
    zs_inside[:] = zs
    with pytest.raises(ModelError, match="out xs shares memory with zs"):
        batch.run_tracks(kernel, zs_inside, x0s, P0s, with_covariance=False,
                         out=(shared[size - 2:size * 3 - 2].reshape(300, STEPS, 2), None))
    assert np.array_equal(zs_inside, zs)


def test_out_is_for_numpy_inputs_only(kf):
    da = pytest.importorskip("dask.array")
    kernel, _ = kf
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=100)
    with pytest.raises(ModelError, match="out= is for NumPy inputs"):
        batch.run_tracks(kernel, da.from_array(zs, chunks=(50, -1, -1)), x0s, P0s,
                         out=(np.zeros((100, STEPS, 2)), np.zeros((100, STEPS, 2, 2))))


# -- the bench: this machine's limits beside the batch's figure ------------------------------


def test_the_bar_line_prints_both_limits_and_the_share_of_the_lower():
    limits = scaling.Limits(2, 24e9, 24, 24e9 / 24, 8e8)
    rows = [scaling.ScaleRow("threads", 1, 4e8, 1.0, True, "", limits),
            scaling.ScaleRow("threads", 2, 5e8, 0.8, True, "", limits, 3e8)]
    head, body, lines = scaling.scaling_table(rows)
    assert head[5] == "this machine's limits, same run"
    text = scaling.limits_text(limits)
    assert body[1][5] == text
    assert text == ("memory traffic 1e+09 (2-thread copy 24.0 GB/s / 24 B); compute 8e+08 "
                    "(2 thread(s) in cache)")
    assert lines[-1].startswith("bar: batch mpt3d_b KF, covariances not stored, 2 threads, "
                                "into outputs reused (out=): 5e+08 track-steps/s (>= 6e+08: "
                                "NOT met); into new outputs each call 3e+08")
    assert lines[-1].endswith(f"{text}; the figure is {5e8 / 8e8:.0%} of the lower")


@needs_gcc
def test_the_limits_are_measured_on_as_many_threads(kf):
    kernel, module = kf
    start = make_batch(1, 1)
    for threads in (1, 2):
        assert copy_bandwidth(megabytes=4, repeats=1, threads=threads) > 0
        assert scaling.compute_ceiling(module, start.x0, start.P0, 5, threads, 1,
                                       work=10_000) > 0


@needs_gcc
def test_a_large_batch_is_cut_into_more_slices_than_threads_taken_in_turn(kf, monkeypatch):
    _, module = kf
    workers = 2
    tracks = workers * batch.SLICES_PER_WORKER * batch.TRACK_MULTIPLE * 2 + 7
    zs, x0s, P0s = _tracks("mpt3d_b", tracks=tracks)
    whole = module.run_tracks(zs, x0s, P0s)
    calls = []
    original = module.run_tracks

    def recorded(zs_slice, *args, **kwargs):
        calls.append(zs_slice.__array_interface__["data"][0])
        return original(zs_slice, *args, **kwargs)
    monkeypatch.setattr(module, "run_tracks", recorded)
    xs, Ps = batch.run_tracks(module, zs, x0s, P0s, workers=workers)
    starts = sorted((address - zs.__array_interface__["data"][0]) // zs[0].nbytes
                    for address in calls)
    assert starts == [a for a, _ in batch.split(tracks, workers * batch.SLICES_PER_WORKER,
                                                 batch.TRACK_MULTIPLE)]
    assert len(starts) == workers * batch.SLICES_PER_WORKER
    assert np.array_equal(xs, whole[0]) and np.array_equal(Ps, whole[1])
    few = batch.SLICES_PER_WORKER * batch.TRACK_MULTIPLE       # fewer: one slice a thread
    calls.clear()
    batch.run_tracks(module, zs[:few], x0s[:few], P0s[:few], workers=workers)
    assert len(calls) == workers
