"""Update-first start (option start="update"): the first measurement updates x0 without a
prediction, pykalman's convention; predict-first stays the default."""

import numpy as np
import pytest
from pykalman import KalmanFilter

from derive import LinearModel, NonlinearModel
from derive.errors import OptionError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.pipeline import load_generated


def tracker():
    """A constant-velocity tracker in 2-D measured in position (pykalman's own kind)."""
    dt = 0.5
    F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    H = [[1, 0, 0, 0], [0, 1, 0, 0]]
    Q = (np.eye(4) * 0.05 + 0.01).tolist()
    R = [[1.0, 0.3], [0.3, 2.0]]
    return LinearModel("tracker", ["x", "y", "vx", "vy"], ["zx", "zy"], F=F, H=H, Q=Q, R=R)


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


@pytest.fixture(scope="module")
def update_first():
    model = tracker()
    return model, load_generated(model, "kf", {"start": "update"})


def test_update_first_matches_pykalman_filter(update_first):
    model, generated = update_first
    num = model.numeric()
    rng = np.random.default_rng(8)
    steps = 400
    zs = np.cumsum(rng.normal(size=(steps, 2)), axis=0) + rng.normal(size=(steps, 2))
    x0 = np.array([0.5, -0.5, 0.1, 0.2])
    P0 = np.diag([4.0, 4.0, 1.0, 1.0]) + 0.1
    peer = KalmanFilter(transition_matrices=num.F, observation_matrices=num.H,
                        transition_covariance=num.GQGt, observation_covariance=num.R,
                        initial_state_mean=x0, initial_state_covariance=P0)
    means, covariances = peer.filter(zs)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs, x0, P0)
        assert relative(xs, means) <= 1e-9
        assert relative(Ps, covariances) <= 1e-9


def test_update_first_with_missing_rows_matches_pykalman_masked(update_first):
    model, generated = update_first
    num = model.numeric()
    rng = np.random.default_rng(9)
    steps = 200
    zs = np.cumsum(rng.normal(size=(steps, 2)), axis=0)
    absent = rng.random(steps) < 0.3
    absent[0] = False
    masked = np.ma.masked_array(zs, mask=np.repeat(absent[:, None], 2, axis=1))
    zs[absent] = np.nan
    x0, P0 = np.zeros(4), np.eye(4)
    peer = KalmanFilter(transition_matrices=num.F, observation_matrices=num.H,
                        transition_covariance=num.GQGt, observation_covariance=num.R,
                        initial_state_mean=x0, initial_state_covariance=P0)
    means, covariances = peer.filter(masked)
    xs, Ps = generated.c.run(zs, x0, P0)
    assert relative(xs, means) <= 1e-9
    assert relative(Ps, covariances) <= 1e-9


def test_predict_first_stays_the_default_and_differs_at_the_first_step(update_first):
    model, generated = update_first
    default = load_generated(model, "kf")
    assert default.unit.run_kind == "timevarying"
    zs = np.ones((3, 2))
    x0, P0 = np.array([0.0, 0.0, 1.0, 1.0]), np.eye(4)
    first, _ = generated.python.run(zs, x0, P0)
    usual, _ = default.python.run(zs, x0, P0)
    num = model.numeric()
    ref = reference_run(model, {"start": "update"}, {"all": zs}, x0=x0, P0=P0)
    assert relative(first, ref.xs) <= 1e-12
    K = P0 @ num.H.T @ np.linalg.inv(num.H @ P0 @ num.H.T + num.R)
    assert np.allclose(first[0], x0 + K @ (zs[0] - num.H @ x0), rtol=1e-13, atol=0)
    assert not np.allclose(first[0], usual[0])


def test_update_first_ekf_matches_the_reference():
    model = NonlinearModel("pend", ["a", "w"], ["z"], f=["a + 0.1*w", "w - 0.1*sin(a)"],
                           h=["sin(a)"], Q=[[1e-4, 0], [0, 1e-4]], R=[[0.01]],
                           x0=[0.3, 0.0], P0=[[0.1, 0], [0, 0.1]])
    generated = load_generated(model, "ekf", {"start": "update"})
    assert list(generated.unit.programs) == ["predict", "update_all"]
    rng = np.random.default_rng(4)
    zs = np.sin(0.3 * np.cos(0.1 * np.arange(300)))[:, None] + 0.1 * rng.normal(size=(300, 1))
    x0, P0 = np.array([0.3, 0.0]), np.diag([0.1, 0.1])
    ref = reference_run(model, {"start": "update"}, {"all": zs}, x0=x0, P0=P0)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs, x0, P0)
        assert relative(xs, ref.xs) <= 1e-9 and relative(Ps, ref.Ps) <= 1e-9


def test_an_unknown_start_is_refused_naming_the_choices():
    with pytest.raises(OptionError, match=r"option 'start' \(--start\) must be one of "
                                          r"predict, update, got 'updat'"):
        derive_unit(tracker(), "kf", {"start": "updat"})
