"""The simulated flight of docs/navigation.md: the truth at 1 kHz with exact kinematics and the
sensors the INS/GNSS EKF (catalog model ``ins_gnss``) fuses.

The flight plan (times in s, NED, horizontal speed V):

- 0–10: at rest at the origin, level, heading north;
- 10–20: accelerating north at 1.5 m/s² to V = 15 m/s (level, heading north);
- 20–120: a level-to-climbing coordinated turn: the yaw rate and the climb rate rise from 0
  to 0.15 rad/s and 1 m/s over TURN_RAMP = 2 s along a raised cosine (so the bank angle and
  the flight-path angle change continuously), then stay; the horizontal speed stays 15 m/s.
  The body follows the velocity: heading = track, pitch = flight-path angle
  atan(climb rate / V), and the bank angle is the one that leaves no specific force along
  body y (a coordinated turn).

The truth: heading, climb rate and their derivatives are closed-form functions of t, so
velocity and acceleration are exact at any time; position is integrated from the velocity
with Simpson's rule on the 1 ms grid (error below 1e-15 m per step: exact to rounding). The
attitude is integrated as a piecewise-constant body rate: over each 1 ms the rate is the
constant one that turns the flight plan's attitude at the start into the one at the end,
and the quaternion is advanced by its exact exponential, q ← q ⊗ exp(ω·1 ms / 2) (not first
order). The specific force of each 1 ms is C(q)ᵀ (a − g) at its midpoint.

The sensors (seeded, numpy.random.default_rng(seed)):

- IMU at 100 Hz: an integrating IMU; its sample over [t_k, t_k + 10 ms] is the mean of the
  truth's ten 1 ms body rates and specific forces (delta angle and delta velocity over dt),
  plus the true biases (constant over the flight), plus white noise. The noise per sample
  has σ = σg (gyro) and σa (accelerometer), the input noise Qu of the filter: the model gives
  Qu = diag(σg², σa²) as the covariance of each input sample, so the per-sample σ is σg
  itself (as a density it would be σg·√dt rad/√s; the filter's Fu Qu Fuᵀ with Fu ∝ dt
  makes the per-step attitude variance σg² dt²/4).
- GNSS at 5 Hz: position and velocity plus white noise of R = diag(1.5², 1.5², 3², 0.1²,
  0.1², 0.2²).
- Barometer at 20 Hz: altitude −pd plus white noise of σ = 0.5 m.

Filter rows: row k of the inputs is the IMU sample over [t_k, t_k+1] (the u(k) that predicts
x(k+1) from x(k)); a measurement at t_k+1 sits in row k of its sensor's array, the other rows
NaN (no measurement at that step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.ins import constants as c
from derive.apps.ins import quaternion as quat


@dataclass(frozen=True)
class Plan:
    """The closed-form flight plan at times t (arrays)."""

    t: np.ndarray
    velocity: np.ndarray  # (..., 3) NED
    acceleration: np.ndarray  # (..., 3) NED
    attitude: np.ndarray  # (..., 4)


def _ramp(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raised-cosine ramp r from 0 (t ≤ ACCEL_END) to 1 (t ≥ ACCEL_END + TURN_RAMP): r, its
    time integral and its time derivative."""
    s = np.clip((t - c.ACCEL_END) / c.TURN_RAMP, 0.0, 1.0)
    ramp = 0.5 * (1.0 - np.cos(np.pi * s))
    after = np.maximum(t - c.ACCEL_END - c.TURN_RAMP, 0.0)
    integral = c.TURN_RAMP * (0.5 * s - np.sin(np.pi * s) / (2.0 * np.pi)) + after
    rate = np.where((s > 0.0) & (s < 1.0), 0.5 * np.pi * np.sin(np.pi * s) / c.TURN_RAMP, 0.0)
    return ramp, integral, rate


def plan(t: np.ndarray) -> Plan:
    """Velocity, acceleration and attitude of the flight plan at times t."""
    t = np.asarray(t, dtype=float)
    speed = c.ACCELERATION * np.clip(t - c.REST_END, 0.0, c.ACCEL_END - c.REST_END)
    speed_rate = np.where((t >= c.REST_END) & (t < c.ACCEL_END), c.ACCELERATION, 0.0)
    ramp, ramp_integral, ramp_rate = _ramp(t)
    heading = c.YAW_RATE * ramp_integral
    yaw_rate = c.YAW_RATE * ramp
    climb = c.CLIMB_RATE * ramp
    climb_rate = c.CLIMB_RATE * ramp_rate
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    velocity = np.stack([speed * cos_h, speed * sin_h, -climb], axis=-1)
    acceleration = np.stack([
        speed_rate * cos_h - speed * yaw_rate * sin_h,
        speed_rate * sin_h + speed * yaw_rate * cos_h,
        -climb_rate,
    ], axis=-1)
    pitch = np.arctan2(climb, np.maximum(speed, 1e-300))
    pitch = np.where(speed > 0.0, pitch, 0.0)
    # specific force in NED, then the bank that leaves none along body y
    force = acceleration - np.array([0.0, 0.0, c.GRAVITY])
    along = force[..., 0] * cos_h + force[..., 1] * sin_h
    across = -force[..., 0] * sin_h + force[..., 1] * cos_h
    roll = np.arctan2(across, -(np.sin(pitch) * along + np.cos(pitch) * force[..., 2]))
    return Plan(t, velocity, acceleration, quat.from_euler(heading, pitch, roll))


@dataclass(frozen=True)
class Truth:
    """The truth on the 1 kHz grid (N + 1 times) and per 1 ms interval (N)."""

    t: np.ndarray  # (N+1,)
    attitude: np.ndarray  # (N+1, 4), integrated
    velocity: np.ndarray  # (N+1, 3)
    position: np.ndarray  # (N+1, 3)
    body_rate: np.ndarray  # (N, 3), constant over each interval
    specific_force: np.ndarray  # (N, 3), body, at each interval's midpoint
    acceleration: np.ndarray  # (N, 3), NED, at each interval's midpoint
    plan_attitude: np.ndarray  # (N+1, 4), the flight plan's attitude (closed form)


def _integrate_attitude(q_start: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """q(k+1) = q(k) ⊗ increments[k], sequentially (Python floats: one pass, no NumPy per
    step)."""
    out = np.empty((len(increments) + 1, 4))
    q0, q1, q2, q3 = (float(v) for v in q_start)
    out[0] = q0, q1, q2, q3
    for k, (r0, r1, r2, r3) in enumerate(increments.tolist()):
        q0, q1, q2, q3 = (q0 * r0 - q1 * r1 - q2 * r2 - q3 * r3,
                          q0 * r1 + q1 * r0 + q2 * r3 - q3 * r2,
                          q0 * r2 - q1 * r3 + q2 * r0 + q3 * r1,
                          q0 * r3 + q1 * r2 - q2 * r1 + q3 * r0)
        out[k + 1] = q0, q1, q2, q3
    return out


def truth(duration: float = c.DURATION, dt: float = c.TRUTH_DT) -> Truth:
    """Integrate the flight plan at 1/dt Hz (see the module docstring)."""
    steps = int(round(duration / dt))
    t = np.arange(steps + 1) * dt
    mid = (np.arange(steps) + 0.5) * dt
    at_grid, at_mid = plan(t), plan(mid)
    # the constant rate of each interval, from the plan's attitude at its two ends
    relative = quat.multiply(quat.conjugate(at_grid.attitude[:-1]), at_grid.attitude[1:])
    body_rate = quat.to_rotation_vector(relative) / dt
    attitude = _integrate_attitude(at_grid.attitude[0], quat.from_rotation_vector(body_rate * dt))
    q_mid = quat.multiply(attitude[:-1], quat.from_rotation_vector(body_rate * (0.5 * dt)))
    force_ned = at_mid.acceleration - np.array([0.0, 0.0, c.GRAVITY])
    specific_force = np.einsum("kji,kj->ki", quat.rotation_matrix(q_mid), force_ned)
    # Simpson's rule on each interval
    increments = (at_grid.velocity[:-1] + 4.0 * at_mid.velocity + at_grid.velocity[1:]) * (dt / 6.0)
    position = np.vstack([np.zeros(3), np.cumsum(increments, axis=0)])
    return Truth(t, attitude, at_grid.velocity, position, body_rate, specific_force,
                 at_mid.acceleration, at_grid.attitude)


@dataclass(frozen=True)
class Flight:
    """The truth at the IMU rate and the sensor arrays the filter runs on.

    Row k of ``imu`` (steps, 6: gyro, accelerometer) drives the step from t[k] to t[k+1];
    ``gnss`` (steps, 6) and ``baro`` (steps, 1) hold at row k the measurement taken at
    t[k+1], NaN rows where there is none. ``states`` (steps + 1, 16) is the true state at
    t (true biases included); ``imu_clean`` is the IMU without biases and noise.
    """

    seed: int
    t: np.ndarray
    states: np.ndarray
    imu: np.ndarray
    imu_clean: np.ndarray
    dt: np.ndarray
    gnss: np.ndarray
    baro: np.ndarray
    truth: Truth

    @property
    def steps(self) -> int:
        return len(self.imu)

    @property
    def gnss_rows(self) -> np.ndarray:
        """Rows of the GNSS epochs."""
        return np.flatnonzero(~np.isnan(self.gnss[:, 0]))

    @property
    def baro_rows(self) -> np.ndarray:
        return np.flatnonzero(~np.isnan(self.baro[:, 0]))


def simulate(seed: int = 0, duration: float = c.DURATION) -> Flight:
    """The seeded flight of docs/navigation.md (see the module docstring)."""
    rng = np.random.default_rng(seed)
    tr = truth(duration)
    per_imu = int(round(c.IMU_DT / c.TRUTH_DT))
    steps = len(tr.body_rate) // per_imu
    rate = tr.body_rate[: steps * per_imu].reshape(steps, per_imu, 3).mean(axis=1)
    force = tr.specific_force[: steps * per_imu].reshape(steps, per_imu, 3).mean(axis=1)
    imu_clean = np.hstack([rate, force])
    noise = rng.standard_normal((steps, 6)) * np.array([c.SIGMA_GYRO] * 3 + [c.SIGMA_ACCEL] * 3)
    imu = imu_clean + np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS]) + noise
    grid = np.arange(steps + 1) * per_imu
    biases = np.tile(np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS]), (steps + 1, 1))
    states = np.hstack([tr.attitude[grid], tr.velocity[grid], tr.position[grid], biases])
    gnss = np.full((steps, 6), np.nan)
    rows = np.arange(c.GNSS_EVERY - 1, steps, c.GNSS_EVERY)
    exact = np.hstack([tr.position[grid[rows + 1]], tr.velocity[grid[rows + 1]]])
    gnss[rows] = exact + rng.standard_normal(exact.shape) * c.GNSS_STD
    baro = np.full((steps, 1), np.nan)
    rows = np.arange(c.BARO_EVERY - 1, steps, c.BARO_EVERY)
    baro[rows, 0] = -tr.position[grid[rows + 1], 2] + rng.standard_normal(len(rows)) * c.BARO_STD
    return Flight(seed, tr.t[grid], states, imu, imu_clean, np.full(steps, c.IMU_DT), gnss,
                  baro, tr)
