"""The 24-state flight-controller EKF (catalog model ``ins_fc24``, derive.apps.ins.fc24): the
catalog states the application's numbers and equations, the hand-written Jacobians match
finite differences, the committed generated Python equals the NumPy reference on a short
flight with every sensor, and the estimate of a 40 s flight is inside its own 3σ."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import catalog
from derive.apps.ins import compare, fc24
from derive.apps.ins import constants as c
from derive.build import load_python
from derive.filters.sensors import unit_norm_noise

GENERATED = Path(__file__).resolve().parents[2] / "generated" / "ins_fc24" / "ekf.py"
AGREEMENT = 1e-9
"""Generated against the reference, relative (as derive.apps.ins.run.AGREEMENT)."""


@pytest.fixture(scope="module")
def model():
    return catalog.load(fc24.MODEL)


def _point(rng) -> tuple[np.ndarray, np.ndarray, float]:
    q = rng.standard_normal(4)
    x = np.concatenate([q / np.linalg.norm(q), rng.standard_normal(20) * 3.0])
    return x, rng.standard_normal(6) * 0.05, float(rng.uniform(0.005, 0.02))


def test_catalog_numbers_and_equations_are_the_applications(model):
    assert tuple(model.states) == fc24.STATES
    assert tuple(u.name for u in model.inputs) == fc24.INPUTS
    assert [s.name for s in model.sensors] == list(fc24.SENSORS)
    assert np.array_equal(np.array(model.x0, dtype=float).ravel(), fc24.X0)
    assert np.allclose(np.array(model.P0, dtype=float), fc24.p0(), rtol=1e-15, atol=0)
    for sensor in model.sensors:
        assert np.allclose(np.array(sensor.R, dtype=float), fc24.SENSORS[sensor.name][1],
                           rtol=1e-15, atol=0)
    xs, us = list(model.state_symbols), list(model.inputs)
    (dt,) = model.parameters
    values = {sympy.Symbol(k, real=True): v for k, v in model.values.items()}
    f = model.f.subs(values)
    lam = {name: sympy.lambdify([xs, us, dt], expr, "numpy") for name, expr in
           (("f", f), ("F", f.jacobian(xs)), ("Fu", f.jacobian(us)), ("Q", model.Q.subs(values)),
            ("Qu", model.Qu.subs(values)))}
    h = {s.name: sympy.lambdify([xs], sympy.Matrix(s.h).subs(values), "numpy")
         for s in model.sensors}
    rng = np.random.default_rng(3)
    for _ in range(3):
        x, u, step = _point(rng)
        jac, jac_u = fc24.jacobians(x, u, step)
        assert np.allclose(np.ravel(lam["f"](x, u, step)), fc24.f(x, u, step), rtol=1e-14,
                           atol=1e-15)
        assert np.allclose(np.array(lam["F"](x, u, step), dtype=float), jac, rtol=1e-14,
                           atol=1e-15)
        assert np.allclose(np.array(lam["Fu"](x, u, step), dtype=float), jac_u, rtol=1e-14,
                           atol=1e-15)
        assert np.allclose(np.array(lam["Qu"](x, u, step), dtype=float),
                           fc24.input_noise(step), rtol=1e-14, atol=0)
        assert np.allclose(np.diag(np.array(lam["Q"](x, u, step), dtype=float)),
                           fc24.walk(step), rtol=1e-14, atol=0)
        for name, (measure, _) in fc24.SENSORS.items():
            assert np.allclose(np.ravel(h[name](x)), measure(x)[0], rtol=1e-14, atol=1e-15)


def _central(fn, at: np.ndarray, step: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(len(at)):
        e = np.zeros(len(at))
        e[i] = step
        cols.append((fn(at + e) - fn(at - e)) / (2 * step))
    return np.stack(cols, axis=-1)


def test_hand_jacobians_match_central_differences():
    # central differences of a polynomial of degree <= 3 are exact to O(step²) and rounding
    rng = np.random.default_rng(5)
    x, u, step = _point(rng)
    jac, jac_u = fc24.jacobians(x, u, step)
    assert np.abs(_central(lambda y: fc24.f(y, u, step), x) - jac).max() < 1e-8
    assert np.abs(_central(lambda v: fc24.f(x, v, step), u) - jac_u).max() < 1e-8
    for name, (measure, _) in fc24.SENSORS.items():
        numeric = _central(lambda y, measure=measure: measure(y)[0], x)
        assert np.abs(numeric - measure(x)[1]).max() < 1e-7, name


def test_generated_python_equals_the_reference_with_every_sensor():
    # 1.5 s from rest, the airspeed measured from the start and the wind's estimate started
    # at [2, -1] (at v = w = 0 the airspeed's H is 0/0): every sensor updates
    short = fc24.simulate(seed=2, duration=1.5, airspeed_from=0.0)
    x0 = fc24.X0.copy()
    x0[fc24.W_ROWS] = [2.0, -1.0]
    assert all(len(short.rows(name)) > 0 for name in fc24.SENSORS)
    module = load_python(GENERATED)
    xs, Ps = module.run(*(short.measured[name] for name in fc24.SENSORS), short.imu, x0,
                        fc24.p0(), short.dt[:, None])
    xs = np.asarray(xs).reshape(short.steps, fc24.N_STATES)
    Ps = np.asarray(Ps).reshape(short.steps, fc24.N_STATES, fc24.N_STATES)
    ref = fc24.run(short, x0=x0)
    scale = np.maximum(np.abs(ref.xs).max(axis=0), fc24.P0_STD)
    assert (np.abs(xs - ref.xs).max(axis=0) / scale).max() <= AGREEMENT
    assert compare.covariance_agreement(Ps, ref.Ps) <= AGREEMENT


def test_predict_uses_the_unit_quaternion_and_renormalises_q_first(model):
    """The EKF's predict reduces Fu Qu Fu^T by q0² + q1² + q2² + q3² = 1 (the velocity
    block C Qa C^T to Qa, the quaternion block's diagonal to 1 - q_i²) and renormalises q
    at its start, so the reduction is exact: the reduced entries equal the full product
    at a unit q (to rounding) and not at q scaled by 1.1; the generated predict at 1.1 q
    is its predict at q; its header names the invariant."""
    reduced = unit_norm_noise(model)
    assert {(4, 4), (5, 5), (6, 6), (4, 5), (0, 0)} <= set(reduced)
    rng = np.random.default_rng(3)
    x, u, dt = _point(rng)
    _, jac_u = fc24.jacobians(x, u, dt)
    exact = jac_u @ fc24.input_noise(dt) @ jac_u.T
    values = dict(zip(model.state_symbols, x)) | {p: dt for p in model.parameters}
    for (i, j), entry in reduced.items():
        assert float(entry.xreplace(values)) == pytest.approx(exact[i, j], rel=1e-12,
                                                             abs=1e-12 * exact.max())
    scaled = x.copy()
    scaled[:4] *= 1.1
    _, jac_scaled = fc24.jacobians(scaled, u, dt)
    off = jac_scaled @ fc24.input_noise(dt) @ jac_scaled.T
    values |= dict(zip(model.state_symbols[:4], scaled[:4]))
    assert abs(float(reduced[4, 4].xreplace(values)) - off[4, 4]) > 1e-3 * off[4, 4]
    module = load_python(GENERATED)
    P = np.eye(24) * 0.01
    at_unit = np.asarray(module.predict(x, P.ravel(), u, [dt])[1])
    at_scaled = np.asarray(module.predict(scaled, P.ravel(), u, [dt])[1])
    assert np.max(np.abs(at_scaled - at_unit)) <= 1e-15 * np.max(np.abs(at_unit))
    assert "invariants used: q0^2 + q1^2 + q2^2 + q3^2 = 1" in GENERATED.read_text()


def test_estimate_inside_its_three_sigma_on_a_turning_flight():
    # 40 s: rest, acceleration, 20 s of the turn (the wind and the magnetic states become
    # observable in it); the reference, which the generated code equals (above)
    fl = fc24.simulate(seed=0, duration=40.0)
    run = fc24.run(fl)
    err = run.xs - fl.states[1:]
    sd = np.sqrt(np.diagonal(run.Ps, axis1=1, axis2=2))
    after = fl.t[1:] >= 30.0  # the wind, 10 s into the turn
    for rows in (fc24.V_ROWS, fc24.P_ROWS, fc24.BG_ROWS, fc24.BA_ROWS, fc24.M_ROWS,
                 fc24.MB_ROWS):
        inside = np.all(np.abs(err[:, rows]) <= 3 * sd[:, rows], axis=1).mean()
        assert inside >= compare.INSIDE_BAR, (rows, inside)
    inside = np.all(np.abs(err[after, fc24.W_ROWS]) <= 3 * sd[after, fc24.W_ROWS], axis=1)
    assert inside.mean() >= compare.INSIDE_BAR
    assert np.abs(err[-1, fc24.W_ROWS]).max() < 1.0  # from 3.6 m/s at the start


def test_imu_deltas_are_the_rates_integrated_over_the_step():
    fl = fc24.simulate(seed=4, duration=0.5)
    assert fl.imu.shape == (fl.steps, 6)
    # at rest, level: Δv is the specific force −g (up in body z) times dt plus the biases
    mean = fl.imu.mean(axis=0) / c.IMU_DT
    assert np.allclose(mean[3:], c.TRUE_ACCEL_BIAS + [0.0, 0.0, -c.GRAVITY],
                       atol=4 * c.SIGMA_ACCEL / np.sqrt(fl.steps))
    assert np.allclose(mean[:3], c.TRUE_GYRO_BIAS, atol=4 * c.SIGMA_GYRO / np.sqrt(fl.steps))
