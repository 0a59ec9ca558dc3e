"""The option ``loglik``: run stores each step's Gaussian log-likelihood of the innovation,
-1/2 (m log 2 pi + log det S + nu' S^-1 nu), computed from the LDL^T factors of S the update
solves with; a missing measurement adds nothing.

Checked against the NumPy reference (derive.reference.likelihood, slogdet and a solve) to the
linear tolerance, against statsmodels' ``loglikeobs`` and pykalman's ``loglikelihood`` (their
first state is derive's first prediction: statsmodels' a_1 = F x0, P_1 = F P0 F' + G Q G';
pykalman's initial state, which it updates before it predicts, the same; pykalman skips an
observation with any entry missing whole, so it is given rows missing whole), and counted as
every operation is: header = Python executed = C text.
"""

import numpy as np
import pytest
from test_dynamic_counts import _inputs
from test_ekf_ukf import PENDULUM
from test_missing_measurements import correlated, gappy

from derive import catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import (
    LINEAR_TOLERANCE,
    NONLINEAR_TOLERANCE,
    nonlinear_scenario,
    relative_error,
    verify_modules,
)
from derive.cli import main
from derive.filters import derive_unit
from derive.fitting import free_text
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.modelfile import loads_model
from derive.pipeline import load_generated
from derive.reference.likelihood import gaussian_loglik, innovations_loglik

STEPS = 120


def scenario(model, seed: int = 5):
    """``model``'s measurements over STEPS steps with about a third missing (steps 0, 7 and
    40..45 entirely), P0 = I, and the reference run's per-step log-likelihoods."""
    num = model.numeric()
    zs = gappy(simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, STEPS, seed).zs,
               seed)
    P0 = np.eye(model.n)
    lls = np.empty(STEPS)
    reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs, lls=lls)
    return num, zs, P0, lls


@pytest.fixture(scope="module")
def axes():
    """mpt3d_a (three measured axes) with missing measurements, and its KF with loglik."""
    model = catalog.load("mpt3d_a")
    return (model, *scenario(model),
            load_generated(model, "kf", {"missing": True, "loglik": True}))


def test_kf_and_udkf_loglik_equal_the_reference_with_missing_measurements(axes):
    model, num, zs, P0, lls, generated = axes
    assert np.isnan(zs[7]).all() and lls[7] == 0.0  # the reference: a step with nothing
    ud = load_generated(model, "udkf", {"missing": True, "loglik": True}, "python").python
    for module in (generated.python, generated.c, ud):
        xs, Ps, ll = module.run(zs, num.x0, P0)
        assert np.shape(ll) == (STEPS,)
        assert relative_error(ll, lls) <= LINEAR_TOLERANCE
        assert ll[7] == 0.0  # every measurement absent: log 1 = 0 and a masked nu
        assert abs(np.sum(ll) - np.sum(lls)) <= LINEAR_TOLERANCE * abs(np.sum(lls))


def test_each_step_is_the_log_density_of_its_own_innovation():
    """Correlated R, rows missing: each step's ll is log N(nu; 0, S) of the prediction the
    generated run made, to 1e-12 (the UD filter's from its scalar updates of the
    decorrelated measurements).  (Run against run, ll differs by what x does: nu = z - H x
    cancels, so x's absolute rounding error, growing with |x|, reaches ll unscaled; this
    model's position grows to ~1e4 and its run-to-run ll differs by ~2e-12.)"""
    model = correlated()
    num, zs, P0, _ = scenario(model)
    generated = load_generated(model, "kf", {"missing": True, "loglik": True})
    ud = load_generated(model, "udkf", {"missing": True, "loglik": True}, "python").python
    for module in (generated.python, generated.c, ud):
        xs, Ps, ll = module.run(zs, num.x0, P0)
        Ps = np.reshape(Ps, (STEPS, model.n, model.n))
        for k in range(1, STEPS):
            x = num.F @ xs[k - 1]
            P = num.F @ Ps[k - 1] @ num.F.T + num.GQGt
            present = ~np.isnan(zs[k])
            H = num.H[present]
            expected = (gaussian_loglik(zs[k][present] - H @ x,
                                        H @ P @ H.T + num.R[np.ix_(present, present)])
                        if present.any() else 0.0)
            assert abs(ll[k] - expected) <= LINEAR_TOLERANCE * max(abs(expected), 1.0)


def test_the_c_run_takes_lls_null_and_the_estimates_do_not_change(axes):
    model, num, zs, P0, lls, generated = axes
    xs, Ps, ll = generated.c.run(zs, num.x0, P0)
    step = generated.python.step(num.x0, P0.ravel(), zs[0])
    assert len(step) == 3  # x_new, P_new, ll
    alone = generated.c.call("run", zs, num.x0, P0, with_covariance=False)  # Ps, lls NULL
    np.testing.assert_array_equal(alone, xs)
    # run_tracks: each track's xs its own run's (lls not stored by the wrapper)
    xs2, _ = generated.c.run_tracks(np.stack([zs, zs[::-1]]), np.stack([num.x0] * 2),
                                    np.stack([P0] * 2))
    np.testing.assert_array_equal(xs2[0], xs)
    np.testing.assert_array_equal(xs2[1], generated.c.run(zs[::-1], num.x0, P0)[0])
    # Python's tracks axis: each track's lls as its own run's
    both = np.stack([zs, zs[::-1]], axis=-1)
    _, _, ll2 = generated.python.run(both, np.stack([num.x0] * 2, -1),
                                     np.stack([P0] * 2, -1))
    np.testing.assert_array_equal(ll2[:, 0], generated.python.run(zs, num.x0, P0)[2])
    np.testing.assert_array_equal(ll2[:, 1], generated.python.run(zs[::-1], num.x0, P0)[2])
    plain = load_generated(model, "kf", {"missing": True}, "python").python
    xp, Pp = plain.run(zs, num.x0, P0)
    np.testing.assert_array_equal(generated.python.run(zs, num.x0, P0)[0], xp)
    assert relative_error(xs, xp) <= LINEAR_TOLERANCE


def test_kf_loglik_equals_statsmodels_and_pykalman(axes):
    from pykalman import KalmanFilter as PyKalman
    from statsmodels.tsa.statespace.kalman_filter import KalmanFilter

    model, num, zs, P0, lls, generated = axes
    _, _, ll = generated.python.run(zs, num.x0, P0)
    a1 = num.F @ num.x0  # derive predicts first: the others' first state is x(1/0)
    P1 = num.F @ P0 @ num.F.T + num.GQGt
    sm = KalmanFilter(k_endog=model.m, k_states=model.n, k_posdef=num.G.shape[1],
                      transition=num.F, design=num.H, selection=num.G,
                      state_cov=num.Q, obs_cov=num.R)
    sm.bind(zs.copy())
    sm.initialize_known(a1, P1)
    theirs = sm.filter().llf_obs
    assert relative_error(ll, theirs) <= LINEAR_TOLERANCE
    # pykalman skips an observation with any entry masked whole: rows missing whole
    rows = np.where(np.isnan(zs).any(axis=1, keepdims=True), np.nan, zs)
    _, _, ll = generated.python.run(rows, num.x0, P0)
    pk = PyKalman(transition_matrices=num.F, observation_matrices=num.H,
                  transition_covariance=num.GQGt, observation_covariance=num.R,
                  initial_state_mean=a1, initial_state_covariance=P1)
    total = pk.loglikelihood(np.ma.masked_invalid(rows))
    assert abs(np.sum(ll) - total) <= LINEAR_TOLERANCE * abs(total)


def test_ekf_loglik_equals_the_reference_innovations_loglik():
    """The EKF's ll against log N(nu; 0, S) of the reference EKF's recorded innovations."""
    fns = PENDULUM.numeric_functions()
    sc = nonlinear_scenario(PENDULUM, STEPS, seed=3)
    res = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"], sc.x0,
                        sc.P0, sc.zs, skip_nan=False)
    expected = innovations_loglik(res.innovations, res.innovation_covariances)
    generated = load_generated(PENDULUM, "ekf", {"loglik": True})
    for module in (generated.python, generated.c):
        xs, Ps, ll = module.run(sc.zs, sc.x0, sc.P0)
        assert relative_error(xs, res.xs) <= NONLINEAR_TOLERANCE
        assert relative_error(ll, expected) <= NONLINEAR_TOLERANCE


@pytest.mark.parametrize("name, filter_name, options", [
    ("corr", "kf", {"missing": True, "loglik": True}), ("gps_static", "kf", {"loglik": True}),
    ("mpt3d_a", "udkf", {"missing": True, "loglik": True}),
    ("cv", "kf", {"missing": True, "gradient": True})])
def test_the_loglik_step_counts_agree(name, filter_name, options):
    """Header = Python executed (CountingFloat, np.log a call) = C text, log counted; with
    the option gradient (cv with sq2 and sr2 free) the step carrying the sensitivities."""
    model = (correlated() if name == "corr" else
             loads_model(free_text(catalog.read_text(name), ["sq2", "sr2"]))
             if options.get("gradient") else catalog.load(name))
    unit = derive_unit(model, filter_name, options)
    files = render_filter(model, filter_name, "all", options)
    scope: dict = {}
    py = files[f"{filter_name}.py"]
    exec(compile(py, "generated.py", "exec"), scope)  # derive's own generated code
    program = unit.programs["step"]
    static_py, static_c = count(program, "python"), count(program, "c")
    counter = OpCounter()
    scope["step"](*[counter.wrap(v) for v in _inputs(model, program, unit, "",
                                                      np.random.default_rng(2))])
    assert counter.snapshot() == static_py
    assert count_c_function(files[f"{filter_name}.c"], f"{unit.prefix}_step") == static_c
    assert static_c.calls == model.m  # one log per pivot
    assert f"operations per call of step (Python): {static_py.summary()}" in py


def test_loglik_is_refused_where_it_is_not_computed(tmp_path, capsys):
    assert main(["generate", "cv", "--filter", "sskf", "--loglik", "--out",
                 str(tmp_path)]) == 2
    assert "loglik" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_derive_verify_checks_lls_against_the_reference_scaled(axes):
    """verify_modules compares run's lls with the family's reference, each step's error
    relative to loglik_scale (its terms' size and the cancellation in nu); an lls off by
    1e-9 fails."""
    model, num, zs, P0, lls, generated = axes

    class Off:  # run's lls moved by 1e-9, its xs and Ps untouched
        def run(self, *args):
            xs, Ps, ll = generated.python.run(*args)
            return xs, Ps, ll + 1e-9

    options = {"missing": True, "loglik": True}
    good = verify_modules(model, "kf", {"python": generated.python}, 200, 7, options)
    bad = verify_modules(model, "kf", {"python": Off()}, 200, 7, options)
    assert good[0].passed and good[0].error <= LINEAR_TOLERANCE
    assert not bad[0].passed and bad[0].error > 1e-11
