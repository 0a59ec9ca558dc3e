"""The hand-written NumPy INS/GNSS EKF (derive.apps.ins.reference) against SPEC section 8:
Jacobians against central finite differences, the process noise's structure, the update's
renormalisation, and the filter's consistency on the seeded flight."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from derive.apps.ins import constants as c
from derive.apps.ins import flight as fl
from derive.apps.ins import reference as ref
from derive.apps.ins.quaternion import rotation_matrix


def _point(seed: int):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    x = np.concatenate([q / np.linalg.norm(q) * 1.01, rng.normal(size=6) * 10,
                        rng.normal(size=3) * 1e-2, rng.normal(size=3) * 0.1])
    u = np.concatenate([rng.normal(size=3), rng.normal(size=3) * 5])
    return x, u


def _central(fun, point, step):
    cols = []
    for i in range(len(point)):
        e = np.zeros(len(point))
        e[i] = step
        cols.append((fun(point + e) - fun(point - e)) / (2 * step))
    return np.array(cols).T


@pytest.mark.parametrize("seed", range(4))
def test_jacobians_match_finite_differences(seed):
    x, u = _point(seed)
    dt = 0.01 + 0.02 * seed
    jac, jac_u = ref.jacobians(x, u, dt)
    # f is a polynomial of degree 3 in (x, u): the central difference's error is h²/6 times
    # the third derivative (dt-sized, O(1) entries), so h = 1e-4 leaves ~1e-10 plus rounding
    step = 1e-4
    tolerance = step ** 2 + 1e3 * np.finfo(float).eps * np.abs(ref.f(x, u, dt)).max() / step
    assert np.abs(jac - _central(lambda y: ref.f(y, u, dt), x, step)).max() < tolerance
    assert np.abs(jac_u - _central(lambda v: ref.f(x, v, dt), u, step)).max() < tolerance
    # the hand-written pieces are not all identities: each block is exercised
    assert np.abs(jac[ref.V_ROWS, ref.Q_ROWS]).max() > 0.01
    assert np.abs(jac[ref.Q_ROWS, ref.BG_ROWS]).max() > 0.001


def test_f_follows_spec_for_a_known_case():
    # level, heading north, at rest, accelerometer reading -g on z: nothing moves
    x = c.X0.copy()
    u = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -c.GRAVITY])
    assert np.array_equal(ref.f(x, u, 0.01), x)
    # a yaw rate turns q by [1, 0, 0, ω dt/2] (first order, not renormalised)
    u = np.array([0.0, 0.0, 0.2, 0.0, 0.0, -c.GRAVITY])
    assert np.allclose(ref.f(x, u, 0.01)[:4], [1.0, 0.0, 0.0, 0.001], rtol=0, atol=1e-17)


def test_process_noise_depends_on_dt_and_state():
    x, u = _point(9)
    q1, q2 = ref.process_noise(x, u, 0.01), ref.process_noise(x, u, 0.02)
    assert np.abs(q1 - q1.T).max() <= 4 * np.finfo(float).eps * np.abs(q1).max()
    # the bias random walks: σ² dt on the diagonal, nothing else in those rows
    assert np.allclose(np.diag(q1)[10:13], c.SIGMA_GYRO_BIAS ** 2 * 0.01, rtol=1e-15, atol=0)
    assert np.allclose(np.diag(q2)[13:], c.SIGMA_ACCEL_BIAS ** 2 * 0.02, rtol=1e-15, atol=0)
    assert np.count_nonzero(q1[10:, :]) == 6
    # the velocity block is dt² σa² C Cᵀ (C(q) not orthogonal for |q| != 1)
    cq = rotation_matrix(x[:4])
    assert np.allclose(q1[4:7, 4:7], 1e-4 * c.SIGMA_ACCEL ** 2 * cq @ cq.T, rtol=1e-13, atol=0)
    # the attitude block is (dt/2)² σg² L Lᵀ over L's vector columns
    lq = ref.left_matrix(x[:4])[:, 1:]
    assert np.allclose(q1[:4, :4], 0.25e-4 * c.SIGMA_GYRO ** 2 * lq @ lq.T, rtol=1e-13, atol=0)


def test_update_renormalises_the_quaternion():
    x, _ = _point(4)
    P = c.p0()
    z = ref.h_gnss(x) + 1.0
    new, P_new, innovation, S = ref.update(x, P, z, "gnss")
    assert abs(np.linalg.norm(new[:4]) - 1) < 4 * np.finfo(float).eps
    assert np.allclose(innovation, 1.0, rtol=0, atol=1e-13)
    assert np.allclose(S, ref.H_gnss() @ P @ ref.H_gnss().T + np.diag(c.GNSS_STD ** 2),
                       rtol=1e-15, atol=0)
    new, _, _, _ = ref.update(x, P, np.array([-x[9] + 0.3]), "baro")
    assert abs(np.linalg.norm(new[:4]) - 1) < 4 * np.finfo(float).eps


@pytest.fixture(scope="module")
def reference_run():
    flight = fl.simulate(seed=0)
    return flight, ref.run(flight)


def test_filter_is_consistent_on_the_flight(reference_run):
    flight, run = reference_run
    # NIS per sensor: its mean within 5 standard errors of m (chi-square mean m, var 2m)
    for name, m in (("gnss", 6), ("baro", 1)):
        rows, nis = run.nis[name]
        assert len(rows) == len(getattr(flight, f"{name}_rows"))
        assert abs(nis.mean() - m) < 5 * np.sqrt(2 * m / len(nis))
        # and at least 90 % of the epochs inside the 95 % band
        low, high = chi2.ppf([0.025, 0.975], m)
        assert np.mean((nis >= low) & (nis <= high)) > 0.9
    # biases converge toward the truth within 3σ at the end
    sd = np.sqrt(np.diag(run.Ps[-1]))
    truth = flight.states[-1]
    assert np.all(np.abs(run.xs[-1, 10:] - truth[10:]) <= 3 * sd[10:])
