"""The RTS smoother of a model with inputs (B u, D u): generated Python and C against the
NumPy reference (1e-12) and against pykalman's smoother with the inputs as offsets."""

from __future__ import annotations

import numpy as np
import pytest
from pykalman import KalmanFilter

from derive import LinearModel
from derive.apps.verify import InputRun
from derive.filters.rts import reference
from derive.options import validate
from derive.pipeline import load_generated


def cart():
    """Position and speed pushed by a measured acceleration, measured with a known offset."""
    return LinearModel("cart_in", ["s", "v"], ["z"], F=[[1, 0.1], [0, 1]], H=[[1, 0]],
                       Q=[[1e-3, 0], [0, 2e-3]], R=[[0.05]], B=[[0.005, 0], [0.1, 0]],
                       D=[[0, 1]], inputs=["a", "off"], P0=[[1, 0], [0, 1]])


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


@pytest.fixture(scope="module")
def smoother():
    return load_generated(cart(), "rts")


def _data(steps=150):
    rng = np.random.default_rng(24)
    us = np.column_stack([np.sin(0.1 * np.arange(steps)), rng.normal(size=steps)])
    zs = np.cumsum(rng.normal(size=(steps, 1)), axis=0) * 0.1 + us[:, 1:]
    return zs, us


def test_rts_with_inputs_matches_the_reference_and_pykalman(smoother):
    model, (zs, us) = cart(), _data()
    num = model.numeric()

    run = InputRun(zs, us)  # what derive verify hands a filter of a model with inputs
    xs_ref, Ps_ref = reference(model, run, validate("rts", {}))
    for module in (smoother.python, smoother.c):
        xs, Ps = module.run(zs, us, num.x0, num.P0)
        assert relative(xs, xs_ref) <= 1e-12 and relative(Ps, Ps_ref) <= 1e-12
    # pykalman: its state t is x(t+1); offsets b_t = B u(t+1), d_t = D u(t)
    Bu, Du = us @ num.B.T, us @ num.D.T
    peer = KalmanFilter(transition_matrices=num.F, observation_matrices=num.H,
                        transition_covariance=num.GQGt, observation_covariance=num.R,
                        transition_offsets=np.vstack([Bu[1:], np.zeros((1, 2))]),
                        observation_offsets=Du,
                        initial_state_mean=num.F @ num.x0 + Bu[0],
                        initial_state_covariance=num.F @ num.P0 @ num.F.T + num.GQGt)
    means, covariances = peer.smooth(zs)
    assert relative(xs_ref, means) <= 1e-9 and relative(Ps_ref, covariances) <= 1e-9
