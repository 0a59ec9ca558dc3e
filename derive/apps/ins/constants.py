"""The numbers of docs/navigation.md (the catalog model ``ins_gnss``) as the NumPy side of the
INS/GNSS application reads them: noise, gravity, start, flight plan and true biases.

They are the model's values, typed once here for the reference EKF and the simulation; the
catalog model file (derive/catalog/ins_gnss.toml) states the same numbers for derive, and
tests/navigation/test_nav_ins_catalog.py checks that the two agree.
"""

from __future__ import annotations

import numpy as np

GRAVITY = 9.80665
"""g (m/s²), down positive in NED."""

SIGMA_GYRO = 0.002
"""σg (rad/s): white noise on each gyro sample (the input noise Qu)."""
SIGMA_ACCEL = 0.05
"""σa (m/s²): white noise on each accelerometer sample."""
SIGMA_GYRO_BIAS = 1e-5
"""σbg (rad/s/√s): gyro bias random walk, variance σbg² dt per step."""
SIGMA_ACCEL_BIAS = 1e-4
"""σba (m/s²/√s): accelerometer bias random walk, variance σba² dt per step."""

GNSS_STD = np.array([1.5, 1.5, 3.0, 0.1, 0.1, 0.2])
"""Standard deviations of the GNSS measurement [pn, pe, pd, vn, ve, vd] (m, m/s)."""
BARO_STD = 0.5
"""Standard deviation of the barometric altitude (m)."""

STATES = ("q0", "q1", "q2", "q3", "vn", "ve", "vd", "pn", "pe", "pd",
          "bgx", "bgy", "bgz", "bax", "bay", "baz")
INPUTS = ("wx", "wy", "wz", "ax", "ay", "az")

X0 = np.array([1.0] + [0.0] * 15)
"""Start: level, heading north, at rest at the origin, biases zero."""
P0_STD = np.array([1e-2] * 4 + [0.5] * 3 + [3.0] * 3 + [0.002] * 3 + [0.1] * 3)
"""Square roots of P0's diagonal: 1e-4 (q), 0.5² (v), 3² (p), 0.002² (bg), 0.1² (ba)."""

TRUE_GYRO_BIAS = np.array([0.002, -0.001, 0.0015])
TRUE_ACCEL_BIAS = np.array([0.05, -0.03, 0.08])

IMU_DT = 0.01
"""IMU period (s), 100 Hz; the filter's dt."""
TRUTH_DT = 0.001
"""Truth integration period (s), 1 kHz."""
GNSS_EVERY = 20
"""IMU steps per GNSS epoch (5 Hz)."""
BARO_EVERY = 5
"""IMU steps per barometer sample (20 Hz)."""

REST_END = 10.0
"""End of the rest phase (s)."""
ACCEL_END = 20.0
"""End of the acceleration north (s)."""
DURATION = 120.0
"""End of the flight (s)."""
ACCELERATION = 1.5
"""Acceleration north (m/s²) from REST_END to ACCEL_END: 15 m/s at its end."""
YAW_RATE = 0.15
"""Yaw rate of the turn (rad/s)."""
CLIMB_RATE = 1.0
"""Climb rate of the turn (m/s)."""
TURN_RAMP = 2.0
"""Seconds over which yaw rate and climb rate rise from 0 to their values (raised cosine)."""


def input_noise() -> np.ndarray:
    """Qu = diag(σg² ×3, σa² ×3)."""
    return np.diag([SIGMA_GYRO ** 2] * 3 + [SIGMA_ACCEL ** 2] * 3)


def p0() -> np.ndarray:
    """P0 of docs/navigation.md."""
    return np.diag(P0_STD ** 2)
