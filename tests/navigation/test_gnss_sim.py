"""Scalar-update GNSS filters (derive.apps.gnss.scalar_updates, driven by derive.apps.gnss.drive) on
the simulated scenario of derive.apps.simulate, against the NumPy reference filters.

Sequential scalar updates re-linearise after every pseudorange, so they equal the
reference filter run one pseudorange per step (Q added at the first pseudorange of an
epoch only) to rounding, and differ from the reference's one-batch-per-epoch update only
by second-order terms (bounded below with the reason).
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from derive.apps.gnss import (
    Epoch,
    FilterSettings,
    ScalarEkf,
    ScalarUkf,
    drive,
    ekf_update1,
    least_squares_fix,
    numpy_filters,
    ukf_update1,
)
from derive.apps.gnss.errors import GnssDataError
from derive.apps.simulate import gnss_scenario, pseudorange, pseudorange_jacobian
from derive.errors import ModelError, NumericalError, ShapeError
from derive.reference import ekf, ukf

EXACT = 1e-6          # m: same algorithm, different code; observed ~1e-9


def nis_atol(sc) -> float:
    """Absolute tolerance of a normalised innovation (z - h(x)) / sqrt(S) computed by two
    codes: z and h(x) are pseudoranges of ~2.6e7 m, so their difference carries a few
    roundings of that size (8 u |z|), divided by sqrt(S) >= sigma."""
    return 8 * np.finfo(float).eps * float(np.nanmax(np.abs(sc.pseudoranges))) / sc.sigma
SIX_SATS = dict(elevations_deg=(80.0, 35.0, 45.0, 55.0, 20.0, 65.0),
                azimuths_deg=(30.0, 90.0, 210.0, 330.0, 150.0, 270.0))


def epochs_of(scenario, keep=None):
    """Epoch objects from a scenario; keep (steps, m) bool selects satellites per epoch."""
    m = scenario.satellites.shape[1]
    names = tuple(f"S{i + 1:02d}" for i in range(m))
    keep = np.ones(scenario.pseudoranges.shape, bool) if keep is None else keep
    out = []
    for k, (sats, rho, sel) in enumerate(zip(scenario.satellites, scenario.pseudoranges, keep)):
        idx = np.flatnonzero(sel)
        zeros = np.zeros(len(idx))
        out.append(Epoch(float(k + 1), tuple(names[i] for i in idx), sats[idx], rho[idx],
                         zeros, zeros, zeros))
    return out


def per_scalar_reference(kind, epochs, x0, P0, Q, sigma, **weights):
    """derive.reference.ekf/ukf, one pseudorange per call, Q only at an epoch's first."""
    x, P = np.asarray(x0, float), np.asarray(P0, float)
    states, nis = [], []
    R = [[sigma ** 2]]
    for epoch in epochs:
        q = Q
        for i in np.argsort(epoch.prns, kind="stable"):
            z, u = [[epoch.pseudoranges[i]]], [epoch.satellites[i][None, :]]
            if kind == "ekf":
                res = ekf(None, None, pseudorange, pseudorange_jacobian, q, R, x, P, z, u)
            else:
                res = ukf(None, pseudorange, q, R, x, P, z, inputs=u, **weights)
            x, P = res.xs[0], res.Ps[0]
            nis.append(res.normalized_innovations[0, 0])
            q = np.zeros((4, 4))
        if not epoch.prns:
            P = P + Q
        states.append(x)
    return np.array(states), P, np.array(nis)


def used_normalized(track, epochs):
    """The track's normalised innovations in processing order."""
    col = {p: j for j, p in enumerate(track.prns)}
    return np.array([track.normalized_innovations[k, col[p]]
                     for k, e in enumerate(epochs) for p in sorted(e.prns)])


@pytest.mark.parametrize("moving", [False, True])
def test_scalar_ekf_equals_reference_one_pseudorange_per_step(moving):
    sc = gnss_scenario(steps=300, seed=3, moving=moving)
    epochs = epochs_of(sc)
    f = ScalarEkf(sc.Q, sc.sigma)
    track = drive(f.predict, f.update1, epochs, sc.x0, sc.P0, sc.sigma)
    xs, P, nis = per_scalar_reference("ekf", epochs, sc.x0, sc.P0, sc.Q, sc.sigma)
    np.testing.assert_allclose(track.states, xs, rtol=0, atol=EXACT)
    np.testing.assert_allclose(track.covariances[-1], P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(used_normalized(track, epochs), nis, rtol=1e-7, atol=1e-9)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2 ** 16), drop=st.floats(0.0, 0.6),
       alpha=st.floats(0.5, 1.5), beta=st.floats(0.0, 2.0), kappa=st.floats(-1.0, 3.0))
def test_scalar_filters_follow_a_varying_number_of_satellites(seed, drop, alpha, beta, kappa):
    """Random dropouts (0 to 6 satellites per epoch) and UKF weights."""
    sc = gnss_scenario(steps=40, seed=seed, moving=True, **SIX_SATS)
    keep = np.random.default_rng(seed).random(sc.pseudoranges.shape) >= drop
    epochs = epochs_of(sc, keep)
    f = ScalarEkf(sc.Q, sc.sigma)
    track = drive(f.predict, f.update1, epochs, sc.x0, sc.P0, sc.sigma)
    xs, _, nis = per_scalar_reference("ekf", epochs, sc.x0, sc.P0, sc.Q, sc.sigma)
    np.testing.assert_allclose(track.states, xs, rtol=0, atol=EXACT)
    np.testing.assert_allclose(used_normalized(track, epochs), nis, rtol=1e-7, atol=nis_atol(sc))
    u = ScalarUkf(sc.Q, sc.sigma, alpha, beta, kappa)
    track = drive(u.predict, u.update1, epochs, sc.x0, sc.P0, sc.sigma)
    xs, P, nis = per_scalar_reference("ukf", epochs, sc.x0, sc.P0, sc.Q, sc.sigma,
                                      alpha=alpha, beta=beta, kappa=kappa)
    np.testing.assert_allclose(track.states, xs, rtol=0, atol=EXACT)
    np.testing.assert_allclose(track.covariances[-1], P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(used_normalized(track, epochs), nis, rtol=1e-7, atol=nis_atol(sc))
    assert np.all(np.isnan(track.innovations[~keep]))


@pytest.mark.parametrize("kind", ["EKF", "UKF"])
def test_sequential_differs_from_batch_only_at_second_order(kind):
    """Batch: the reference filter with all four pseudoranges of an epoch at once. The
    Jacobian moves by |Δx|/ρ ≈ 30 m / 2e7 m ≈ 1.5e-6 between scalars; times innovations of
    tens of metres this bounds the state difference by ~1e-5 m (observed ~1e-6 m)."""
    sc = gnss_scenario(steps=500, seed=1, moving=True)
    settings_ = FilterSettings(sigma=sc.sigma, q_position=0.01, q_clock=0.01, p0_std=10.0)
    predict, update1 = numpy_filters(settings_)[kind]
    track = drive(predict, update1, epochs_of(sc), sc.x0, sc.P0, sc.sigma)
    if kind == "EKF":
        ref = ekf(None, None, pseudorange, pseudorange_jacobian, sc.Q, sc.R, sc.x0, sc.P0,
                  sc.pseudoranges, inputs=list(sc.satellites))
    else:
        ref = ukf(None, pseudorange, sc.Q, sc.R, sc.x0, sc.P0, sc.pseudoranges,
                  inputs=list(sc.satellites))
    np.testing.assert_allclose(track.states, ref.xs, rtol=0, atol=1e-5)
    np.testing.assert_allclose(track.covariances, ref.Ps, rtol=0, atol=1e-4)


def test_linear_case_sequential_equals_batch_exactly():
    """With the position known (P's position block zero) only b moves, so h is affine in
    the uncertain state and sequential scalar updates equal the batch update."""
    sc = gnss_scenario(steps=50, seed=5, moving=True)
    x0 = sc.truth[0] + np.array([0.0, 0.0, 0.0, 7.0])
    P0, Q = np.diag([0.0, 0.0, 0.0, 100.0]), np.diag([0.0, 0.0, 0.0, 0.01])
    f = ScalarEkf(Q, sc.sigma)
    track = drive(f.predict, f.update1, epochs_of(sc), x0, P0, sc.sigma)
    ref = ekf(None, None, pseudorange, pseudorange_jacobian, Q, sc.R, x0, P0,
              sc.pseudoranges, inputs=list(sc.satellites))
    np.testing.assert_allclose(track.states, ref.xs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.covariances, ref.Ps, rtol=1e-10, atol=1e-12)


def test_driver_accepts_two_tuple_updates_like_generated_code():
    sc = gnss_scenario(steps=50, seed=2, moving=True)
    f = ScalarEkf(sc.Q, sc.sigma)
    epochs = epochs_of(sc)
    full = drive(f.predict, f.update1, epochs, sc.x0, sc.P0, sc.sigma)
    bare = drive(f.predict, lambda x, P, rho, s: f.update1(x, P, rho, s)[:2], epochs,
                 sc.x0, sc.P0, sc.sigma)
    np.testing.assert_array_equal(bare.states, full.states)
    np.testing.assert_allclose(bare.normalized_innovations, full.normalized_innovations,
                               rtol=1e-12)


def test_ukf_update_reports_an_indefinite_covariance_with_its_epoch():
    sc = gnss_scenario(steps=3, seed=0)
    u = ScalarUkf(np.zeros((4, 4)), sc.sigma)
    with pytest.raises(NumericalError, match=r"epoch 0 .*S01.*not positive definite"):
        drive(u.predict, u.update1, epochs_of(sc), sc.x0, np.diag([1.0, 1.0, -1.0, 1.0]),
              sc.sigma)


def test_scalar_updates_reject_bad_shapes_and_settings():
    x, P = np.zeros(4) + 1.0, np.eye(4)
    with pytest.raises(ShapeError, match=r"sat_xyz .*\(3,\).*\(2,\)"):
        ekf_update1(x, P, 2e7, [1.0, 2.0], 9.0)
    with pytest.raises(ShapeError, match="sat_xyz"):
        ukf_update1(x, P, 2e7, np.zeros((1, 3)), 9.0)
    with pytest.raises(ShapeError, match=r"Q must be 4×4"):
        ScalarEkf(np.eye(3), 3.0)
    with pytest.raises(ModelError, match="sigma"):
        FilterSettings(sigma=0.0)
    with pytest.raises(ModelError, match="q_clock"):
        FilterSettings(q_clock=-1.0)


def test_least_squares_recovers_a_noiseless_position():
    sc = gnss_scenario(steps=2, seed=0, sigma=0.0, moving=True, **SIX_SATS)
    fix = least_squares_fix(sc.satellites[0], sc.pseudoranges[0])
    np.testing.assert_allclose(fix.state, sc.truth[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fix.residuals, 0.0, atol=1e-6)
    assert 1.0 < fix.gdop < 10.0
    with pytest.raises(GnssDataError, match=">= 4 satellites, got 3"):
        least_squares_fix(sc.satellites[0][:3], sc.pseudoranges[0][:3])
