"""A NumPy EKF of the INS/GNSS model written by hand from docs/navigation.md, independently of
derive's derivation: the Jacobians below are worked out on paper from the equations (and
checked against finite differences in tests/navigation/test_nav_ins_reference.py), not by sympy.

State x = [q0..q3, vn, ve, vd, pn, pe, pd, bg(3), ba(3)], input u = [ω(3), a(3)], parameter
dt. Predict: x ← f(x, u), P ← F P Fᵀ + Q(x, u) with F = ∂f/∂x, Fu = ∂f/∂u at (x, u) and
Q(x, u) = Fu Qu Fuᵀ + diag(0 ×10, σbg² dt ×3, σba² dt ×3). Update (gnss: h = [p, v], baro:
h = −pd): S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x ← x + K (z − h(x)), P ← P − K H P, then
q ← q/‖q‖. P is kept symmetric, (P + Pᵀ)/2 after each update: computed as written,
P − K H P is symmetric only to rounding, and over a 12,000-step flight that asymmetry grows
to ~1e-9 of the standard deviations (derive's code computes one triangle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.ins import constants as c
from derive.apps.ins.quaternion import multiply, rotation_matrix

N_STATES = 16
Q_ROWS, V_ROWS, P_ROWS, BG_ROWS, BA_ROWS = (slice(0, 4), slice(4, 7), slice(7, 10),
                                            slice(10, 13), slice(13, 16))


def left_matrix(q: np.ndarray) -> np.ndarray:
    """L(q) with q ⊗ r = L(q) r."""
    q0, q1, q2, q3 = q
    return np.array([[q0, -q1, -q2, -q3],
                     [q1, q0, -q3, q2],
                     [q2, q3, q0, -q1],
                     [q3, -q2, q1, q0]])


def right_matrix(r: np.ndarray) -> np.ndarray:
    """R(r) with q ⊗ r = R(r) q."""
    r0, r1, r2, r3 = r
    return np.array([[r0, -r1, -r2, -r3],
                     [r1, r0, r3, -r2],
                     [r2, -r3, r0, r1],
                     [r3, r2, -r1, r0]])


def rotated_jacobian(q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """∂(C(q) a)/∂q (3 x 4), differentiating C(q) of docs/navigation.md entry by entry."""
    q0, q1, q2, q3 = q
    a1, a2, a3 = a
    return 2.0 * np.array([
        [-q3 * a2 + q2 * a3, q2 * a2 + q3 * a3, -2 * q2 * a1 + q1 * a2 + q0 * a3,
         -2 * q3 * a1 - q0 * a2 + q1 * a3],
        [q3 * a1 - q1 * a3, q2 * a1 - 2 * q1 * a2 - q0 * a3, q1 * a1 + q3 * a3,
         q0 * a1 - 2 * q3 * a2 + q2 * a3],
        [-q2 * a1 + q1 * a2, q3 * a1 + q0 * a2 - 2 * q1 * a3, -q0 * a1 + q3 * a2 - 2 * q2 * a3,
         q1 * a1 + q2 * a2],
    ])


def _increment(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    rate = u[:3] - x[BG_ROWS]
    return np.concatenate([[1.0], 0.5 * dt * rate])


def f(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """The process model of docs/navigation.md."""
    force = u[3:] - x[BA_ROWS]
    out = x.copy()
    out[Q_ROWS] = multiply(x[Q_ROWS], _increment(x, u, dt))
    out[V_ROWS] = x[V_ROWS] + (rotation_matrix(x[Q_ROWS]) @ force
                               + np.array([0.0, 0.0, c.GRAVITY])) * dt
    out[P_ROWS] = x[P_ROWS] + x[V_ROWS] * dt
    return out


def jacobians(x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F = ∂f/∂x (16 x 16) and Fu = ∂f/∂u (16 x 6), by hand."""
    q = x[Q_ROWS]
    force = u[3:] - x[BA_ROWS]
    c_q = rotation_matrix(q)
    half = 0.5 * dt * left_matrix(q)[:, 1:]  # ∂(q ⊗ [1, ½ω'dt])/∂ω'
    jac = np.eye(N_STATES)
    jac[Q_ROWS, Q_ROWS] = right_matrix(_increment(x, u, dt))
    jac[Q_ROWS, BG_ROWS] = -half
    jac[V_ROWS, Q_ROWS] = dt * rotated_jacobian(q, force)
    jac[V_ROWS, BA_ROWS] = -dt * c_q
    jac[P_ROWS, V_ROWS] = dt * np.eye(3)
    jac_u = np.zeros((N_STATES, 6))
    jac_u[Q_ROWS, :3] = half
    jac_u[V_ROWS, 3:] = dt * c_q
    return jac, jac_u


def process_noise(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """Q(x, u) = Fu Qu Fuᵀ + diag(0 ×10, σbg² dt ×3, σba² dt ×3)."""
    _, jac_u = jacobians(x, u, dt)
    walk = np.concatenate([np.zeros(10), np.full(3, c.SIGMA_GYRO_BIAS ** 2 * dt),
                           np.full(3, c.SIGMA_ACCEL_BIAS ** 2 * dt)])
    return jac_u @ c.input_noise() @ jac_u.T + np.diag(walk)


def h_gnss(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x[P_ROWS], x[V_ROWS]])


def H_gnss() -> np.ndarray:
    jac = np.zeros((6, N_STATES))
    jac[:3, P_ROWS] = np.eye(3)
    jac[3:, V_ROWS] = np.eye(3)
    return jac


def h_baro(x: np.ndarray) -> np.ndarray:
    return np.array([-x[9]])


def H_baro() -> np.ndarray:
    jac = np.zeros((1, N_STATES))
    jac[0, 9] = -1.0
    return jac


SENSORS = {
    "gnss": (h_gnss, H_gnss, np.diag(c.GNSS_STD ** 2)),
    "baro": (h_baro, H_baro, np.array([[c.BARO_STD ** 2]])),
}
"""name -> (h, H, R)."""


def predict(x: np.ndarray, P: np.ndarray, u: np.ndarray, dt: float):
    """One EKF prediction: (x, P) at the next step, from x with q renormalised (the
    generated predict uses |q| = 1 in its noise, so it renormalises q first)."""
    x = unit_quaternion(x)
    jac, _ = jacobians(x, u, dt)
    return f(x, u, dt), jac @ P @ jac.T + process_noise(x, u, dt)


def unit_quaternion(x: np.ndarray) -> np.ndarray:
    """x with q divided by its norm."""
    x = np.array(x, dtype=float)
    x[:4] /= np.linalg.norm(x[:4])
    return x


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, sensor: str):
    """One EKF update of `sensor` then the quaternion renormalised: (x, P, innovation, S)."""
    h, H_of, R = SENSORS[sensor]
    return update_with(x, P, z, h(x), H_of(), R)


def update_with(x: np.ndarray, P: np.ndarray, z, h: np.ndarray, H: np.ndarray, R: np.ndarray):
    """The EKF update with h(x), H and R given, then q renormalised: (x, P, innovation, S)."""
    innovation = np.asarray(z, dtype=float) - h
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ innovation
    P = P - K @ H @ P
    P = 0.5 * (P + P.T)  # symmetric to rounding (P - K H P is not, and the drift grows)
    x[Q_ROWS] = x[Q_ROWS] / np.linalg.norm(x[Q_ROWS])
    return x, P, innovation, S


@dataclass(frozen=True)
class Run:
    """A filter run over a flight: estimates after each step (steps, 16) and (steps, 16, 16),
    and per sensor the rows it updated and the NIS there."""

    xs: np.ndarray
    Ps: np.ndarray
    nis: dict[str, tuple[np.ndarray, np.ndarray]]


def run(flight, x0: np.ndarray | None = None, P0: np.ndarray | None = None) -> Run:
    """Predict with every IMU row, then update with each sensor that has a row there (gnss
    first, then baro)."""
    x = (c.X0 if x0 is None else x0).astype(float).copy()
    P = (c.p0() if P0 is None else P0).astype(float).copy()
    xs = np.empty((flight.steps, N_STATES))
    Ps = np.empty((flight.steps, N_STATES, N_STATES))
    nis: dict[str, list] = {name: [] for name in SENSORS}
    measured = {"gnss": flight.gnss, "baro": flight.baro}
    for k in range(flight.steps):
        x, P = predict(x, P, flight.imu[k], float(flight.dt[k]))
        for name in SENSORS:
            z = measured[name][k]
            if np.isnan(z).any():
                continue
            x, P, innovation, S = update(x, P, z, name)
            nis[name].append((k, float(innovation @ np.linalg.solve(S, innovation))))
        xs[k], Ps[k] = x, P
    return Run(xs, Ps, {name: (np.array([r for r, _ in rows], dtype=int),
                               np.array([v for _, v in rows])) for name, rows in nis.items()})
