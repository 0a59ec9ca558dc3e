"""The outputs a generated run_tracks allocates start on a cache line, called on its own
(FilterModule.run_tracks without ``out=``) as through derive.batch: one allocator
(derive.aligned.aligned_empty, through FilterModule.empty), results bitwise unchanged."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from derive import aligned, batch, catalog
from derive.build import FilterModule
from derive.pipeline import load_generated

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
STEPS = 50


@pytest.fixture(scope="module")
def kf(tmp_path_factory):
    """mpt3d_a's KF written and compiled (its run carries the axes in vector lanes)."""
    generated = load_generated("mpt3d_a", "kf", None, "c", tmp_path_factory.mktemp("kf"))
    return batch.Kernel(str(generated.paths[".c"])), generated.c


def _tracks(tracks: int, seed: int = 3):
    num = catalog.load("mpt3d_a").numeric()
    rng = np.random.default_rng(seed)
    n, m = len(num.x0), np.shape(num.H)[0]
    zs = rng.normal(size=(tracks, STEPS, m)) * 10
    x0s = np.asarray(num.x0, float) + rng.normal(size=(tracks, n))
    P0s = (np.repeat(np.asarray(num.P0, float)[None], tracks, axis=0)
           * (1 + rng.random(tracks))[:, None, None])
    return zs, x0s, P0s


def _aligned(array: np.ndarray) -> bool:
    return array.flags.c_contiguous and array.ctypes.data % aligned.ALIGNMENT == 0


@needs_gcc
@pytest.mark.parametrize("tracks", [1, 3, 64, 777])   # 777 x 50 x 36 doubles: 11 MB (mmap)
def test_run_tracks_on_its_own_allocates_aligned_outputs(kf, tracks):
    _, module = kf
    zs, x0s, P0s = _tracks(tracks)
    xs, Ps = module.run_tracks(zs, x0s, P0s)
    assert _aligned(xs) and _aligned(Ps)
    xs_given, Ps_given = np.empty_like(xs), np.empty_like(Ps)
    module.run_tracks(zs, x0s, P0s, out=(xs_given, Ps_given))
    assert np.array_equal(xs.view(np.uint64), xs_given.view(np.uint64))
    assert np.array_equal(Ps.view(np.uint64), Ps_given.view(np.uint64))
    for t in {0, tracks // 2, tracks - 1}:
        x_run, P_run = module.run(zs[t], x0s[t], P0s[t])
        assert np.array_equal(xs[t].view(np.uint64), x_run.view(np.uint64)), t
        assert np.array_equal(Ps[t].view(np.uint64), P_run.view(np.uint64)), t
    xs_only = module.run_tracks(zs, x0s, P0s, with_covariance=False)[0]
    assert _aligned(xs_only) and np.array_equal(xs_only, xs)


@needs_gcc
def test_batch_and_run_tracks_share_one_allocator(kf, monkeypatch):
    kernel, module = kf
    zs, x0s, P0s = _tracks(200)
    want = module.run_tracks(zs, x0s, P0s)
    made = []
    allocate = FilterModule.empty

    def recording(self, shape):
        array = allocate(self, shape)
        made.append(array)
        return array

    monkeypatch.setattr(FilterModule, "empty", recording)
    xs, Ps = batch.run_tracks(kernel, zs, x0s, P0s, workers=2)
    assert any(a is xs for a in made) and any(a is Ps for a in made)
    assert _aligned(xs) and _aligned(Ps)
    assert np.array_equal(xs.view(np.uint64), want[0].view(np.uint64))
    assert np.array_equal(Ps.view(np.uint64), want[1].view(np.uint64))


def test_the_allocator_aligns_every_size_and_dtype():
    for dtype in (np.float64, np.float32):
        for shape in ((1,), (3, 5), (1000, 7), (2, 3, 4)):
            array = aligned.aligned_empty(shape, dtype)
            assert array.shape == shape and array.dtype == dtype and _aligned(array)
