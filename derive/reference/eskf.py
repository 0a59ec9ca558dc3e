"""NumPy reference of the error-state EKF (nominal state on its manifold, P in the tangent
space), written from the equations on plain arrays and callables.

Per step k: ``predict(x, P, u, p) -> (x, P)`` (the caller's: the nominal state predicted and
projected, ``F P F^T + Fu Qu Fu^T + Q`` over the tangent space); then for each sensor in
order whose row k of z has no NaN: ``nu = z - h(x, u_s)``, ``S = H P H^T + R`` (H the
Jacobian of h over the tangent coordinates), ``nis = nu^T S^-1 nu``; unless a gate is
given and ``nis`` exceeds it: ``dx = K nu``, ``x <- x ⊞ dx`` (the caller's ``inject``),
``P <- (I - K H) P (I - K H)^T + K R K^T`` (Joseph's form, as derive.reference.sensors), and
with ``reset(dx)`` given, ``P <- G P G^T``, G = reset(dx).

The reset of a quaternion's block, from the error-state kinematics (Solà, "Quaternion
kinematics for the error-state Kalman filter", section 7.2) for the injection
``q ⊗ [1, dθ/2] / |[1, dθ/2]|``: the error about the new nominal state is
``e+ = 2 vec(p̂* ⊗ p̂e)`` with ``p = [1, dθ/2]``, ``pe = [1, (dθ + e)/2]``, whose derivative
at e = 0 is ``G = (I - [dθ/2]x) / (1 + |dθ|²/4)`` (Solà's first-order ``I - [dθ/2]x``
over the norm of the first-order increment); global error: ``(I + [dθ/2]x) / (1 + |dθ|²/4)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from derive.domains import check_rows
from derive.reference.sensors import SensorFunctions, SensorsResult, StepTrace, UpdateTrace


def skew(v) -> np.ndarray:
    """[v]x: [v]x w = v x w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quaternion_reset(dtheta, local: bool = True) -> np.ndarray:
    """G of one quaternion's error (the module docstring), 3 x 3."""
    half = 0.5 * np.asarray(dtheta, dtype=float)
    return ((np.eye(3) - skew(half)) if local else (np.eye(3) + skew(half))) / (
        1.0 + float(half @ half))


def run(predict: Callable, sensors: Sequence[SensorFunctions], inject: Callable, x0, P0,
        zs: dict, us=None, ps=None, reset: Callable | None = None,
        unit_norm: Sequence[Sequence[int]] = (), trace: list | None = None,
        domains: Sequence[tuple[int, str, str]] = ()) -> SensorsResult:
    """The error-state filter over ``zs`` (``{sensor: (steps, m_s)}``, rows of NaN:
    absent); ``inject(x, dx) -> x ⊞ dx``; ``reset(dx) -> G`` or None (no reset);
    ``unit_norm``: index groups of x renormalised after every update (as
    derive.reference.sensors); the rest as derive.reference.sensors.run."""
    steps = len(next(iter(zs.values())))
    x, P = np.array(x0, dtype=float), np.array(P0, dtype=float)
    n, nt = x.shape[0], P.shape[0]
    us = np.zeros((steps, 0)) if us is None else np.asarray(us, dtype=float)
    ps = np.zeros((steps, 0)) if ps is None else np.asarray(ps, dtype=float)
    xs, Ps = np.empty((steps, n)), np.empty((steps, nt, nt))
    nis = {s.name: np.full(steps, np.nan) for s in sensors}
    applied = {s.name: np.zeros(steps) for s in sensors}
    check_rows(domains, ps)
    for k in range(steps):
        x_before = x
        x, P = predict(x, P, us[k], ps[k])
        predicted, updates = P, []
        for s in sensors:
            z = np.asarray(zs[s.name][k], dtype=float)
            if np.isnan(z).any():
                continue
            u = us[k, list(s.columns)]
            H = np.asarray(s.H(x, u, ps[k]), dtype=float).reshape(len(z), nt)
            R = np.asarray(s.R(ps[k]), dtype=float).reshape(len(z), len(z))
            nu = z - np.asarray(s.h(x, u, ps[k]), dtype=float).ravel()
            S = H @ P @ H.T + R
            value = float(nu @ np.linalg.solve(S, nu))
            K = np.linalg.solve(S, H @ P).T
            done = s.gate is None or value <= s.gate
            P_before = P
            if done:
                dx = K @ nu
                x = inject(x, dx)
                IKH = np.eye(nt) - K @ H
                P = IKH @ P @ IKH.T + K @ R @ K.T
                if reset is not None:
                    G = reset(dx)
                    P = G @ P @ G.T
                P = (P + P.T) / 2
            nis[s.name][k], applied[s.name][k] = value, float(done)
            updates.append(UpdateTrace(s.name, H, S, K, done, P_before))
            for group in unit_norm:
                index = list(group)
                x[index] = x[index] / np.sqrt(np.sum(x[index] ** 2))
        xs[k], Ps[k] = x, P
        if trace is not None:
            trace.append(StepTrace(x_before, us[k], ps[k], predicted, tuple(updates)))
    return SensorsResult(xs, Ps, nis, applied)


__all__ = ["quaternion_reset", "run", "skew"]
