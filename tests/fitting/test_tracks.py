"""A fleet through the C ``run_tracks`` of a filter with the gradient: each track's xs,
lls and dlls equal its own ``run``'s to 1e-12 relative (the blocks of tracks in lanes,
each lane entered by the enter program, and the last tracks, fewer than a block, by run);
the generated Python run takes the tracks as a trailing axis; and a fit over the fleet
sums what one run_tracks call per slice of tracks returns."""

import numpy as np
import pytest
from test_gradient import freed, measurements

from derive import batch
from derive.errors import PatternError
from derive.fitting import _TracksRun, fit
from derive.model import LinearModel
from derive.pipeline import load_generated

TOLERANCE = 1e-12
#: more than two blocks of the widest lanes (64 at AVX-512 for cv's two states), and a tail
TRACKS = 131
STEPS = 40


@pytest.fixture(scope="module")
def fleet():
    model = freed("cv", ["sq2", "sr2"])
    generated = load_generated(model, "kf", {"gradient": True, "missing": True})
    theta = np.array([0.03, 0.4])
    zs = [measurements(model, theta, seed=seed, steps=STEPS) for seed in range(TRACKS)]
    return model, generated, theta, zs


def close(a, b) -> bool:
    return np.max(np.abs(a - b)) <= TOLERANCE * max(np.max(np.abs(b)), 1e-300)


def test_run_tracks_equals_run_on_each_track_with_lls_and_dlls(fleet):
    model, generated, theta, zs = fleet
    c = generated.c
    x0, P0 = np.zeros(2), np.eye(2)
    assert "run_tracks" in c.functions
    tracks = _TracksRun(c, [(z, None) for z in zs], x0, P0, len(theta))
    ll, dll = tracks(theta)
    out = tracks.outputs
    lls, dlls = out["lls"].reshape(TRACKS, STEPS), out["dlls"].reshape(TRACKS, STEPS, 2)
    xs = out["xs"].reshape(TRACKS, STEPS, 2)
    for t, z in enumerate(zs):
        xs_t, _, lls_t, dlls_t = c.run(z, x0, P0, theta)
        assert close(xs[t], xs_t) and close(lls[t], lls_t) and close(dlls[t], dlls_t), t
    assert close(np.array([ll]), np.array([np.sum(lls)]))
    assert close(dll, dlls.sum(axis=(0, 1)))


def test_run_tracks_enters_each_lane_with_the_enter_programs_checks():
    """gps_static's three random walks (a diagonal P0 pattern, which enter checks), their
    variances free: 70 tracks (two blocks of AVX-512's 32 lanes for this state, and a
    tail), each equal to its own run."""
    model = freed("gps_static", ["upsilon", "tau", "zeta"])
    c = load_generated(model, "kf", {"gradient": True, "missing": True}, "c").c
    theta = np.array([0.01, 0.02, 0.03])
    zs = [measurements(model, theta, seed=seed, steps=20) for seed in range(70)]
    x0, P0 = np.zeros(3), np.diag([1.0, 2.0, 3.0])
    tracks = _TracksRun(c, [(z, None) for z in zs], x0, P0, 3)
    tracks(theta)
    out = tracks.outputs
    for t, z in enumerate(zs):
        xs_t, _, lls_t, dlls_t = c.run(z, x0, P0, theta)
        assert close(out["xs"].reshape(70, 20, 3)[t], xs_t), t
        assert close(out["lls"].reshape(70, 20)[t], lls_t), t
        assert close(out["dlls"].reshape(70, 20, 3)[t], dlls_t), t
    bad = P0.copy()
    bad[0, 1] = 0.5  # outside the pattern: enter's status, named as run's would be
    with pytest.raises(PatternError, match=r"P0\[0\]\[1\]"):
        _TracksRun(c, [(z, None) for z in zs], x0, bad, 3)(theta)


def test_run_tracks_takes_each_tracks_inputs():
    """A model with inputs (a state and a measurement offset, q and r free): 70 tracks
    through run_tracks, their inputs one track after another, each equal to its own run
    (the fit's call, and the wrapper's us)."""
    model = LinearModel("offsets", ["x"], ["z"], [[1]], [[1]], [["q"]], [["r"]],
                        B=[[1, 0]], D=[[0, 1]], inputs=["b", "d"], x0=[1.0], P0=[[3.0]],
                        parameters=["q", "r"])
    c = load_generated(model, "kf", {"gradient": True}, "c").c
    rng = np.random.default_rng(4)
    zs, us = rng.normal(size=(70, 30, 1)) * 3, rng.normal(size=(70, 30, 2))
    theta, x0, P0 = np.array([0.25, 2.0]), np.array([1.0]), np.array([[3.0]])
    tracks = _TracksRun(c, list(zip(zs, us)), x0, P0, 2)
    tracks(theta)
    out = tracks.outputs
    xs, _ = c.run_tracks(zs, np.stack([x0] * 70), np.stack([P0] * 70), theta, us=us)
    spread, _ = batch.run_tracks(c, zs, x0, P0, theta, us=us, workers=2)
    np.testing.assert_array_equal(spread, xs)
    for t in range(70):
        xs_t, _, lls_t, dlls_t = c.run(zs[t], us[t], x0, P0, theta)
        assert close(out["xs"].reshape(70, 30)[t], xs_t[:, 0]) and close(xs[t], xs_t), t
        assert close(out["lls"].reshape(70, 30)[t], lls_t), t
        assert close(out["dlls"].reshape(70, 30, 2)[t], dlls_t), t


def test_the_python_run_takes_the_tracks_as_a_trailing_axis(fleet):
    model, generated, theta, zs = fleet
    py = generated.python
    few = np.stack(zs[:3], axis=-1)  # (steps, m, tracks)
    x0, P0 = np.zeros((2, 3)), np.repeat(np.eye(2)[:, :, None], 3, axis=2)
    xs, _, lls, dlls = py.run(few, x0, P0, theta)
    for t in range(3):
        xs_t, _, lls_t, dlls_t = generated.c.run(zs[t], x0[:, t], P0[:, :, t], theta)
        assert close(xs[..., t], xs_t) and close(lls[..., t], lls_t)
        assert close(dlls[..., t], dlls_t)


def test_a_fleet_of_two_lengths_is_summed_over_run_tracks_calls_in_slices(fleet):
    """The fit's evaluation at its start (no step taken): its log L and gradient are the
    sums of each track's own run, the tracks of each length split into slices (two
    workers) of run_tracks calls."""
    model, generated, theta, zs = fleet
    tracks = zs[:70] + [zs[70][:25], zs[71][:25]]
    x0, P0 = np.zeros(2), np.eye(2)
    start = dict(zip(("sq2", "sr2"), theta))
    result = fit(model, tracks, generated=generated, progress=False, workers=2, x0=x0,
                 P0=P0, start=start, gtol=1e12, polish=0)
    runs = [generated.c.run(z, x0, P0, theta) for z in tracks]
    ll = sum(np.sum(r[2]) for r in runs)
    dll = sum(np.sum(r[3], axis=0) for r in runs)
    assert abs(result.loglik - ll) <= TOLERANCE * abs(ll)
    assert close(result.gradient, dll)
