"""FilterPy's ``ExtendedKalmanFilter`` doing the INS/GNSS EKF's steps (a benchmark peer).

FilterPy's EKF propagates x linearly (``x = F x + B u``) unless ``predict_x`` is overridden,
and takes F and Q as attributes the user sets: the FilterPy way to run this model is to
evaluate f, F = ∂f/∂x and Q(x, u) each step (here by the NumPy reference's hand-written
functions, derive.apps.ins.reference) and call ``predict``; an update is
``update(z, HJacobian, Hx, R)`` (FilterPy's Joseph form) followed by renormalising q.
"""

from __future__ import annotations

import numpy as np

from derive.apps.ins import reference as ref


def make_filter(x: np.ndarray, P: np.ndarray):
    """A FilterPy EKF holding (x, P), with ``predict_step(u, dt)`` and
    ``update_step(z, sensor)`` methods doing one step each."""
    from filterpy.kalman import ExtendedKalmanFilter  # optional: a benchmark peer

    class InsEkf(ExtendedKalmanFilter):
        def __init__(self):
            super().__init__(dim_x=ref.N_STATES, dim_z=6)
            self.x = np.array(x, dtype=float).reshape(-1, 1)
            self.P = np.array(P, dtype=float)
            self._input = (np.zeros(6), 0.0)

        def predict_x(self, u=0):
            u_k, dt = self._input
            self.x = ref.f(self.x.ravel(), u_k, dt).reshape(-1, 1)

        def predict_step(self, u: np.ndarray, dt: float) -> None:
            self.x[:4] /= np.linalg.norm(self.x[:4])  # as derive's predict, at a unit q
            state = self.x.ravel()
            self.F, _ = ref.jacobians(state, u, dt)
            self.Q = ref.process_noise(state, u, dt)
            self._input = (u, dt)
            self.predict()

        def update_step(self, z: np.ndarray, sensor: str) -> None:
            h, H_of, R = ref.SENSORS[sensor]
            H = H_of()
            self.update(np.asarray(z, dtype=float).reshape(-1, 1),
                        lambda state: H, lambda state: h(state.ravel()).reshape(-1, 1), R=R)
            self.x[:4] /= np.linalg.norm(self.x[:4])

    return InsEkf()
