"""Innovation gating (options gate, gate_sensors): NIS from the gain's factorisation, the
update skipped above the chi-square quantile, NIS and applied reported."""

import numpy as np
import pytest
from scipy.stats import chi2

from derive import LinearModel, Sensor
from derive.cli import main
from derive.errors import OptionError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.pipeline import load_generated

SIGMA_GNSS = 2.0
OUTLIER_STEP = 60


def gnss_like():
    """A 2-D constant-velocity vehicle with a GNSS-like position fix (2) and a speed
    sensor (2), at dt = 0.1."""
    dt = 0.1
    F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    return LinearModel(
        "car", ["x", "y", "vx", "vy"], F=F, Q=np.diag([1e-4, 1e-4, 1e-2, 1e-2]),
        sensors=[Sensor("gnss", ["e", "n"], H=[[1, 0, 0, 0], [0, 1, 0, 0]],
                        R=np.eye(2) * SIGMA_GNSS**2),
                 Sensor("odo", ["ve", "vn"], H=[[0, 0, 1, 0], [0, 0, 0, 1]],
                        R=np.eye(2) * 0.01)],
        x0=[0, 0, 1, 0], P0=np.eye(4))


def data(steps=200):
    rng = np.random.default_rng(21)
    truth = np.c_[0.1 * np.arange(1, steps + 1), np.zeros(steps)]
    gnss = truth + SIGMA_GNSS * rng.normal(size=(steps, 2))
    gnss[np.arange(steps) % 10 != 0] = np.nan
    gnss[OUTLIER_STEP] = truth[OUTLIER_STEP] + 50 * SIGMA_GNSS  # a 50-sigma outlier
    odo = np.tile([1.0, 0.0], (steps, 1)) + 0.1 * rng.normal(size=(steps, 2))
    odo[np.arange(steps) % 2 != 0] = np.nan
    return {"gnss": gnss, "odo": odo}


@pytest.fixture(scope="module")
def gated():
    model = gnss_like()
    return model, load_generated(model, "kf", {"gate_sensors": "gnss=0.999"})


def test_the_threshold_is_the_chi_square_quantile_stated_in_the_header():
    unit = derive_unit(gnss_like(), "kf", {"gate": 0.999})
    threshold = float(chi2.ppf(0.999, 2))
    assert f"gate of gnss: update applied when nis <= {threshold!r}" in "\n".join(unit.facts)
    assert [s.gated for s in unit.sensors] == [True, True]


def test_a_50_sigma_outlier_is_rejected_and_reported(gated):
    model, generated = gated
    zs = data()
    x0, P0 = np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    ref = reference_run(model, {"gate_sensors": "gnss=0.999"}, zs, x0=x0, P0=P0)
    threshold = chi2.ppf(0.999, 2)
    for module in (generated.python, generated.c):
        xs, Ps, nis, applied = module.run(zs["gnss"], zs["odo"], x0, P0)
        assert nis[OUTLIER_STEP] > threshold and applied[OUTLIER_STEP] == 0.0
        fixes = ~np.isnan(zs["gnss"][:, 0])
        assert np.array_equal(np.isnan(nis), ~fixes)
        assert applied[fixes].sum() == fixes.sum() - 1  # only the outlier is rejected
        np.testing.assert_allclose(nis[fixes], ref.nis["gnss"][fixes], rtol=1e-12, atol=0)
        assert np.max(np.abs(xs - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))
        # rejected: the step's estimate is the prediction updated by the odometer alone
        assert abs(xs[OUTLIER_STEP, 0] - 0.1 * (OUTLIER_STEP + 1)) < 5 * SIGMA_GNSS


def test_with_gating_off_the_outlier_is_applied(gated):
    model, generated = gated
    zs = data()
    x0, P0 = np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    plain = load_generated(model, "kf")
    xs_plain, _ = plain.c.run(zs["gnss"], zs["odo"], x0, P0)
    xs_gated, *_ = gated[1].c.run(zs["gnss"], zs["odo"], x0, P0)
    ref = reference_run(model, {}, zs, x0=x0, P0=P0)
    assert ref.applied["gnss"][OUTLIER_STEP] == 1.0
    assert np.max(np.abs(xs_plain - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))
    jump = xs_plain[OUTLIER_STEP, 0] - xs_gated[OUTLIER_STEP, 0]
    assert jump > 2 * SIGMA_GNSS  # pulled towards the outlier, beyond the fix's noise


def test_update_function_returns_nis_and_applied(gated):
    model, generated = gated
    py = generated.python
    x, P = np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    S = np.eye(2) + np.eye(2) * SIGMA_GNSS**2
    for z in ([0.5, -0.3], [100.0, 0.0]):
        nu = np.array(z)
        expected = nu @ np.linalg.solve(S, nu)
        x_new, P_new, nis, applied = py.update_gnss(x, P.ravel(), z)
        assert nis[0] == pytest.approx(expected, rel=1e-12)
        assert applied[0] == float(expected <= chi2.ppf(0.999, 2))
        if not applied[0]:
            assert np.array_equal(np.asarray(x_new, float), x)
            assert np.array_equal(np.asarray(P_new, float), P)


def test_an_unknown_sensor_in_gate_sensors_is_one_line(capsys):
    with pytest.raises(OptionError, match=r"option 'gate_sensors' \(--gate-sensors\) names "
                                          r"sensor 'gps'; the sensors are gnss, odo"):
        derive_unit(gnss_like(), "kf", {"gate_sensors": "gps=0.99"})
    assert main(["generate", "mpt3d_b", "--filter", "kf", "--gate", "1.5"]) == 2
    assert "option 'gate' (--gate) must be a finite number in (0, 1), got 1.5" in \
        capsys.readouterr().err


def test_gate_is_refused_by_filters_without_sensor_support():
    with pytest.raises(OptionError, match=r"option 'gate' is taken by kf, ekf, eskf, not by lf"):
        derive_unit(LinearModel("a", ["x"], ["z"], F=[[1]], H=[[1]], Q=[[1]], R=[[1]]),
                    "lf", {"gate": 0.99})


def test_a_single_sensor_model_is_gated_through_its_one_update():
    model = LinearModel("a", ["x"], ["z"], F=[[1]], H=[[1]], Q=[[0.01]], R=[[1]],
                        x0=[0], P0=[[1]])
    generated = load_generated(model, "kf", {"gate": 0.99})
    assert list(generated.unit.programs) == ["predict", "update_all"]
    zs = np.array([[0.1], [-0.2], [40.0], [0.3]])
    xs, Ps, nis, applied = generated.c.run(zs, np.zeros(1), np.eye(1))
    assert applied.tolist() == [1.0, 1.0, 0.0, 1.0]
    assert nis[2] > chi2.ppf(0.99, 1) >= nis[[0, 1, 3]].max()
    assert xs[2, 0] == xs[1, 0]  # the rejected step keeps the prediction (F = 1)


@pytest.mark.parametrize("key", ["missing", "joseph"])
def test_missing_and_joseph_are_refused_with_sensors_in_one_line(key):
    with pytest.raises(OptionError, match=rf"option '{key}' is not taken with several sensors, "
                                          r"gating, sequential updates or update-first"):
        derive_unit(gnss_like(), "kf", {key: True})


def test_python_run_takes_tracks_each_with_its_own_absent_rows(gated):
    model, generated = gated
    zs = data()
    tracks = 3
    gnss = np.repeat(zs["gnss"][:, :, None], tracks, axis=2)
    odo = np.repeat(zs["odo"][:, :, None], tracks, axis=2)
    gnss[10, :, 1] = np.nan  # track 1 misses the fix of step 10
    x0, P0 = np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    xs, Ps, nis, applied = generated.python.run(
        gnss, odo, np.repeat(x0[:, None], tracks, axis=1),
        np.repeat(P0[:, :, None], tracks, axis=2))
    one = generated.python.run(zs["gnss"], zs["odo"], x0, P0)
    missed = dict(zs)
    missed["gnss"] = zs["gnss"].copy()
    missed["gnss"][10] = np.nan
    other = generated.python.run(missed["gnss"], zs["odo"], x0, P0)
    for track, expected in ((0, one), (1, other), (2, one)):
        assert np.array_equal(xs[..., track], expected[0])
        assert np.array_equal(nis[..., track], expected[2], equal_nan=True)
        assert np.array_equal(applied[..., track], expected[3])
