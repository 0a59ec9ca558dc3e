"""Generated Python and C against the NumPy reference: catalog, random models, many tracks."""

import numpy as np
import pytest
import sympy
from _random_models import stable_models
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import LinearModel, catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import LINEAR_TOLERANCE, relative_error, verify_filter
from derive.filters import available
from derive.pipeline import load_generated

LINEAR = [(name, f) for name in catalog.names() for f in available(catalog.load(name))
          if catalog.load(name).kind == "linear"]


@pytest.mark.parametrize("model_name, filter_name", LINEAR)
def test_catalog_filter_matches_reference(model_name, filter_name):
    results = verify_filter(catalog.load(model_name), filter_name, steps=1000)
    assert [r.lang for r in results] == ["python", "c"]
    for r in results:
        assert r.error <= LINEAR_TOLERANCE, r.line()


def test_relative_error_is_normwise_per_step():
    ref = np.array([[1e6, 1.0], [2.0, 3.0]])
    assert relative_error(ref + [[1e-6, 1e-6], [0, 0]], ref) == pytest.approx(1e-12)
    assert relative_error(ref + [[0, 0], [0, 3e-12]], ref) == pytest.approx(1e-12)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stable_models(), st.integers(0, 1000))
def test_random_models_kf_and_sskf_match_reference(model, seed):
    num = model.numeric()
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 200, seed)
    P0 = np.eye(model.n)
    xs, Ps = load_generated(model, "kf", lang="python").python.run(run.zs, num.x0, P0)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, run.zs)
    assert relative_error(xs, xr) <= 1e-12
    assert relative_error(Ps, Pr) <= 1e-12
    xs = load_generated(model, "sskf", lang="python").python.run(run.zs, num.x0)
    assert relative_error(xs, reference.sskf(num.F, num.G, num.H, num.Q, num.R, num.x0,
                                             run.zs)) <= 1e-12


def test_trailing_track_axis_filters_many_tracks():
    model = catalog.load("mpt3d_a")
    num = model.numeric()
    mod = load_generated(model, "kf", lang="python").python
    tracks = 7
    zs = np.stack([simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 50, s).zs
                   for s in range(tracks)], axis=-1)  # (steps, m, tracks)
    x0 = np.zeros((model.n, tracks))
    P0 = np.zeros((model.n, model.n, tracks))
    xs, Ps = mod.run(zs, x0, P0)
    assert xs.shape == (50, model.n, tracks) and Ps.shape == (50, model.n, model.n, tracks)
    for t in range(tracks):
        x1, P1 = mod.run(zs[..., t], x0[:, t], P0[..., t])
        np.testing.assert_array_equal(xs[..., t], x1)
        np.testing.assert_array_equal(Ps[..., t], P1)


def test_free_parameter_model_runs_with_p():
    dt = sympy.Symbol("dt")
    m = LinearModel("freedt", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[0.01]], [[0.1]],
                    G=[[dt / 2], [1]], parameters=[dt])
    mod = load_generated(m, "kf", lang="python").python
    num = LinearModel("fixed", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[0.01]], [[0.1]],
                      G=[[dt / 2], [1]], values={"dt": 0.5}).numeric()
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 100, 3)
    xs, Ps = mod.run(run.zs, num.x0, np.eye(2), np.array([0.5]))
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, np.eye(2), run.zs)
    assert relative_error(xs, xr) <= 1e-12 and relative_error(Ps, Pr) <= 1e-12


@pytest.mark.parametrize("model_name, filter_name", [("mpt3d_b", "kf"), ("mpt3d_a", "sskf"),
                                                     ("gps_static", "ikf")])
def test_c_run_tracks_equals_the_run_of_each_track(model_name, filter_name):
    """run_tracks (4 tracks advanced together, then singles) is each track's run, bit for bit."""
    model = catalog.load(model_name)
    num = model.numeric()
    mod = load_generated(model, filter_name, lang="c").c
    tracks = 7  # one block of 4 and three singles
    zs = np.stack([simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 60, s).zs
                   for s in range(tracks)])
    rng = np.random.default_rng(1)
    x0 = rng.normal(size=(tracks, model.n))
    if filter_name == "sskf":
        xs = mod.run_tracks(zs, x0)
        for t in range(tracks):
            np.testing.assert_array_equal(xs[t], mod.run(zs[t], x0[t]))
        return
    A = rng.normal(size=(tracks, model.n, model.n))
    P0 = A @ np.swapaxes(A, 1, 2) + np.eye(model.n)
    if model.P0_pattern == "diagonal":  # the code accepts a P0 inside its pattern only
        P0 = P0 * np.eye(model.n)
    xs, Ps = mod.run_tracks(zs, x0, P0)
    for t in range(tracks):
        x1, P1 = mod.run(zs[t], x0[t], P0[t])
        np.testing.assert_array_equal(xs[t], x1)
        np.testing.assert_array_equal(Ps[t], P1)
