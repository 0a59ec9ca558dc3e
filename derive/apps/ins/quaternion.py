"""Quaternions (scalar first, rotating body vectors into NED) for the INS application, in
NumPy: the product and the rotation matrix exactly as docs/navigation.md writes them, and the
exact exponential and logarithm the truth simulation needs.

Arrays of quaternions are (..., 4); every function works on one or many.
"""

from __future__ import annotations

import numpy as np


def multiply(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """q ⊗ r (docs/navigation.md)."""
    q0, q1, q2, q3 = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    r0, r1, r2, r3 = np.moveaxis(np.asarray(r, dtype=float), -1, 0)
    return np.stack([
        q0 * r0 - q1 * r1 - q2 * r2 - q3 * r3,
        q0 * r1 + q1 * r0 + q2 * r3 - q3 * r2,
        q0 * r2 - q1 * r3 + q2 * r0 + q3 * r1,
        q0 * r3 + q1 * r2 - q2 * r1 + q3 * r0,
    ], axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    """The inverse rotation of a unit quaternion."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """C(q) of docs/navigation.md (not normalised: the form the filter uses), shape (..., 3, 3)."""
    q0, q1, q2, q3 = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    rows = [
        [1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def from_rotation_vector(phi: np.ndarray) -> np.ndarray:
    """exp(φ/2): the unit quaternion of a rotation by |φ| about φ/|φ| (exact, any angle)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1)
    half = 0.5 * angle
    # sin(half)/angle, its series below 1e-4 rad (error < 1e-18)
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half)[..., None], scale[..., None] * phi], axis=-1)


def to_rotation_vector(q: np.ndarray) -> np.ndarray:
    """The rotation vector φ of a unit quaternion (the inverse of from_rotation_vector), with
    the angle in [0, π]."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0, -q, q)
    vector = q[..., 1:]
    sine = np.linalg.norm(vector, axis=-1)
    angle = 2.0 * np.arctan2(sine, q[..., 0])
    small = sine < 1e-8
    scale = np.where(small, 2.0 / q[..., 0], angle / np.where(small, 1.0, sine))
    return scale[..., None] * vector


def from_euler(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """The quaternion of C = Rz(yaw) Ry(pitch) Rx(roll) (aerospace ZYX order, body to NED)."""
    cy, sy = np.cos(0.5 * np.asarray(yaw)), np.sin(0.5 * np.asarray(yaw))
    cp, sp = np.cos(0.5 * np.asarray(pitch)), np.sin(0.5 * np.asarray(pitch))
    cr, sr = np.cos(0.5 * np.asarray(roll)), np.sin(0.5 * np.asarray(roll))
    return np.stack([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ], axis=-1)


def to_euler(q: np.ndarray) -> np.ndarray:
    """Yaw, pitch, roll (rad, ZYX) of unit quaternions, shape (..., 3)."""
    c = rotation_matrix(q)
    yaw = np.arctan2(c[..., 1, 0], c[..., 0, 0])
    pitch = -np.arcsin(np.clip(c[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(c[..., 2, 1], c[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def attitude_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Small-angle attitude error (rad, NED axes, shape (..., 3)): the rotation vector of
    q_est ⊗ q_true⁻¹ after normalising q_est."""
    q_est = np.asarray(q_est, dtype=float)
    q_est = q_est / np.linalg.norm(q_est, axis=-1, keepdims=True)
    return to_rotation_vector(multiply(q_est, conjugate(q_true)))
