"""One calling convention for run and step, whatever the start: run takes the per-step
arrays in one order (z, then u) and by name (zs=, us=, p=, the names the header's
interface states), refuses an array of the wrong shape in one line naming it, and step and
run return P as (n, n) arrays, in the generated Python and in derive.build's C wrappers."""

from __future__ import annotations

import numpy as np
import pytest
import sympy

from derive import LinearModel
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
