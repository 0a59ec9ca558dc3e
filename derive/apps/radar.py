"""The CTRV radar tracker through bearing ±π: derive's EKF of the catalog model
``ctrv_radar`` against a textbook EKF written here from the equations.

The target turns at a constant rate (CTRV, X = [px, py, v, psi, omega]) on a circle of
300 m around (-1000, 0): it crosses the negative x axis, where the bearing atan2(py, px)
jumps between π and -π, twice a revolution (every 94 s at 10 m/s). The radar at the
origin reports range and bearing, the bearing in (-π, π] as radars report it.

- :func:`flight`: one seeded flight: the truth by the CTRV equations plus the model's
  process noise Q, the measurements h(truth) plus noise of R, the bearing wrapped, and the
  filter's start drawn from (x0, P0);
- :func:`textbook_ekf`: the EKF of the textbook (Bar-Shalom, Li and Kirubarajan, ch. 10;
  the CTRV Jacobian of Schubert, Richter and Wanielik 2008), Jacobians written by hand,
  the bearing residual wrapped as arctan2(sin y, cos y);
- :func:`derive_ekf`: the generated Python EKF of the model (the bearing declared an angle,
  so its innovation is wrapped), or of the model without that declaration;
- :func:`compare`: RMS position errors of the three over seeded flights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.catalog import read_text
from derive.modelfile import loads_model
from derive.pipeline import load_generated

MODEL = "ctrv_radar"
STEPS = 200
GUARD = 0.03
"""|omega dt| at or below which the CTRV step is the turn's second-order expansion in
omega dt (the model's guard)."""


@dataclass(frozen=True)
class Flight:
    """truth (steps + 1, 5), zs (steps, 2: range, bearing), the filter start x0, P0, and
    the model's numbers (dt, Q, R)."""

    truth: np.ndarray
    zs: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    dt: float
    Q: np.ndarray
    R: np.ndarray


def model(angles: bool = True):
    """The catalog model; ``angles=False``: without the bearing declared an angle (what
    derive made of it before angle measurements existed)."""
    text = read_text(MODEL)
    if not angles:
        text = "\n".join(line for line in text.splitlines()
                         if not line.startswith("angles ="))
    return loads_model(text, source=MODEL)


def ctrv(x: np.ndarray, dt: float) -> np.ndarray:
    """The CTRV step (its second-order expansion in a = omega dt where |a| <= GUARD)."""
    px, py, v, psi, omega = x
    a = omega * dt
    if abs(a) > GUARD:
        return np.array([px + v / omega * (np.sin(psi + omega * dt) - np.sin(psi)),
                         py + v / omega * (np.cos(psi) - np.cos(psi + omega * dt)),
                         v, psi + omega * dt, omega])
    s, c, b = np.sin(psi), np.cos(psi), 1 - a * a / 6
    return np.array([px + v * dt * (c * b - s * a / 2), py + v * dt * (s * b + c * a / 2),
                     v, psi + omega * dt, omega])


def ctrv_jacobian(x: np.ndarray, dt: float) -> np.ndarray:
    """∂ctrv/∂x, by hand."""
    _, _, v, psi, omega = x
    F = np.eye(5)
    F[3, 4] = dt
    s, c = np.sin(psi), np.cos(psi)
    a = omega * dt
    if abs(a) > GUARD:
        s2, c2 = np.sin(psi + omega * dt), np.cos(psi + omega * dt)
        F[0, 2:5] = [(s2 - s) / omega, v / omega * (c2 - c),
                     v * dt * c2 / omega - v * (s2 - s) / omega ** 2]
        F[1, 2:5] = [(c - c2) / omega, v / omega * (s2 - s),
                     v * dt * s2 / omega - v * (c - c2) / omega ** 2]
    else:
        b = 1 - a * a / 6
        F[0, 2:5] = [dt * (c * b - s * a / 2), -v * dt * (s * b + c * a / 2),
                     v * dt * dt * (-c * a / 3 - s / 2)]
        F[1, 2:5] = [dt * (s * b + c * a / 2), v * dt * (c * b - s * a / 2),
                     v * dt * dt * (-s * a / 3 + c / 2)]
    return F


def radar(x: np.ndarray) -> np.ndarray:
    """Range and bearing from the origin."""
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def radar_jacobian(x: np.ndarray) -> np.ndarray:
    px, py = x[0], x[1]
    r2 = px * px + py * py
    r = np.sqrt(r2)
    H = np.zeros((2, 5))
    H[0, :2] = [px / r, py / r]
    H[1, :2] = [-py / r2, px / r2]
    return H


def flight(seed: int, steps: int = STEPS) -> Flight:
    """One seeded flight (the module docstring), with the model's dt, Q, R, x0 and P0."""
    m = model()
    fns = m.numeric_functions()
    dt = float(m.subs(m.symbol("dt")))
    Q, R = fns["Q"], fns["R"]
    x0 = np.asarray(m.x0.tolist(), dtype=float).ravel()
    P0 = np.asarray(m.P0.tolist(), dtype=float)
    rng = np.random.default_rng(seed)
    truth = np.empty((steps + 1, 5))
    truth[0] = x0
    for k in range(steps):
        truth[k + 1] = ctrv(truth[k], dt) + rng.multivariate_normal(np.zeros(5), Q)
    zs = np.array([radar(x) for x in truth[1:]])
    zs += rng.multivariate_normal(np.zeros(2), R, size=steps)
    zs[:, 1] = np.arctan2(np.sin(zs[:, 1]), np.cos(zs[:, 1]))
    start = x0 + rng.multivariate_normal(np.zeros(5), P0)
    return Flight(truth, zs, start, P0, dt, Q, R)


def textbook_ekf(fl: Flight, wrap: bool = True) -> np.ndarray:
    """The textbook EKF (the module docstring): estimates x(k/k), (steps, 5)."""
    x, P = fl.x0.copy(), fl.P0.copy()
    xs = np.empty((len(fl.zs), 5))
    for k, z in enumerate(fl.zs):
        F = ctrv_jacobian(x, fl.dt)
        x = ctrv(x, fl.dt)
        P = F @ P @ F.T + fl.Q
        H = radar_jacobian(x)
        y = z - radar(x)
        if wrap:
            y[1] = np.arctan2(np.sin(y[1]), np.cos(y[1]))
        S = H @ P @ H.T + fl.R
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ y
        P = (np.eye(5) - K @ H) @ P
        xs[k] = x
    return xs


def derive_ekf(fl: Flight, angles: bool = True, module=None) -> np.ndarray:
    """The generated Python EKF of the model (``angles=False``: without the bearing
    declared an angle) on the flight: x(k/k), (steps, 5). ``module``: one already loaded."""
    if module is None:
        module = load_generated(model(angles), "ekf", lang="python").module("python")
    xs, _ = module.run(fl.zs, fl.x0, fl.P0)
    return np.asarray(xs, dtype=float)


def position_rms(xs: np.ndarray, fl: Flight) -> float:
    """RMS over the steps of the position error |p(k/k) - p(k)| (m)."""
    error = np.hypot(xs[:, 0] - fl.truth[1:, 0], xs[:, 1] - fl.truth[1:, 1])
    return float(np.sqrt(np.mean(error ** 2)))


def compare(seeds=range(10), steps: int = STEPS) -> dict[str, float]:
    """RMS position errors (m) pooled over the seeded flights: ``derive`` (the bearing an
    angle), ``textbook`` (residual wrapped), ``derive_unwrapped`` (the bearing not
    declared an angle), and ``crossings``: the bearing's jumps through ±π in the flights."""
    wrapped_module = load_generated(model(True), "ekf", lang="python").module("python")
    plain_module = load_generated(model(False), "ekf", lang="python").module("python")
    squares = {"derive": [], "textbook": [], "derive_unwrapped": []}
    crossings = 0
    for seed in seeds:
        fl = flight(seed, steps)
        runs = {"derive": derive_ekf(fl, module=wrapped_module),
                "textbook": textbook_ekf(fl),
                "derive_unwrapped": derive_ekf(fl, module=plain_module)}
        for name, xs in runs.items():
            squares[name].append(position_rms(xs, fl) ** 2)
        crossings += int(np.sum(np.abs(np.diff(fl.zs[:, 1])) > np.pi))
    out = {name: float(np.sqrt(np.mean(v))) for name, v in squares.items()}
    out["crossings"] = crossings
    return out


__all__ = ["Flight", "compare", "ctrv", "ctrv_jacobian", "derive_ekf", "flight", "model",
           "position_rms", "radar", "radar_jacobian", "textbook_ekf"]
