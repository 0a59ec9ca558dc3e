"""The generated EKF of the catalog model ``ins_gnss`` over SPEC §8's whole 120 s flight, in
Python and in C, against the hand-written NumPy reference EKF (1e-9 relative: states per
state against max(max_k |x|, prior σ), covariances against sqrt(P_ii P_jj)); the bar that
its position error is inside its own 3σ at ≥ 95 % of GNSS epochs; the per-step calls agree
with the single ``run`` call."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from derive.apps.ins import compare, flight, reference
from derive.apps.ins.constants import STATES
from derive.apps.ins.run import AGREEMENT, generated_run, stepwise_run
from derive.pipeline import load_generated


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    fl = flight.simulate(seed=0)
    generated = load_generated("ins_gnss", "ekf", {}, "all", tmp_path_factory.mktemp("ins"))
    return fl, reference.run(fl), generated


@pytest.mark.parametrize("lang", ["c", "python"])
def test_whole_flight_matches_the_numpy_reference(setup, lang):
    fl, ref, generated = setup
    xs, Ps = generated_run(getattr(generated, lang), fl)
    assert np.all(np.isfinite(xs)) and np.all(np.isfinite(Ps))
    states = compare.state_agreement(xs, ref.xs)
    assert states.max() <= AGREEMENT, dict(zip(STATES, states))
    assert compare.covariance_agreement(Ps, ref.Ps) <= AGREEMENT
    # the quaternion is unit after every step that ended with an update
    updated = np.union1d(fl.gnss_rows, fl.baro_rows)
    assert np.abs(np.linalg.norm(xs[updated, :4], axis=1) - 1).max() < 8 * np.finfo(float).eps


def test_stepwise_calls_equal_the_run_and_give_the_reference_nis(setup):
    fl, ref, generated = setup
    xs, Ps = generated_run(generated.c, fl)
    steps = stepwise_run(generated.c, fl)
    assert np.array_equal(steps.xs, xs) and np.array_equal(steps.Ps, Ps)
    for name in ("gnss", "baro"):
        rows, nis = steps.nis[name]
        assert np.array_equal(rows, ref.nis[name][0])
        assert np.allclose(nis, ref.nis[name][1], rtol=AGREEMENT, atol=0)


def test_position_error_inside_three_sigma_at_most_gnss_epochs(setup):
    fl, _, generated = setup
    xs, Ps = generated_run(generated.c, fl)
    inside = compare.inside_fraction(fl, compare.errors(fl, xs, Ps))
    print(f"position error inside 3 sigma at {inside:.1%} of {len(fl.gnss_rows)} GNSS epochs")
    assert inside >= compare.INSIDE_BAR


def test_dt_is_a_per_step_parameter(setup):
    # a flight whose steps alternate between 10 ms and 5 ms: the generated run with a dt row
    # per step equals the reference stepping with those dts
    fl, _, generated = setup
    short = flight.simulate(seed=1, duration=2.0)
    dts = np.where(np.arange(short.steps) % 2 == 0, 0.01, 0.005)
    varied = replace(short, dt=dts)
    xs, Ps = generated_run(generated.c, varied)
    expected = reference.run(varied)
    assert compare.state_agreement(xs, expected.xs).max() <= AGREEMENT
    same = reference.run(short)
    assert np.abs(expected.xs - same.xs).max() > 1e-6  # the dt row is used
