"""The 24-state flight-controller EKF of the catalog model ``ins_fc24``: its numbers, its
simulated flight and a NumPy EKF written by hand from its equations (docs/navigation.md,
"The 24-state EKF").

State x = [q0..q3, vn, ve, vd, pn, pe, pd, bg(3), ba(3), m(3), mb(3), wn, we]: the first 16
as ``ins_gnss`` (derive.apps.ins.reference), then the earth magnetic field m (NED, gauss), the
body magnetic bias mb (gauss) and the horizontal wind w (m/s). Input u = [Δθ(3), Δv(3)], the
IMU's delta angle and delta velocity over the step (body axes), as flight controllers
integrate the IMU; parameter dt. Predict (first order):

    q' = q ⊗ [1, (Δθ − bg dt)/2],  v' = v + C(q)(Δv − ba dt) + g dt,  p' = p + v dt

and the rest constant; P' = F P Fᵀ + Fu Qu Fuᵀ + diag(0 ×10, σbg² dt ×3, σba² dt ×3, σm² dt
×3, σmb² dt ×3, σw² dt ×2) with Qu = diag(σg² dt² ×3, σa² dt² ×3), the variances of the
deltas. Sensors: gnss (p, v), baro (−pd), mag (C(q)ᵀ m + mb) and airspeed (|v − w|,
w = [wn, we, 0]); each update is the batch EKF update with q renormalised after it
(derive.apps.ins.reference.update_with). The Jacobians below are worked out on paper
(C(q)ᵀ = C(q*) with q* the conjugate, so ∂(C(q)ᵀ m)/∂q is the ∂(C(q) a)/∂q of ins_gnss at
q*, its last three columns negated), checked against finite differences in the tests.

The flight is ins_gnss's (derive.apps.ins.flight.truth: the same plan and 1 kHz truth); the
sensors: the IMU's deltas over each 10 ms step (the truth's mean rate and specific force
times dt) plus the biases times dt plus white noise of σg dt and σa dt; GNSS and barometer
as ins_gnss; the magnetometer at 50 Hz, C(q)ᵀ m + mb of the truth plus white noise; the
airspeed at 10 Hz from 20 s in (in flight), |v − w| of the truth plus white noise.
Measurements sit in the row of the step that ends at their time (as ins_gnss), NaN
elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.ins import constants as c
from derive.apps.ins import flight as gnss_flight
from derive.apps.ins.quaternion import multiply, rotation_matrix
from derive.apps.ins.reference import (
    BA_ROWS,
    BG_ROWS,
    P_ROWS,
    Q_ROWS,
    V_ROWS,
    left_matrix,
    right_matrix,
    rotated_jacobian,
    unit_quaternion,
    update_with,
)

MODEL = "ins_fc24"
N_STATES = 24
STATES = c.STATES + ("mn", "me", "md", "mbx", "mby", "mbz", "wn", "we")
INPUTS = ("dthx", "dthy", "dthz", "dvx", "dvy", "dvz")
M_ROWS, MB_ROWS, W_ROWS = slice(16, 19), slice(19, 22), slice(22, 24)

SIGMA_EARTH_FIELD = 1e-4
"""σm (gauss/√s): random walk of the earth field."""
SIGMA_BODY_FIELD = 1e-4
"""σmb (gauss/√s): random walk of the body magnetic bias."""
SIGMA_WIND = 0.1
"""σw (m/s/√s): random walk of the wind."""
MAG_STD = 0.005
"""Standard deviation of each magnetometer axis (gauss)."""
AIRSPEED_STD = 0.5
"""Standard deviation of the true airspeed (m/s)."""
MAG_EVERY = 2
"""IMU steps per magnetometer sample (50 Hz)."""
AIRSPEED_EVERY = 10
"""IMU steps per airspeed sample (10 Hz)."""
AIRSPEED_FROM = c.ACCEL_END
"""The airspeed is measured from this time (s), in flight at 15 m/s: at rest it is |w|
alone, whose direction is not observable (a pitot is not fused on the ground)."""

TRUE_EARTH_FIELD = np.array([0.21, 0.02, 0.43])
TRUE_BODY_FIELD = np.array([0.02, -0.01, 0.015])
TRUE_WIND = np.array([3.0, -2.0])

X0 = np.concatenate([c.X0, [0.2, 0.0, 0.45], np.zeros(3), np.zeros(2)])
"""Start: ins_gnss's, the earth field of a field model [0.2, 0, 0.45], no body bias, no
wind."""
P0_STD = np.concatenate([c.P0_STD, [0.05] * 3, [0.05] * 3, [5.0] * 2])
"""Square roots of P0's diagonal: ins_gnss's, 0.05 gauss (m, mb) and 5 m/s (wind)."""


def p0() -> np.ndarray:
    return np.diag(P0_STD ** 2)


def input_noise(dt: float) -> np.ndarray:
    """Qu = diag(σg² dt² ×3, σa² dt² ×3): the variances of the deltas over dt."""
    return np.diag([c.SIGMA_GYRO ** 2 * dt * dt] * 3 + [c.SIGMA_ACCEL ** 2 * dt * dt] * 3)


def walk(dt: float) -> np.ndarray:
    """The random walks' diagonal over dt."""
    sigmas = [(c.SIGMA_GYRO_BIAS, 3), (c.SIGMA_ACCEL_BIAS, 3), (SIGMA_EARTH_FIELD, 3),
              (SIGMA_BODY_FIELD, 3), (SIGMA_WIND, 2)]
    return np.concatenate([np.zeros(10)] + [np.full(k, s * s * dt) for s, k in sigmas])


def _increment(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    return np.concatenate([[1.0], 0.5 * (u[:3] - x[BG_ROWS] * dt)])


def f(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    delta_v = u[3:] - x[BA_ROWS] * dt
    out = x.copy()
    out[Q_ROWS] = multiply(x[Q_ROWS], _increment(x, u, dt))
    out[V_ROWS] = x[V_ROWS] + rotation_matrix(x[Q_ROWS]) @ delta_v + np.array([0.0, 0.0,
                                                                               c.GRAVITY * dt])
    out[P_ROWS] = x[P_ROWS] + x[V_ROWS] * dt
    return out


def jacobians(x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F = ∂f/∂x (24 x 24) and Fu = ∂f/∂u (24 x 6), by hand."""
    q = x[Q_ROWS]
    c_q = rotation_matrix(q)
    half = 0.5 * left_matrix(q)[:, 1:]  # ∂(q ⊗ [1, ½δ])/∂δ
    jac = np.eye(N_STATES)
    jac[Q_ROWS, Q_ROWS] = right_matrix(_increment(x, u, dt))
    jac[Q_ROWS, BG_ROWS] = -dt * half
    jac[V_ROWS, Q_ROWS] = rotated_jacobian(q, u[3:] - x[BA_ROWS] * dt)
    jac[V_ROWS, BA_ROWS] = -dt * c_q
    jac[P_ROWS, V_ROWS] = dt * np.eye(3)
    jac_u = np.zeros((N_STATES, 6))
    jac_u[Q_ROWS, :3] = half
    jac_u[V_ROWS, 3:] = c_q
    return jac, jac_u


def predict(x: np.ndarray, P: np.ndarray, u: np.ndarray, dt: float):
    """One EKF prediction from x with q renormalised (as the generated predict, which
    uses |q| = 1 in its noise)."""
    x = unit_quaternion(x)
    jac, jac_u = jacobians(x, u, dt)
    return f(x, u, dt), jac @ P @ jac.T + jac_u @ input_noise(dt) @ jac_u.T + np.diag(walk(dt))


_CONJUGATE = np.diag([1.0, -1.0, -1.0, -1.0])


def _mag(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = x[Q_ROWS]
    conj = _CONJUGATE @ q
    H = np.zeros((3, N_STATES))
    H[:, Q_ROWS] = rotated_jacobian(conj, x[M_ROWS]) @ _CONJUGATE
    H[:, M_ROWS] = rotation_matrix(q).T
    H[:, MB_ROWS] = np.eye(3)
    return rotation_matrix(q).T @ x[M_ROWS] + x[MB_ROWS], H


def _airspeed(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    air = x[V_ROWS] - np.array([x[22], x[23], 0.0])
    speed = float(np.linalg.norm(air))
    H = np.zeros((1, N_STATES))
    H[0, V_ROWS] = air / speed
    H[0, W_ROWS] = -air[:2] / speed
    return np.array([speed]), H


def _gnss(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    H = np.zeros((6, N_STATES))
    H[:3, P_ROWS] = np.eye(3)
    H[3:, V_ROWS] = np.eye(3)
    return H @ x, H


def _baro(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    H = np.zeros((1, N_STATES))
    H[0, 9] = -1.0
    return H @ x, H


SENSORS = {
    "gnss": (_gnss, np.diag(c.GNSS_STD ** 2)),
    "baro": (_baro, np.array([[c.BARO_STD ** 2]])),
    "mag": (_mag, np.eye(3) * MAG_STD ** 2),
    "airspeed": (_airspeed, np.array([[AIRSPEED_STD ** 2]])),
}
"""name -> (x -> (h(x), H(x)), R), in the order the filter updates."""


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, sensor: str):
    """One EKF update of ``sensor`` then q renormalised: (x, P, innovation, S)."""
    measure, R = SENSORS[sensor]
    h, H = measure(x)
    return update_with(x, P, z, h, H, R)


@dataclass(frozen=True)
class Flight:
    """ins_gnss's flight with the sensors of this model: row k of ``imu`` (steps, 6: Δθ, Δv)
    drives the step from t[k] to t[k+1]; each sensor's array holds at row k the measurement
    taken at t[k+1], NaN rows where there is none; ``states`` (steps + 1, 24) the truth."""

    t: np.ndarray
    states: np.ndarray
    imu: np.ndarray
    dt: np.ndarray
    measured: dict[str, np.ndarray]

    @property
    def steps(self) -> int:
        return len(self.imu)

    def rows(self, sensor: str) -> np.ndarray:
        return np.flatnonzero(~np.isnan(self.measured[sensor][:, 0]))


def _every(steps: int, every: int) -> np.ndarray:
    return np.arange(every - 1, steps, every)


def simulate(seed: int = 0, duration: float = c.DURATION,
             airspeed_from: float = AIRSPEED_FROM) -> Flight:
    """The seeded flight (see the module docstring); the airspeed measured from
    ``airspeed_from`` (s)."""
    rng = np.random.default_rng(seed)
    tr = gnss_flight.truth(duration)
    per_imu = int(round(c.IMU_DT / c.TRUTH_DT))
    steps = len(tr.body_rate) // per_imu
    dt = c.IMU_DT
    rate = tr.body_rate[: steps * per_imu].reshape(steps, per_imu, 3).mean(axis=1)
    force = tr.specific_force[: steps * per_imu].reshape(steps, per_imu, 3).mean(axis=1)
    noise = rng.standard_normal((steps, 6)) * np.array([c.SIGMA_GYRO] * 3 + [c.SIGMA_ACCEL] * 3)
    imu = (np.hstack([rate, force]) + np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS])
           + noise) * dt
    grid = np.arange(steps + 1) * per_imu
    constant = np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS, TRUE_EARTH_FIELD,
                               TRUE_BODY_FIELD, TRUE_WIND])
    states = np.hstack([tr.attitude[grid], tr.velocity[grid], tr.position[grid],
                        np.tile(constant, (steps + 1, 1))])
    exact = {name: np.array([SENSORS[name][0](s)[0] for s in states[1:]])
             for name in ("mag", "airspeed")}
    exact["gnss"] = np.hstack([states[1:, P_ROWS], states[1:, V_ROWS]])
    exact["baro"] = -states[1:, 9:10]
    every = {"gnss": c.GNSS_EVERY, "baro": c.BARO_EVERY, "mag": MAG_EVERY,
             "airspeed": AIRSPEED_EVERY}
    std = {"gnss": c.GNSS_STD, "baro": np.array([c.BARO_STD]), "mag": np.full(3, MAG_STD),
           "airspeed": np.array([AIRSPEED_STD])}
    measured = {}
    for name in SENSORS:
        out = np.full(exact[name].shape, np.nan)
        rows = _every(steps, every[name])
        if name == "airspeed":
            rows = rows[tr.t[grid[rows + 1]] >= airspeed_from]
        out[rows] = exact[name][rows] + rng.standard_normal((len(rows), out.shape[1])) * std[name]
        measured[name] = out
    return Flight(tr.t[grid], states, imu, np.full(steps, dt), measured)


@dataclass(frozen=True)
class Run:
    xs: np.ndarray
    Ps: np.ndarray


def run(fl: Flight, x0: np.ndarray | None = None, P0: np.ndarray | None = None) -> Run:
    """Predict with every IMU row, then update with each sensor that has a row there, in the
    order of SENSORS."""
    x = (X0 if x0 is None else x0).astype(float).copy()
    P = (p0() if P0 is None else P0).astype(float).copy()
    xs = np.empty((fl.steps, N_STATES))
    Ps = np.empty((fl.steps, N_STATES, N_STATES))
    for k in range(fl.steps):
        x, P = predict(x, P, fl.imu[k], float(fl.dt[k]))
        for name in SENSORS:
            z = fl.measured[name][k]
            if not np.isnan(z).any():
                x, P = update(x, P, z, name)[:2]
        xs[k], Ps[k] = x, P
    return Run(xs, Ps)


def operating_point(seconds: float = 25.0, seed: int = 0):
    """The reference's state ``seconds`` into the seeded flight (the airspeed fused for 5 s)
    and what each function is called with there: (x, P, {function: u or z}, dt); each
    sensor's z is its next measurement."""
    fl = simulate(seed=seed, duration=seconds + 1.0)
    step = int(round(seconds / c.IMU_DT))
    short = Flight(fl.t[:step + 1], fl.states[:step + 1], fl.imu[:step], fl.dt[:step],
                   {name: rows[:step] for name, rows in fl.measured.items()})
    ran = run(short)
    args = {"predict": fl.imu[step]}
    for name in SENSORS:
        later = fl.rows(name)
        args[f"update_{name}"] = fl.measured[name][later[later >= step][0]]
    return ran.xs[-1], ran.Ps[-1], args, float(fl.dt[step])


def expected(x: np.ndarray, P: np.ndarray, function: str, arg: np.ndarray, dt: float):
    """(x, P) of the reference's ``function`` (predict or update_<sensor>)."""
    if function == "predict":
        return predict(x, P, arg, dt)
    return update(x, P, arg, function.removeprefix("update_"))[:2]
