"""One calling convention for run and step, whatever the start: run takes the per-step
arrays in one order (z, then u) and by name (zs=, us=, p=, the names the header's
interface states), refuses an array of the wrong shape in one line naming it, and step and
run return P as (n, n) arrays, in the generated Python and in derive.build's C wrappers."""

from __future__ import annotations

import numpy as np
import pytest
import sympy

from derive import LinearModel, NonlinearModel, Sensor
from derive.errors import ShapeError
from derive.filters.sensors import reference_run
from derive.pipeline import load_generated

dt = sympy.Symbol("dt", positive=True)


def cart():
    """A cart pushed by a measured acceleration: one input and one measurement (m = n_u =
    1), so that a call with z and u swapped has the right shapes."""
    return LinearModel("cart", ["s", "v"], ["z"], F=[[1, dt], [0, 1]], H=[[1, 0]],
                       Q=[[0.01, 0], [0, 0.02]], R=[[0.1]], B=[[dt * dt / 2], [dt]],
                       inputs=["a"], parameters=["dt"])


@pytest.fixture(scope="module")
def starts():
    model = cart()
    return model, {start: load_generated(model, "kf", {"start": start})
                   for start in ("predict", "update")}


def _data(steps=60):
    rng = np.random.default_rng(26)
    us = rng.normal(size=(steps, 1))
    zs = np.cumsum(rng.normal(size=(steps, 1)), axis=0)
    return zs, us, np.array([0.5, -0.2]), np.diag([2.0, 1.0]), np.full((steps, 1), 0.1)


def test_run_takes_z_then_u_for_every_start_and_by_name(starts):
    model, generated = starts
    zs, us, x0, P0, ps = _data()
    ref = reference_run(model, {"start": "update"}, {"all": zs}, us, ps, x0, P0)
    for module in (generated["update"].python, generated["update"].c):
        xs, Ps = module.run(zs, us, x0, P0, ps)
        assert float(np.max(np.abs(xs - ref.xs)) / np.max(np.abs(ref.xs))) <= 1e-12
        named = module.run(us=us, zs=zs, x0=x0, P0=P0, p=ps)
        np.testing.assert_array_equal(named[0], xs)
    for module in (generated["predict"].python, generated["predict"].c):
        first = module.run(zs, us, x0, P0, ps)
        np.testing.assert_array_equal(module.run(P0=P0, x0=x0, us=us, zs=zs, p=ps)[0],
                                      first[0])


@pytest.mark.parametrize("start", ["predict", "update"])
def test_a_per_step_array_of_the_wrong_shape_is_refused_naming_it(starts, start):
    _, generated = starts
    zs, us, x0, P0, ps = _data()
    for module in (generated[start].python, generated[start].c):
        with pytest.raises(ShapeError, match=r"^(run: us |cart_kf_run: argument 'u' ).*\(59, 1\)$"):
            module.run(zs, us[:-1], x0, P0, ps)
        with pytest.raises(TypeError, match="zss"):
            module.run(zss=zs, us=us, x0=x0, P0=P0, p=ps)


def test_step_and_the_sensor_functions_return_P_as_run_does(starts):
    """step (and predict, update_all) return P as an (n, n) array, as run returns
    (steps, n, n): the Python and the C wrapper alike, equal to run's first row."""
    _, generated = starts
    zs, us, x0, P0, ps = _data(1)
    for module in (generated["predict"].python, generated["predict"].c):
        x, P = module.step(x0, P0, zs[0], us[0], ps[0])
        xs, Ps = module.run(zs, us, x0, P0, ps)
        assert np.shape(P) == (2, 2) and Ps.shape == (1, 2, 2)
        np.testing.assert_array_equal(np.asarray(P), Ps[0])
        np.testing.assert_array_equal(np.asarray(x), xs[0])
    for module in (generated["update"].python, generated["update"].c):
        x, P = module.predict(x0, P0, us[0], ps[0])
        assert np.shape(P) == (2, 2)
        x, P = module.update_all(x, P, zs[0], us[0], ps[0])
        assert np.shape(P) == (2, 2)


def test_a_one_measurement_R_given_per_call_may_be_a_1x1_matrix():
    """R of a one-measurement update given per call: [[r]] (as C's wrapper takes it), [r]
    or r's flat row, the same update."""
    model = LinearModel("one", ["s", "v"], F=[[1, 1], [0, 1]], Q=[[0.1, 0], [0, 0.1]],
                        sensors=[Sensor("gps", ["zs"], H=[[1, 0]], R="argument")])
    python = load_generated(model, "kf", lang="python").python
    x, P = np.array([0.3, -0.1]), np.array([[2.0, 0.5], [0.5, 1.0]])
    flat = python.update_gps(x, P, [1.2], [0.4])
    for R in ([[0.4]], np.array([[0.4]])):
        got = python.update_gps(x, P, [1.2], R)
        np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(flat[0]))
        np.testing.assert_array_equal(got[1], flat[1])


def test_the_ekf_predict_needs_no_p_it_does_not_read():
    """A free parameter in h alone: the EKF's predict does not read p, so p may be left
    out (Python); update1, which reads it, still takes it."""
    a, w, g = sympy.symbols("a w g", real=True)
    model = NonlinearModel("pend", ["a", "w"], ["z"], f=[a + w / 10, w - sympy.sin(a) / 10],
                           h=[g * sympy.sin(a)], Q=[[1e-4, 0], [0, 1e-4]], R=[[0.01]],
                           parameters=["g"])
    python = load_generated(model, "ekf", lang="python").python
    x, P = [0.3, 0.1], np.eye(2)
    without = python.predict(x, P)
    np.testing.assert_array_equal(without[1], python.predict(x, P, [2.0])[1])
    with pytest.raises(TypeError):
        python.update1(x, P, [0.2])
