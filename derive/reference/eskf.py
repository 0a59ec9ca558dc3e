"""What the NumPy reference of the error-state EKF adds to derive.reference.sensors.run
(whose ``inject`` and ``reset`` take an error-state filter's x ⊞ dx and G): the reset
Jacobian of a quaternion's error, written from the equations.

The run: per step the caller's ``predict(x, P, u, p)`` (the nominal state predicted and
projected, ``F P F^T + Fu Qu Fu^T + Q`` over the tangent space); per present sensor
``nu = z - h(x, u_s)``, ``S = H P H^T + R`` (H over the tangent coordinates), ``dx = K nu``,
``x <- x ⊞ dx``, Joseph's ``P <- (I - K H) P (I - K H)^T + K R K^T``, and with a reset
``P <- G P G^T``, G = reset(dx).

The reset of a quaternion's block, from the error-state kinematics (Solà, "Quaternion
kinematics for the error-state Kalman filter", section 7.2) for the injection
``q ⊗ [1, dθ/2] / |[1, dθ/2]|``: the error about the new nominal state is
``e+ = 2 vec(p̂* ⊗ p̂e)`` with ``p = [1, dθ/2]``, ``pe = [1, (dθ + e)/2]``, whose derivative
at e = 0 is ``G = (I - [dθ/2]x) / (1 + |dθ|²/4)`` (Solà's first-order ``I - [dθ/2]x``
over the norm of the first-order increment); global error: ``(I + [dθ/2]x) / (1 + |dθ|²/4)``.
"""

from __future__ import annotations

import numpy as np


def skew(v) -> np.ndarray:
    """[v]x: [v]x w = v x w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quaternion_reset(dtheta, local: bool = True) -> np.ndarray:
    """G of one quaternion's error (the module docstring), 3 x 3."""
    half = 0.5 * np.asarray(dtheta, dtype=float)
    return ((np.eye(3) - skew(half)) if local else (np.eye(3) + skew(half))) / (
        1.0 + float(half @ half))


__all__ = ["quaternion_reset", "skew"]
