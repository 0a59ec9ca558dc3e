"""The generated EKF of ``ins_gnss`` on a simulated flight: one ``run`` call over the whole
flight (per-sensor arrays with NaN rows, dt as a per-step parameter row), or the generated
``predict`` and ``update_<sensor>`` called step by step to see each update's innovation.

Both accept a generated Python module (functions return arrays) or a compiled C module
(derive.build.FilterModule: the same names, P returned (16, 16)).
"""

from __future__ import annotations

import numpy as np

from derive.apps.ins import reference
from derive.apps.ins.constants import X0, p0

AGREEMENT = 1e-9
"""Bar: generated against the NumPy reference over the whole flight, relative (see
derive.apps.ins.compare)."""

SENSORS = ("gnss", "baro")


def generated_run(module, flight, x0=None, P0=None) -> tuple[np.ndarray, np.ndarray]:
    """xs (steps, 16) and Ps (steps, 16, 16) of the generated ``run`` over the flight."""
    x0 = X0 if x0 is None else x0
    P0 = p0() if P0 is None else P0
    p_rows = flight.dt[:, None]
    xs, Ps = module.run(flight.gnss, flight.baro, flight.imu, x0, P0, p_rows)
    steps = flight.steps
    return np.asarray(xs).reshape(steps, 16), np.asarray(Ps).reshape(steps, 16, 16)


def stepwise_run(module, flight, x0=None, P0=None) -> reference.Run:
    """The generated predict and updates called step by step; each update's NIS from the
    generated filter's predicted (x, P) (h and H of docs/navigation.md, linear in the state)."""
    x = np.array(X0 if x0 is None else x0, dtype=float)
    P = np.array(p0() if P0 is None else P0, dtype=float)
    xs = np.empty((flight.steps, 16))
    Ps = np.empty((flight.steps, 16, 16))
    measured = {"gnss": flight.gnss, "baro": flight.baro}
    nis: dict[str, list] = {name: [] for name in SENSORS}
    for k in range(flight.steps):
        p = flight.dt[k:k + 1]
        x, P = (np.asarray(v, dtype=float) for v in module.predict(x, P, flight.imu[k], p))
        P = P.reshape(16, 16)
        for name in SENSORS:
            z = measured[name][k]
            if np.isnan(z).any():
                continue
            h, H_of, R = reference.SENSORS[name]
            H = H_of()
            innovation = z - h(x)
            nis[name].append((k, float(innovation @ np.linalg.solve(H @ P @ H.T + R,
                                                                     innovation))))
            x, P = (np.asarray(v, dtype=float) for v in getattr(module, f"update_{name}")(
                x, P, z, p))
            P = P.reshape(16, 16)
        xs[k], Ps[k] = x, P
    return reference.Run(xs, Ps, {name: (np.array([r for r, _ in rows], dtype=int),
                                         np.array([v for _, v in rows]))
                                  for name, rows in nis.items()})
