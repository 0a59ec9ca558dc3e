"""The simulated flight of SPEC section 8 (derive.apps.ins.flight): the truth's physics and
the sensors' timing and noise."""

from __future__ import annotations

import numpy as np
import pytest

from derive.apps.ins import constants as c
from derive.apps.ins import flight as fl
from derive.apps.ins import quaternion as quat


@pytest.fixture(scope="module")
def flight():
    return fl.simulate(seed=3)


def _midpoint_rotation(tr):
    dt = np.diff(tr.t)[:, None]
    return quat.rotation_matrix(quat.multiply(tr.attitude[:-1],
                                              quat.from_rotation_vector(tr.body_rate * dt / 2)))


def test_quaternion_helpers_match_spec_and_rotation_order():
    rng = np.random.default_rng(1)
    yaw, pitch, roll = rng.uniform(-1, 1, 3)
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0],
                   [-np.sin(pitch), 0, np.cos(pitch)]])
    rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    q = quat.from_euler(yaw, pitch, roll)
    assert np.allclose(quat.rotation_matrix(q), rz @ ry @ rx, rtol=0, atol=1e-15)
    assert np.allclose(quat.to_euler(q), [yaw, pitch, roll], rtol=0, atol=1e-14)
    r = quat.from_euler(*rng.uniform(-1, 1, 3))
    # C(q ⊗ r) = C(q) C(r): the product composes rotations body -> NED
    assert np.allclose(quat.rotation_matrix(quat.multiply(q, r)),
                       quat.rotation_matrix(q) @ quat.rotation_matrix(r), rtol=0, atol=1e-15)
    phi = rng.normal(size=3)
    assert np.allclose(quat.to_rotation_vector(quat.from_rotation_vector(phi)), phi,
                       rtol=0, atol=1e-14)


def test_attitude_integrated_exactly_tracks_the_plan(flight):
    tr = flight.truth
    # the exponential of each constant 1 ms rate lands on the plan's next attitude: what is
    # left is rounding accumulated over 120 000 products
    rounding = len(tr.body_rate) * 4 * np.finfo(float).eps
    assert np.abs(tr.attitude - tr.plan_attitude).max() < rounding
    assert np.abs(np.linalg.norm(tr.attitude, axis=1) - 1).max() < rounding
    # a first-order step (q ⊗ [1, ω dt/2]) would be off by (|ω| dt)²/8 per step: the truth is not
    first_order = quat.multiply(tr.attitude[:-1], np.hstack([np.ones((len(tr.body_rate), 1)),
                                                              tr.body_rate * c.TRUTH_DT / 2]))
    step_error = np.abs(first_order - tr.attitude[1:]).max()
    assert step_error > 100 * np.abs(tr.attitude - tr.plan_attitude).max() / len(tr.body_rate)


def test_specific_force_is_the_acceleration_seen_in_the_body(flight):
    tr = flight.truth
    dt = c.TRUTH_DT
    rotated = np.einsum("kij,kj->ki", _midpoint_rotation(tr), tr.specific_force)
    gravity = np.array([0.0, 0.0, c.GRAVITY])
    # C(q) f + g is the NED acceleration at the interval's midpoint, to rounding: C(q)ᵀ
    # then C(q) with |q| off 1 by the integration's rounding (a relative 2 (|q|² - 1))
    drift = np.abs(np.linalg.norm(tr.attitude, axis=1) ** 2 - 1).max()
    largest = np.linalg.norm(tr.specific_force, axis=1).max()
    tolerance = 4 * (drift + 8 * np.finfo(float).eps) * largest
    assert np.abs(rotated + gravity - tr.acceleration).max() < tolerance
    # ... and that acceleration is the velocity's change: the midpoint rule errs by at most
    # dt²/24 max|a''| (a'' from second differences of the midpoint accelerations)
    chord = np.diff(tr.velocity, axis=0) / dt
    smooth = np.ones(len(chord), bool)
    for edge in (c.REST_END, c.ACCEL_END):  # acceleration steps: a'' is a delta there
        smooth[int(round(edge / dt)) - 2: int(round(edge / dt)) + 2] = False
    jerk_rate = np.abs(np.diff(tr.acceleration[smooth], 2, axis=0)).max() / dt ** 2
    rounding = 2 * np.abs(tr.velocity).max() * np.finfo(float).eps / dt
    assert np.abs(chord - tr.acceleration)[smooth].max() \
        <= dt ** 2 / 24 * jerk_rate * 1.01 + rounding
    # position is the velocity's integral: its chord is the trapezoid's mean velocity to
    # dt²/12 max|a'|
    jerk = np.abs(np.diff(tr.acceleration[smooth], axis=0)).max() / dt
    trapezoid = (tr.velocity[:-1] + tr.velocity[1:]) / 2
    assert np.abs(np.diff(tr.position, axis=0) / dt - trapezoid).max() \
        <= dt ** 2 / 12 * jerk * 1.01 + 2 * np.abs(tr.position).max() * np.finfo(float).eps / dt


def test_turn_is_coordinated(flight):
    tr = flight.truth
    dt = c.TRUTH_DT
    # no specific force along body y: the bank is computed for the plan's attitude at each
    # midpoint; the integrated attitude at the midpoint differs from it by at most
    # dt² max|ω'| / 8 rad, so the lateral force is below g times that
    angular_acceleration = np.abs(np.diff(tr.body_rate, axis=0)).max() / dt
    bound = np.linalg.norm(tr.specific_force, axis=1).max() * dt ** 2 * angular_acceleration / 8
    assert np.abs(tr.specific_force[:, 1]).max() <= bound
    # the body x axis follows the velocity once moving
    moving = np.linalg.norm(tr.velocity, axis=1) > 1.0
    x_axis = quat.rotation_matrix(tr.attitude[moving])[:, :, 0]
    direction = tr.velocity[moving] / np.linalg.norm(tr.velocity[moving], axis=1)[:, None]
    assert np.abs(x_axis - direction).max() < 1e-11
    # banked into the right turn: tan(roll) = V ψ' / (g cos θ), θ the flight-path angle
    euler = quat.to_euler(tr.attitude)
    late = tr.t >= c.ACCEL_END + c.TURN_RAMP
    horizontal = 15.0
    expected_roll = np.arctan2(horizontal * c.YAW_RATE,
                               c.GRAVITY * np.cos(np.arctan2(c.CLIMB_RATE, horizontal)))
    assert np.abs(euler[late, 2] - expected_roll).max() < 1e-9


def test_speeds_and_rates_as_specified(flight):
    tr = flight.truth
    t = tr.t
    speed = np.linalg.norm(tr.velocity[:, :2], axis=1)
    rest = t <= c.REST_END
    assert np.abs(tr.velocity[rest]).max() == 0 and np.abs(tr.position[rest]).max() == 0
    assert np.abs(tr.attitude[rest] - [1, 0, 0, 0]).max() == 0
    accelerating = (t > c.REST_END) & (t <= c.ACCEL_END)
    assert np.allclose(speed[accelerating], c.ACCELERATION * (t[accelerating] - c.REST_END),
                       rtol=0, atol=1e-12)
    assert np.abs(tr.velocity[accelerating, 1:]).max() == 0
    turning = t >= c.ACCEL_END
    assert np.allclose(speed[turning], c.ACCELERATION * (c.ACCEL_END - c.REST_END),
                       rtol=0, atol=1e-12)
    steady = t >= c.ACCEL_END + c.TURN_RAMP
    assert np.allclose(-tr.velocity[steady, 2], c.CLIMB_RATE, rtol=0, atol=1e-15)
    heading = np.unwrap(quat.to_euler(tr.attitude[steady])[:, 0])
    assert np.allclose(np.diff(heading) / c.TRUTH_DT, c.YAW_RATE, rtol=0, atol=1e-8)
    # altitude: the climb rate's integral, pd from Simpson's integration of vd
    expected_climb = c.CLIMB_RATE * (t[-1] - c.ACCEL_END - c.TURN_RAMP / 2)
    assert abs(-tr.position[-1, 2] - expected_climb) < 1e-9


def test_sensors_timing_biases_and_noise(flight):
    steps = int(round(c.DURATION / c.IMU_DT))
    assert flight.imu.shape == (steps, 6) and np.all(flight.dt == c.IMU_DT)
    assert np.array_equal(flight.gnss_rows, np.arange(c.GNSS_EVERY - 1, steps, c.GNSS_EVERY))
    assert np.array_equal(flight.baro_rows, np.arange(c.BARO_EVERY - 1, steps, c.BARO_EVERY))
    bias = np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS])
    noise = flight.imu - flight.imu_clean - bias
    sigma = np.array([c.SIGMA_GYRO] * 3 + [c.SIGMA_ACCEL] * 3)
    # sample σ within 5 standard errors (σ/√(2N)) of σ
    spread = noise.std(axis=0)
    assert np.all(np.abs(spread / sigma - 1) < 5 / np.sqrt(2 * steps))
    # the clean IMU is the mean of the truth's 1 ms values over each 10 ms
    per = int(round(c.IMU_DT / c.TRUTH_DT))
    assert np.allclose(flight.imu_clean[7, :3], flight.truth.body_rate[7 * per:8 * per].mean(0),
                       rtol=0, atol=1e-15)
    # GNSS at row k measures the truth at t[k+1]
    rows = flight.gnss_rows
    truth_next = flight.states[rows + 1]
    gnss_noise = flight.gnss[rows] - np.hstack([truth_next[:, 7:10], truth_next[:, 4:7]])
    assert np.all(np.abs(gnss_noise.std(axis=0) / c.GNSS_STD - 1) < 5 / np.sqrt(2 * len(rows)))
    rows = flight.baro_rows
    baro_noise = flight.baro[rows, 0] + flight.states[rows + 1, 9]
    assert abs(baro_noise.std() / c.BARO_STD - 1) < 5 / np.sqrt(2 * len(rows))
    # seeded
    again = fl.simulate(seed=3)
    assert np.array_equal(again.imu, flight.imu)
    assert np.array_equal(again.gnss, flight.gnss, equal_nan=True)
