"""Update-first start (option start="update") for the filters whose step fuses the
prediction and the update (the IKF and the UD filter) and for the RTS smoother: run's step 0
calls the unit's ``update`` (the family's step of the model without a prediction: F = I,
no process noise, no input in the prediction), so x(0/0), P(0/0) are x0, P0 updated with
z(0), pykalman's convention; the smoother's row 0 is then x(0/N), P(0/N), the first of
what pykalman's smooth returns."""

import numpy as np
import pytest
from pykalman import KalmanFilter

from derive import LinearModel, build_c, generate, load_python, reference
from derive.errors import OptionError
from derive.filters import derive_unit
from derive.flops import count, count_c_function
from derive.options import validate

FILTERS = ("ikf", "udkf", "rts")
STEPS = 60


def tracker(inputs: bool = False) -> LinearModel:
    """A constant-velocity tracker in 2-D measured in position, R correlated; with
    ``inputs``: an acceleration input (B) and a measurement offset (D)."""
    dt = 0.5
    F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    H = [[1, 0, 0, 0], [0, 1, 0, 0]]
    Q = (np.eye(4) * 0.05 + 0.01).tolist()
    R = [[1.0, 0.3], [0.3, 2.0]]
    if not inputs:
        return LinearModel("tracker", ["x", "y", "vx", "vy"], ["zx", "zy"], F=F, H=H, Q=Q,
                           R=R)
    return LinearModel("pushed", ["x", "y", "vx", "vy"], ["zx", "zy"], F=F, H=H, Q=Q, R=R,
                       inputs=["a", "off"], B=[[dt**2 / 2, 0], [0, 0], [dt, 0], [0, 0]],
                       D=[[0, 1], [0, 0]])


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Python and C of each filter with start=update for the tracker, and the smoother
    for the tracker with inputs: one C build."""
    out = tmp_path_factory.mktemp("update_first")
    generate(tracker(), list(FILTERS), out=out, options={"start": "update"})
    generate(tracker(inputs=True), ["rts"], out=out, options={"start": "update"})
    paths = [out / "tracker" / f"{f}.c" for f in FILTERS] + [out / "pushed" / "rts.c"]
    c = build_c(paths)
    return out, c


def _data():
    rng = np.random.default_rng(8)
    zs = np.cumsum(rng.normal(size=(STEPS, 2)), axis=0) + rng.normal(size=(STEPS, 2))
    return zs, np.array([0.5, -0.5, 0.1, 0.2]), np.diag([4.0, 4.0, 1.0, 1.0]) + 0.1


def _relative(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


def _peer(model, x0, P0, **offsets) -> KalmanFilter:
    num = model.numeric()
    return KalmanFilter(transition_matrices=num.F, observation_matrices=num.H,
                        transition_covariance=num.GQGt, observation_covariance=num.R,
                        initial_state_mean=x0, initial_state_covariance=P0, **offsets)


@pytest.mark.parametrize("name", FILTERS)
def test_update_first_matches_pykalman(built, name):
    """ikf, udkf: pykalman's filter; rts: its smooth, row 0 being x(0/N), P(0/N); Python
    and C, 1e-9 relative (pykalman's own arithmetic differs)."""
    out, c = built
    zs, x0, P0 = _data()
    peer = _peer(tracker(), x0, P0)
    means, covariances = peer.smooth(zs) if name == "rts" else peer.filter(zs)
    python = load_python(out / "tracker" / f"{name}.py")
    for module in (python, c[f"tracker_{name}"]):
        xs, Ps = module.run(zs, x0, P0)
        assert _relative(xs, means) <= 1e-9, module
        assert _relative(Ps, covariances) <= 1e-9, module
        assert _relative(xs[0], means[0]) <= 1e-9  # x(0/0), or x(0/N) for the smoother


def test_the_smoother_with_inputs_matches_pykalman_with_offsets(built):
    """B u(k) predicts x(k/k-1) from step 1 (pykalman's transition offset k - 1), D u(k)
    offsets z(k) (its observation offset k), update-first: the reference and the
    generated smoother, Python and C."""
    out, c = built
    model = tracker(inputs=True)
    num = model.numeric()
    zs, x0, P0 = _data()
    us = np.random.default_rng(3).normal(size=(STEPS, 2))
    B, D = np.asarray(num.B, float), np.asarray(num.D, float)
    peer = _peer(model, x0, P0, transition_offsets=us[1:] @ B.T,
                 observation_offsets=us @ D.T)
    means, covariances = peer.smooth(zs)
    mine = reference.smoother.rts(num, zs, x0, P0, us=us, start="update")
    python = load_python(out / "pushed" / "rts.py")
    for xs, Ps in (mine, python.run(zs, us, x0, P0), c["pushed_rts"].run(zs, us, x0, P0)):
        assert _relative(xs, means) <= 1e-9
        assert _relative(Ps, covariances) <= 1e-9


def test_the_update_is_a_function_of_its_own_counted_as_printed(built):
    """The header states the start; ``MODEL_FILTER_update`` is the update alone: its C
    text counts what the program counts, and it has no prediction (fewer operations than
    the step)."""
    out, _ = built
    unit = derive_unit(tracker(), "ikf", {"start": "update"})
    text = (out / "tracker" / "ikf.c").read_text()
    assert "start: update-first: step 0 updates x0, P0" in text
    update = count(unit.programs["update"], "c")
    assert count_c_function(text, "tracker_ikf_update") == update
    assert update.flops < count(unit.programs["step"], "c").flops


def test_filters_without_the_option_refuse_it():
    for name in ("lf", "jklf", "sskf", "kfp"):
        with pytest.raises(OptionError, match="start"):
            validate(name, {"start": "update"})
