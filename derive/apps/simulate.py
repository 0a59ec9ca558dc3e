"""Seeded simulations: linear state-space runs, SSPRED's 2-D truths and a GNSS scenario.

All randomness comes from numpy.random.default_rng(seed); the same seed gives the same
arrays. Indexing: truths include k = 0; measurements are z(k) for k = 1..steps at row k-1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from derive.errors import ModelError, ShapeError, VerificationError
from derive.manifolds import boxplus_numeric
from derive.system_checks import psd_sqrt, system_arrays

# WGS-84 ellipsoid
WGS84_A = 6_378_137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
GPS_ORBIT_RADIUS = 26_560e3
"""GPS orbit radius from the Earth's centre, metres."""
GPS_ANGULAR_RATE = 2.0 * np.pi / 43_082.0
"""Mean motion of a GPS satellite (half a sidereal day per orbit), rad/s."""
STADIUM = (40.988, 29.037, 50.0)
"""Şükrü Saracoğlu stadium, Istanbul (the GNSS paper): latitude, longitude (deg), height (m)."""


def _steps(steps: int) -> int:
    if int(steps) != steps or steps < 1:
        raise ModelError(f"steps must be a positive integer, got {steps!r}")
    return int(steps)


def _finite(truth: np.ndarray, measured: np.ndarray) -> None:
    """Refuse a simulation whose truth or measurements leave the range of a double: the
    first step where one does, and what grows (a filter verified on it would compare
    infinities, and NumPy would only have warned)."""
    steps = len(measured)
    bad_truth = ~np.isfinite(truth).all(axis=1)
    if bad_truth.any():
        k = int(np.argmax(bad_truth))
        grown = np.abs(truth[k - 1]) if k else np.zeros(truth.shape[1])
        raise ModelError(
            f"the simulated truth is not finite at step {k} of {steps} (the largest state "
            f"before it is {float(grown.max()):.3g}): the model's process leaves the range "
            f"of a double or is undefined there; simulate fewer steps (--steps) or give "
            f"the model values under which it stays finite")
    bad = ~np.isfinite(measured).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad)) + 1
        raise ModelError(
            f"the simulated measurement z({k}) of {steps} is not finite (the largest state "
            f"is {float(np.abs(truth[k]).max()):.3g}): the measurement model overflows or "
            f"is undefined there; "
            f"simulate fewer steps (--steps) or give the model values under which it stays "
            f"finite")


# ---------------------------------------------------------------- linear models
class LinearRun(NamedTuple):
    """xs: true states (steps+1, n) for k = 0..steps; zs: measurements (steps, m), k = 1..steps."""

    xs: np.ndarray
    zs: np.ndarray


def simulate_linear(F, G, H, Q, R, x0, steps: int, seed: int, B=None, D=None,
                    us=None) -> LinearRun:
    """x(k+1) = F x(k) + G w(k), z(k) = H x(k) + v(k), w ~ N(0, Q), v ~ N(0, R), x(0) = x0;
    with inputs ``us`` (steps, n_u): x(k+1) = F x(k) + B us[k] + G w(k),
    z(k+1) = H x(k+1) + D us[k] + v(k+1)."""
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    steps = _steps(steps)
    x = np.asarray(x0, dtype=float).reshape(-1)
    if x.shape != (F.shape[0],):
        raise ShapeError(f"x0 must have {F.shape[0]} entries, got shape {np.shape(x0)}")
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((steps, Q.shape[0])) @ psd_sqrt(Q)
    v = rng.standard_normal((steps, R.shape[0])) @ psd_sqrt(R)
    if us is None:
        Bu, Du = np.zeros((steps, F.shape[0])), np.zeros((steps, H.shape[0]))
    else:
        us = np.asarray(us, dtype=float).reshape(steps, -1)
        Bu, Du = us @ np.asarray(B, dtype=float).T, us @ np.asarray(D, dtype=float).T
    xs = np.empty((steps + 1, F.shape[0]))
    xs[0] = x
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # refused below, by step
        for k in range(steps):
            xs[k + 1] = F @ xs[k] + Bu[k] + G @ w[k]
        zs = xs[1:] @ H.T + Du + v
    _finite(xs, zs)
    return LinearRun(xs, zs)


# ---------------------------------------------------------------- SSPRED truths
@dataclass(frozen=True)
class Trajectory2D:
    """A 2-D truth at t = k·dt (k = 0..steps) and noisy positions z(k), k = 1..steps."""

    dt: float
    noise_std: float
    t: np.ndarray                 # (steps+1,)
    positions: np.ndarray         # (steps+1, 2)
    velocities: np.ndarray        # (steps+1, 2)
    accelerations: np.ndarray     # (steps+1, 2)
    zs: np.ndarray                # (steps, 2)


def _trajectory(p0, v0, a, steps, dt, noise_std, seed) -> Trajectory2D:
    steps = _steps(steps)
    if not (dt > 0 and noise_std >= 0):
        raise ModelError(f"need dt > 0 and noise_std >= 0, got dt={dt!r}, "
                         f"noise_std={noise_std!r}")
    t = np.arange(steps + 1) * float(dt)
    p0, v0, a = (np.asarray(vec, dtype=float).reshape(2) for vec in (p0, v0, a))
    pos = p0 + np.outer(t, v0) + 0.5 * np.outer(t ** 2, a)
    vel = v0 + np.outer(t, a)
    acc = np.tile(a, (steps + 1, 1))
    noise = np.random.default_rng(seed).standard_normal((steps, 2)) * noise_std
    return Trajectory2D(float(dt), float(noise_std), t, pos, vel, acc, pos[1:] + noise)


def constant_velocity_2d(steps: int, seed: int, dt: float = 1.0,
                         noise_std: float = float(np.sqrt(0.1)),
                         velocity=(20.0, 30.0), position0=(0.0, 0.0)) -> Trajectory2D:
    """SSPRED constant-velocity truth, (vx, vy) = (20, 30) m/s from the origin; positions
    measured with white noise of std noise_std per axis (default sqrt(0.1) m, i.e. the
    papers' sigma_r² = 0.1), sampled every dt = 1 s."""
    return _trajectory(position0, velocity, (0.0, 0.0), steps, dt, noise_std, seed)


def constant_acceleration_2d(steps: int, seed: int, dt: float = 1.0,
                             noise_std: float = float(np.sqrt(0.1)),
                             acceleration=(2.0, 3.0), velocity0=(0.0, 0.0),
                             position0=(0.0, 0.0)) -> Trajectory2D:
    """SSPRED constant-acceleration truth, (ax, ay) = (2, 3) m/s² from rest at the origin;
    same measurement noise and dt as constant_velocity_2d."""
    return _trajectory(position0, velocity0, acceleration, steps, dt, noise_std, seed)


# ---------------------------------------------------------------- geodesy
def geodetic_to_ecef(lat_deg: float, lon_deg: float, height: float) -> np.ndarray:
    """WGS-84 geodetic latitude, longitude (degrees) and ellipsoidal height (m) to ECEF (m):
    N = a / sqrt(1 − e² sin²φ), X = (N+h) cosφ cosλ, Y = (N+h) cosφ sinλ,
    Z = (N(1 − e²) + h) sinφ."""
    phi, lam = np.radians(lat_deg), np.radians(lon_deg)
    N = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(phi) ** 2)
    return np.array([(N + height) * np.cos(phi) * np.cos(lam),
                     (N + height) * np.cos(phi) * np.sin(lam),
                     (N * (1.0 - WGS84_E2) + height) * np.sin(phi)])


def enu_basis(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rows: east, north, up unit vectors (ECEF) at a geodetic latitude/longitude."""
    phi, lam = np.radians(lat_deg), np.radians(lon_deg)
    return np.array([[-np.sin(lam), np.cos(lam), 0.0],
                     [-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)],
                     [np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)]])


def satellite_at(receiver: np.ndarray, lat_deg: float, lon_deg: float, elevation_deg: float,
                 azimuth_deg: float, radius: float = GPS_ORBIT_RADIUS) -> np.ndarray:
    """ECEF position at distance `radius` from the Earth's centre seen from the receiver at
    the given elevation and azimuth (clockwise from north)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    east, north, up = enu_basis(lat_deg, lon_deg)
    u = np.cos(el) * np.sin(az) * east + np.cos(el) * np.cos(az) * north + np.sin(el) * up
    ru = receiver @ u
    rng = -ru + np.sqrt(ru ** 2 - receiver @ receiver + radius ** 2)
    return receiver + rng * u


def _rotate(p: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues rotation of p about a unit axis."""
    return (p * np.cos(angle) + np.cross(axis, p) * np.sin(angle)
            + axis * (axis @ p) * (1.0 - np.cos(angle)))


# ---------------------------------------------------------------- GNSS
def pseudorange(x: np.ndarray, sats: np.ndarray) -> np.ndarray:
    """D_i = ||s_i − [x, y, z]|| + b for state x = [x, y, z, b] and satellites (k, 3)."""
    return np.linalg.norm(sats - x[:3], axis=1) + x[3]


def pseudorange_jacobian(x: np.ndarray, sats: np.ndarray) -> np.ndarray:
    """∂D/∂X: rows [−(s_i − r)ᵀ / ||s_i − r||, 1]."""
    diff = sats - x[:3]
    return np.hstack([-diff / np.linalg.norm(diff, axis=1)[:, None], np.ones((len(sats), 1))])


@dataclass(frozen=True)
class GnssScenario:
    """A stationary receiver, four satellites and pseudoranges (the GNSS paper).

    truth: (steps+1, 4) states [x, y, z, b] (ECEF m, clock bias m) for k = 0..steps;
    satellites: (steps, 4, 3) ECEF positions at k = 1..steps; pseudoranges: (steps, 4).
    x0, P0: a filter start, x0 = truth(0) + N(0, init_std² I), P0 = init_std² I.
    Q = 0.01 I4 and R = sigma² I4 are the paper's filter covariances."""

    dt: float
    sigma: float
    geodetic: tuple[float, float, float]
    receiver: np.ndarray
    clock_bias: float
    elevations_deg: np.ndarray
    azimuths_deg: np.ndarray
    truth: np.ndarray
    satellites: np.ndarray
    pseudoranges: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    Q: np.ndarray
    R: np.ndarray


def gnss_scenario(steps: int = 500, seed: int = 0, sigma: float = 10.0,
                  clock_bias: float = 100.0, geodetic=STADIUM,
                  elevations_deg=(80.0, 35.0, 45.0, 55.0),
                  azimuths_deg=(30.0, 90.0, 210.0, 330.0),
                  dt: float = 1.0, moving: bool = False, init_std: float = 10.0,
                  q: float = 0.01) -> GnssScenario:
    """Receiver at the stadium (40.988 N, 29.037 E, 50 m) in ECEF, clock bias b (default
    100 m ≈ 0.33 µs), static truth. Satellites at GPS radius 26,560 km, by default one near
    zenith (el 80°, az 30°) and three spread in azimuth (35°/90°, 45°/210°, 55°/330°).
    moving=True turns each satellite about the axis normal to its position and the Earth's
    polar axis at the GPS mean motion (a plausible drift, not an ephemeris).
    Pseudoranges: D_i + v_i, v_i ~ N(0, sigma²), sigma = 10 m, one per dt = 1 s."""
    steps = _steps(steps)
    elev = np.asarray(elevations_deg, dtype=float)
    azim = np.asarray(azimuths_deg, dtype=float)
    if elev.shape != azim.shape or elev.ndim != 1 or len(elev) < 4:
        raise ShapeError("elevations_deg and azimuths_deg need equal length >= 4, got "
                         f"{elev.shape} and {azim.shape}")
    lat, lon, height = (float(v) for v in geodetic)
    receiver = geodetic_to_ecef(lat, lon, height)
    start = np.array([satellite_at(receiver, lat, lon, e, a) for e, a in zip(elev, azim)])
    t = np.arange(1, steps + 1) * dt
    if moving:
        axes = np.cross(start, [0.0, 0.0, 1.0])
        axes /= np.linalg.norm(axes, axis=1)[:, None]
        sats = np.array([[_rotate(p, ax, GPS_ANGULAR_RATE * tk) for p, ax in zip(start, axes)]
                         for tk in t])
    else:
        sats = np.broadcast_to(start, (steps, *start.shape)).copy()
    state = np.append(receiver, clock_bias)
    truth = np.tile(state, (steps + 1, 1))
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((steps, len(elev))) * sigma
    ranges = np.array([pseudorange(state, s) for s in sats]) + noise
    x0 = state + rng.standard_normal(4) * init_std
    return GnssScenario(float(dt), float(sigma), (lat, lon, height), receiver,
                        float(clock_bias), elev, azim, truth, sats, ranges, x0,
                        init_std ** 2 * np.eye(4), q * np.eye(4),
                        sigma ** 2 * np.eye(len(elev)))


# ---------------------------------------------------------------- several sensors
SENSOR_PERIODS = (1, 4, 10, 20)
"""Steps between measurements of the first, second, third and later sensors of a model
(an IMU-driven run at the step rate with slower sensors): the other rows are NaN."""


@dataclass(frozen=True)
class SensorRun:
    """A seeded run of a model with sensors: ``zs`` ``{sensor: (steps, m_s)}`` (rows of
    NaN where the sensor has no measurement), inputs ``us`` (steps, n_u), the truth
    (steps + 1, n), and the x0, P0 the filters start from."""

    zs: dict
    us: np.ndarray
    truth: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    Rs: dict


def _unit(x: np.ndarray, groups: list[list[int]]) -> None:
    """Each unit-norm group of the state x divided by its norm, in place."""
    for rows in groups:
        x[rows] /= np.linalg.norm(x[rows])


def simulate_sensors(model, groups, steps: int, seed: int, params=None) -> SensorRun:
    """The model's own process driven by inputs uniform in [-1, 1] (nonlinear: with noise
    of covariance Qu on them) and process noise, each group of states the model declares
    unit-norm kept unit in the truth (a quaternion driven by delta angles of up to 1 rad a
    step would otherwise grow without bound, f being first order), manifold states moved by
    ⊞ (the noise, and the start's spread, in the tangent space), measured by each sensor
    of ``groups``
    (derive.model.SensorGroup, rows of the model's stacked h or H) every
    :data:`SENSOR_PERIODS` steps, with noise of its R (an R that depends on the state or
    the inputs: at each step's truth and inputs; a sensor whose R is given per call:
    a diagonal R per step, uniform in [0.5, 2], in ``Rs``). Needs every symbol to have a
    value (``params``: values of the free parameters, name -> number)."""
    steps = _steps(steps)
    rng = np.random.default_rng(seed)
    n, nt, n_u = model.n, model.n_tangent, len(model.inputs)
    x0 = np.asarray(model.x0.tolist(), dtype=float).ravel()
    P0 = np.asarray(model.P0.tolist(), dtype=float)
    us = rng.uniform(-1.0, 1.0, (steps, n_u))
    truth = np.empty((steps + 1, n))
    layout = getattr(model, "layout", None)

    def moved(x, w):  # manifold states: x ⊞ w, w in the tangent space (derive.manifolds)
        return x + w if layout is None else boxplus_numeric(layout, x, w)
    truth[0] = moved(x0, rng.multivariate_normal(np.zeros(nt), P0, method="eigh"))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # refused below, by step
        if model.kind == "linear":
            num = model.numeric(params)
            w = rng.multivariate_normal(np.zeros(num.Q.shape[0]), num.Q, size=steps, method="eigh")
            for k in range(steps):
                truth[k + 1] = num.F @ truth[k] + num.B @ us[k] + num.G @ w[k]

            def h(x, u):
                return num.H @ x + num.D @ u
            R = num.R
        else:
            fns = model.numeric_functions(params)
            moving = set(model.state_symbols) | set(model.inputs)
            if model.Q.free_symbols & moving:
                raise VerificationError(f"no sensor simulation for model {model.name!r}: its "
                                        "Q depends on the state or the inputs")
            w = rng.multivariate_normal(np.zeros(nt), fns["Q"], size=steps, method="eigh")
            noisy = us + (rng.multivariate_normal(np.zeros(n_u), fns["Qu"], size=steps,
                                                  method="eigh") if n_u else 0.0)
            groups_at = [[model.states.index(s) for s in g] for g in model.unit_norm]
            _unit(truth[0], groups_at)
            for k in range(steps):
                step_u = noisy[k, [model.inputs.index(u) for u in model.f_inputs]]
                truth[k + 1] = moved(fns["f"](truth[k], step_u) if model.f_inputs
                                     else fns["f"](truth[k]), w[k])
                _unit(truth[k + 1], groups_at)
            h, R = fns["h"], fns["R"]
        if callable(R):  # R(x, u): the noise of each row at the truth it measures
            v = np.array([rng.multivariate_normal(np.zeros(model.m), R(truth[k + 1], us[k]),
                                                  method="eigh") for k in range(steps)])
        else:
            v = rng.multivariate_normal(np.zeros(model.m), R, size=steps, method="eigh")
        stacked = np.array([h(truth[k + 1], us[k]) for k in range(steps)]) + v
    _finite(truth, stacked)
    zs, Rs = {}, {}
    for i, group in enumerate(groups):
        rows = stacked[:, group.rows[0]:group.rows[1]].copy()
        if group.R_argument:  # R per step: a diagonal drawn in [0.5, 2], noise of that R
            scale = rng.uniform(0.5, 2.0, (steps, group.m))
            Rs[group.name] = np.einsum("ki,ij->kij", scale, np.eye(group.m))
            rows = rows - v[:, group.rows[0]:group.rows[1]] + np.sqrt(scale) * rng.standard_normal(
                (steps, group.m))
        period = SENSOR_PERIODS[min(i, len(SENSOR_PERIODS) - 1)]
        rows[np.arange(steps) % period != 0] = np.nan
        zs[group.name] = rows
    return SensorRun(zs, us, truth, x0, P0, Rs)
