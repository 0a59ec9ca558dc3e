"""Seeded simulations: reproducibility, noise statistics, geometry of the GNSS scenario."""

import numpy as np
import pytest

from derive.apps.simulate import (
    GPS_ANGULAR_RATE,
    GPS_ORBIT_RADIUS,
    STADIUM,
    WGS84_A,
    WGS84_E2,
    WGS84_F,
    constant_acceleration_2d,
    constant_velocity_2d,
    enu_basis,
    geodetic_to_ecef,
    gnss_scenario,
    pseudorange,
    pseudorange_jacobian,
    simulate_linear,
)
from derive.errors import ModelError, ShapeError

# Statistical checks use N samples; the standard error of a sample variance is about
# sqrt(2/N) relative, so with N = 20000 (1 %) a 5 % tolerance is five standard errors.
N_STAT = 20_000
VAR_TOL = 0.05


def model():
    F = np.array([[1.0, 1.0], [0.0, 0.9]])
    G = np.array([[0.5, 0.0], [1.0, 1.0]])                 # invertible: w is recoverable
    H = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    Q = np.array([[0.04, 0.01], [0.01, 0.09]])
    R = np.diag([0.1, 0.2, 0.5])
    return F, G, H, Q, R


def test_linear_simulation_is_reproducible():
    a = simulate_linear(*model(), [1.0, 2.0], 50, seed=4)
    b = simulate_linear(*model(), [1.0, 2.0], 50, seed=4)
    c = simulate_linear(*model(), [1.0, 2.0], 50, seed=5)
    assert np.array_equal(a.xs, b.xs) and np.array_equal(a.zs, b.zs)
    assert not np.array_equal(a.zs, c.zs)
    assert a.xs.shape == (51, 2) and a.zs.shape == (50, 3)
    assert np.array_equal(a.xs[0], [1.0, 2.0])


def test_linear_simulation_noise_statistics():
    F, G, H, Q, R = model()
    xs, zs = simulate_linear(F, G, H, Q, R, [0.0, 0.0], N_STAT, seed=1)
    w = np.linalg.solve(G, (xs[1:] - xs[:-1] @ F.T).T).T
    v = zs - xs[1:] @ H.T
    for noise, cov in ((w, Q), (v, R)):
        scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
        assert np.all(np.abs(np.cov(noise.T) - cov) <= VAR_TOL * scale)
        assert np.all(np.abs(noise.mean(axis=0)) <= 5 * np.sqrt(np.diag(cov) / N_STAT))


def test_linear_simulation_checks_shapes():
    F, G, H, Q, R = model()
    with pytest.raises(ShapeError, match="x0 must have 2 entries"):
        simulate_linear(F, G, H, Q, R, [0.0], 10, seed=0)
    with pytest.raises(ModelError, match="steps"):
        simulate_linear(F, G, H, Q, R, [0.0, 0.0], 0, seed=0)


def test_constant_velocity_truth_and_noise():
    run = constant_velocity_2d(N_STAT, seed=2)
    assert run.positions.shape == (N_STAT + 1, 2) and run.zs.shape == (N_STAT, 2)
    assert np.allclose(run.velocities, [20.0, 30.0])
    assert np.allclose(np.diff(run.positions, axis=0), [20.0, 30.0])
    assert np.allclose(run.accelerations, 0.0)
    noise = run.zs - run.positions[1:]
    assert np.all(np.abs(noise.std(axis=0) / run.noise_std - 1.0) < VAR_TOL)
    assert np.all(np.abs(noise.mean(axis=0)) < 5 * run.noise_std / np.sqrt(N_STAT))
    again = constant_velocity_2d(N_STAT, seed=2)
    assert np.array_equal(run.zs, again.zs)


def test_constant_acceleration_truth():
    run = constant_acceleration_2d(100, seed=3, dt=0.5)
    assert np.allclose(run.accelerations, [2.0, 3.0])
    assert np.allclose(np.diff(run.velocities, axis=0), [1.0, 1.5])
    # second difference of position = a dt²
    assert np.allclose(np.diff(run.positions, 2, axis=0), [0.5, 0.75])
    assert np.allclose(run.positions[0], 0.0) and np.allclose(run.velocities[0], 0.0)


def ecef_to_geodetic(p):
    """Independent inverse (Bowring's iteration) for the round-trip test."""
    x, y, z = p
    lon = np.arctan2(y, x)
    r = np.hypot(x, y)
    lat = np.arctan2(z, r * (1 - WGS84_E2))
    for _ in range(10):
        N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
        h = r / np.cos(lat) - N
        lat = np.arctan2(z, r * (1 - WGS84_E2 * N / (N + h)))
    return np.degrees(lat), np.degrees(lon), h


def test_geodetic_to_ecef():
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A, 0.0, 0.0], atol=1e-9)
    b = WGS84_A * (1 - WGS84_F)
    assert np.allclose(geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, b], atol=1e-6)
    assert np.allclose(geodetic_to_ecef(0.0, 90.0, 100.0), [0.0, WGS84_A + 100.0, 0.0],
                       atol=1e-6)
    for lat, lon, h in [STADIUM, (-33.9, 151.2, 20.0), (64.1, -21.9, 1000.0)]:
        back = ecef_to_geodetic(geodetic_to_ecef(lat, lon, h))
        assert np.allclose(back, (lat, lon, h), atol=1e-6)


def look_angles(receiver, geodetic, sat):
    east, north, up = enu_basis(*geodetic[:2])
    d = (sat - receiver) / np.linalg.norm(sat - receiver)
    return np.degrees(np.arcsin(d @ up)), np.degrees(np.arctan2(d @ east, d @ north)) % 360


def test_gnss_geometry():
    sc = gnss_scenario(steps=10, seed=0)
    assert np.allclose(sc.receiver, geodetic_to_ecef(*STADIUM))
    assert sc.satellites.shape == (10, 4, 3) and sc.pseudoranges.shape == (10, 4)
    assert np.allclose(np.linalg.norm(sc.satellites, axis=2), GPS_ORBIT_RADIUS, rtol=1e-12)
    for sat, el, az in zip(sc.satellites[0], sc.elevations_deg, sc.azimuths_deg):
        assert np.allclose(look_angles(sc.receiver, sc.geodetic, sat), (el, az), atol=1e-9)
    assert np.allclose(sc.truth, np.append(sc.receiver, sc.clock_bias))
    assert np.allclose(sc.Q, 0.01 * np.eye(4)) and np.allclose(sc.R, 100.0 * np.eye(4))


def test_gnss_pseudorange_noise_and_reproducibility():
    sc = gnss_scenario(steps=5000, seed=9)
    clean = np.array([pseudorange(sc.truth[k + 1], s) for k, s in enumerate(sc.satellites)])
    noise = sc.pseudoranges - clean
    # 5000 samples per satellite: std within ±7 % (≈ 5 standard errors of 1 %)
    assert np.all(np.abs(noise.std(axis=0) / sc.sigma - 1.0) < 0.07)
    assert np.all(np.abs(noise.mean(axis=0)) < 5 * sc.sigma / np.sqrt(5000))
    assert np.array_equal(sc.pseudoranges, gnss_scenario(steps=5000, seed=9).pseudoranges)
    assert not np.array_equal(sc.pseudoranges, gnss_scenario(steps=5000, seed=8).pseudoranges)


def test_gnss_moving_satellites_stay_on_orbit():
    sc = gnss_scenario(steps=100, seed=0, moving=True)
    assert np.allclose(np.linalg.norm(sc.satellites, axis=2), GPS_ORBIT_RADIUS, rtol=1e-12)
    step = np.linalg.norm(np.diff(sc.satellites, axis=0), axis=2)
    assert np.allclose(step, GPS_ORBIT_RADIUS * 2 * np.sin(GPS_ANGULAR_RATE / 2), rtol=1e-9)
    el, _ = look_angles(sc.receiver, sc.geodetic, sc.satellites[-1, 0])
    assert el > 0          # still above the horizon after 100 s


def test_pseudorange_jacobian_matches_finite_differences():
    sc = gnss_scenario(steps=1, seed=0)
    x, sats = sc.x0, sc.satellites[0]
    J = pseudorange_jacobian(x, sats)
    step = 1.0
    fd = np.column_stack([(pseudorange(x + step * e, sats) - pseudorange(x - step * e, sats))
                          / (2 * step) for e in np.eye(4)])
    assert np.allclose(J, fd, atol=1e-7)


def test_gnss_scenario_checks_geometry():
    with pytest.raises(ShapeError, match="elevations_deg"):
        gnss_scenario(steps=5, elevations_deg=(80.0, 30.0, 40.0), azimuths_deg=(0.0, 1.0, 2.0))
