"""A NumPy error-state EKF of the INS/GNSS model (catalog model ``ins_eskf``), written by
hand from the error-state kinematics (Solà, "Quaternion kinematics for the error-state
Kalman filter", 2017, sections 5.3.3 and 7), independently of derive's derivation, and the
consistency of a filter run against the truth.

Nominal state x = [q (4), v, p, bg, ba] (16), error state δx = [δθ, δv, δp, δbg, δba] (15)
with the local (body) attitude error q_true = q ⊗ [1, δθ/2]; input u = [ω, a], parameter
dt. With ω' = ω − bg, a' = a − ba and the first-order increment Ω = [1, ε], ε = ω' dt/2
(the model's own discrete f, q ⊗ Ω, renormalised):

    nominal   q ← (q ⊗ Ω)/|q ⊗ Ω|,  v ← v + (C(q) a' + g) dt,  p ← p + v dt
    error     δθ ← C(Ω̂)ᵀ δθ − dt (I − [ε]×)/|Ω|² δbg  − (gyro noise likewise)
              δv ← δv − C(q)[a']× dt δθ − C(q) dt δba  − (accelerometer noise C(q) dt)
              δp ← δp + dt δv,  δbg ← δbg,  δba ← δba

Solà's discrete error dynamics (his eq. 269) are these to first order in dt: his
R{(ω − bg) dt}ᵀ is the rotation of the increment quaternion, here C(Ω̂)ᵀ for the model's
first-order Ω (Ω̂ = Ω/|Ω|), and his −I dt on δbg is here the exact −dt (I − [ε]×)/|Ω|²
of the renormalised first-order step (the error of Ω̂* ⊗ [0, −δbg dt/2], the vector part
of [1, −ε] ⊗ [0, w] being w − ε × w). P ← F P Fᵀ + Fu Qu Fuᵀ + Q, Q = diag(0 ×9,
σbg² dt ×3, σba² dt ×3).

Update (gnss: h = [p, v], baro: h = −pd; h does not depend on the attitude, so H over
the error state is H's rows on δp, δv): S = H P Hᵀ + R, K = P Hᵀ S⁻¹, δx = K (z − h(x)),
injected: q ← (q ⊗ [1, δθ/2])/|q ⊗ [1, δθ/2]|, the rest added; P ← (I − K H) P (I − K H)ᵀ
+ K R Kᵀ (Joseph's form). No reset (G = I), the catalog model's default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.ins import compare
from derive.apps.ins import constants as c
from derive.apps.ins import flight as flight_module
from derive.apps.ins.quaternion import conjugate, multiply, rotation_matrix
from derive.apps.ins.run import generated_run as total_state_run

N_ERRORS = 15
DTH, DV, DP, DBG, DBA = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15))
GRAVITY = np.array([0.0, 0.0, c.GRAVITY])
X0 = c.X0
"""The start: ins_gnss's (level, heading north, at rest, biases zero)."""
P0_STD = np.concatenate([[2e-2] * 3, c.P0_STD[4:]])
"""Square roots of P0's diagonal: ins_gnss's, the attitude's 2e-2 rad (δθ ≈ 2 δq_vec of
its 1e-2 per quaternion component)."""


def p0() -> np.ndarray:
    return np.diag(P0_STD ** 2)


def skew(v: np.ndarray) -> np.ndarray:
    """[v]×."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def predict(x: np.ndarray, P: np.ndarray, u: np.ndarray, dt: float):
    """The nominal state and the error covariance one step on (the module docstring)."""
    q, v, p, bg, ba = x[0:4], x[4:7], x[7:10], x[10:13], x[13:16]
    w, a = u[:3] - bg, u[3:] - ba
    eps = 0.5 * dt * w
    omega = np.concatenate([[1.0], eps])
    norm2 = 1.0 + float(eps @ eps)
    C = rotation_matrix(q)
    q_new = multiply(q, omega)
    x_new = np.concatenate([q_new / np.linalg.norm(q_new), v + (C @ a + GRAVITY) * dt,
                            p + v * dt, bg, ba])
    F = np.eye(N_ERRORS)
    F[DTH, DTH] = rotation_matrix(omega / np.sqrt(norm2)).T
    rate = dt * (np.eye(3) - skew(eps)) / norm2
    F[DTH, DBG] = -rate
    F[DV, DTH] = -C @ skew(a) * dt
    F[DV, DBA] = -C * dt
    F[DP, DV] = np.eye(3) * dt
    Fu = np.zeros((N_ERRORS, 6))
    Fu[DTH, :3] = rate
    Fu[DV, 3:] = C * dt
    Q = np.zeros((N_ERRORS, N_ERRORS))
    Q[DBG, DBG] = np.eye(3) * c.SIGMA_GYRO_BIAS ** 2 * dt
    Q[DBA, DBA] = np.eye(3) * c.SIGMA_ACCEL_BIAS ** 2 * dt
    return x_new, F @ P @ F.T + Fu @ c.input_noise() @ Fu.T + Q


def _gnss_H() -> np.ndarray:
    H = np.zeros((6, N_ERRORS))
    H[0:3, DP] = np.eye(3)
    H[3:6, DV] = np.eye(3)
    return H


def _baro_H() -> np.ndarray:
    H = np.zeros((1, N_ERRORS))
    H[0, 8] = -1.0
    return H


SENSORS = {
    "gnss": (lambda x: np.concatenate([x[7:10], x[4:7]]), _gnss_H(), np.diag(c.GNSS_STD ** 2)),
    "baro": (lambda x: np.array([-x[9]]), _baro_H(), np.array([[c.BARO_STD ** 2]])),
}
"""name -> (h, H over the error state, R)."""


def inject(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """x ⊞ δx: q ⊗ [1, δθ/2] renormalised, the rest added."""
    q = multiply(x[0:4], np.concatenate([[1.0], 0.5 * dx[DTH]]))
    return np.concatenate([q / np.linalg.norm(q), x[4:] + dx[3:]])


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, sensor: str):
    """One update of ``sensor``: (x, P, innovation, S)."""
    h, H, R = SENSORS[sensor]
    innovation = np.asarray(z, dtype=float) - h(x)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    IKH = np.eye(N_ERRORS) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    return inject(x, K @ innovation), 0.5 * (P + P.T), innovation, S


@dataclass(frozen=True)
class Run:
    """Estimates after each step (steps, 16), error covariances (steps, 15, 15)."""

    xs: np.ndarray
    Ps: np.ndarray


def run(flight, x0: np.ndarray | None = None, P0: np.ndarray | None = None) -> Run:
    """Predict with every IMU row, then update with each sensor that has a row there (gnss
    first, then baro)."""
    x = np.array(X0 if x0 is None else x0, dtype=float)
    P = np.array(p0() if P0 is None else P0, dtype=float)
    xs = np.empty((flight.steps, 16))
    Ps = np.empty((flight.steps, N_ERRORS, N_ERRORS))
    measured = {"gnss": flight.gnss, "baro": flight.baro}
    for k in range(flight.steps):
        x, P = predict(x, P, flight.imu[k], float(flight.dt[k]))
        for name in SENSORS:
            z = measured[name][k]
            if not np.isnan(z).any():
                x, P, _, _ = update(x, P, z, name)
        xs[k], Ps[k] = x, P
    return Run(xs, Ps)


def generated_run(module, flight, x0=None, P0=None) -> tuple[np.ndarray, np.ndarray]:
    """xs (steps, 16) and Ps (steps, 15, 15) of the generated ``run`` over the flight."""
    x0 = X0 if x0 is None else x0
    P0 = p0() if P0 is None else P0
    xs, Ps = module.run(flight.gnss, flight.baro, flight.imu, x0, P0, flight.dt[:, None])
    steps = flight.steps
    return (np.asarray(xs).reshape(steps, 16),
            np.asarray(Ps).reshape(steps, N_ERRORS, N_ERRORS))


# -- consistency against the truth --------------------------------------------------------


def body_attitude_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """δθ with q_true = q_est ⊗ [1, δθ/2] to first order: 2 vec(q_est* ⊗ q_true), the
    scalar part's sign made positive (shape (steps, 3))."""
    e = multiply(conjugate(q_est), q_true)
    return 2.0 * np.sign(e[..., :1]) * e[..., 1:]


def error_state(flight, xs: np.ndarray) -> np.ndarray:
    """The true error about each estimate, [δθ, δv, δp, δbg, δba] (steps, 15): the truth
    after each step minus the estimate (the attitude by :func:`body_attitude_error`)."""
    truth = flight.states[1:]
    return np.hstack([body_attitude_error(xs[:, 0:4], truth[:, 0:4]),
                      truth[:, 4:] - xs[:, 4:]])


QUANTITIES = (("attitude", DTH), ("velocity", DV), ("position", DP))
"""The quantities whose 3σ consistency is measured (all three axes inside at a step)."""


def inside_steps(errors: np.ndarray, sigmas: np.ndarray) -> dict[str, np.ndarray]:
    """Per quantity, per step: every axis of its error inside ±3σ (booleans)."""
    return {name: np.all(np.abs(errors[:, rows]) <= 3.0 * sigmas[:, rows], axis=1)
            for name, rows in QUANTITIES}


INSIDE_BAR = 0.99
"""Fraction of steps, pooled over the seeds, at which each quantity's error must be inside
the filter's own 3σ on all three axes."""


def total_state_inside(flight, xs: np.ndarray, Ps: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`inside_steps` of the total-state EKF (ins_gnss: its NED attitude error and
    the attitude σ from its quaternion block, derive.apps.ins.compare)."""
    err = compare.errors(flight, xs, Ps)
    pairs = {"attitude": (err.attitude, err.attitude_sigma),
             "velocity": (err.velocity, err.velocity_sigma),
             "position": (err.position, err.position_sigma)}
    return {name: np.all(np.abs(e) <= 3.0 * s, axis=1) for name, (e, s) in pairs.items()}


def pooled_inside(eskf, ekf, seeds, duration: float = c.DURATION
                  ) -> dict[str, dict[str, float]]:
    """``{"eskf": {quantity: fraction}, "ekf": {...}}``: the fraction of steps inside 3σ
    (:func:`inside_steps`) pooled over the flights of ``seeds`` (``duration`` s each), for
    the generated error-state EKF (ins_eskf) and the generated total-state EKF (ins_gnss)
    on the same flights."""
    pooled: dict[str, dict[str, list]] = {"eskf": {}, "ekf": {}}
    for seed in seeds:
        fl = flight_module.simulate(seed, duration)
        xs, Ps = generated_run(eskf, fl)
        for name, rows in inside_steps(error_state(fl, xs),
                                       np.sqrt(np.diagonal(Ps, axis1=1, axis2=2))).items():
            pooled["eskf"].setdefault(name, []).append(rows)
        for name, rows in total_state_inside(fl, *total_state_run(ekf, fl)).items():
            pooled["ekf"].setdefault(name, []).append(rows)
    return {f: {name: float(np.concatenate(rows).mean()) for name, rows in d.items()}
            for f, d in pooled.items()}


__all__ = ["INSIDE_BAR", "N_ERRORS", "QUANTITIES", "Run", "body_attitude_error",
           "error_state", "generated_run", "inject", "inside_steps", "p0", "pooled_inside",
           "predict", "run", "total_state_inside", "update"]
