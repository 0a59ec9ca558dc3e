"""derive fit / derive.fit: maximum likelihood with the exact gradient (derive.fitting).

Anchors: pykalman's robot data (free scales of Q and R) and gnss-benchmark's moving
receiver (constant velocity per axis, q and r free per axis, derive.apps.fit_anchors):
the estimates equal statsmodels' MLE of the same likelihood (derive.apps.fit_peer) to
1e-6 relative and the log-likelihoods at the optima to 1e-9. On the robot statsmodels runs
BFGS on its own log-likelihood and gradient to a tight tolerance from the parameters'
examples; on the receiver (where that takes it half a minute) its own score at derive's
estimate, through a Newton step, puts its MLE within 1e-6 of derive's.
Bad input: one line, exit 2, no file written.
"""

import sys

import numpy as np
import pytest
import sympy

from derive import catalog, reference
from derive.apps import fit_anchors
from derive.apps.fit_anchors import (
    receiver_data,
    receiver_model_text,
    robot_data,
    robot_model_text,
)
from derive.apps.simulate import simulate_linear
from derive.apps.verify import nonlinear_scenario
from derive.cli import main
from derive.errors import ModelError
from derive.fitting import fit, fitted_text, free_text, kernel
from derive.model import LinearModel, NonlinearModel
from derive.modelfile import load_model_file, loads_model
from derive.reference.likelihood import innovations_loglik


def peer():
    """derive.apps.fit_peer, or the test skipped where statsmodels is not installed."""
    return pytest.importorskip("derive.apps.fit_peer", exc_type=ImportError)

CV = free_text(catalog.read_text("cv"), ["sq2", "sr2"], positive=["sq2", "sr2"])


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - b) / np.abs(b)))


@pytest.fixture(scope="module")
def cv():
    """cv with sq2 and sr2 free and positive, two simulated tracks at (0.05, 0.5)."""
    model = loads_model(CV)
    num = model.at_values({"sq2": 0.05, "sr2": 0.5}).numeric()
    tracks = [simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 300, seed).zs
              for seed in (3, 4)]
    tracks[1][[10, 11, 50]] = np.nan
    return model, tracks, kernel(model, tracks)


def test_the_robot_estimates_equal_statsmodels_mle():
    pytest.importorskip("pykalman")
    model, data = loads_model(robot_model_text()), robot_data()
    ours = fit(model, data, progress=False)
    theirs = peer().statsmodels_fit(model, data, method="bfgs", gtol=1e-8, maxiter=500)
    assert relative(ours.estimates, theirs.estimates) <= 1e-6
    assert abs(ours.loglik - theirs.loglik) <= 1e-9 * abs(theirs.loglik)
    assert np.all(np.isfinite(ours.standard_errors)) and np.all(ours.standard_errors > 0)


def test_the_moving_receiver_estimates_equal_statsmodels_mle():
    """statsmodels' own score at derive's estimate, one Newton step through derive's
    observed information: statsmodels' MLE is within that step (<= 1e-6 relative), and
    its log-likelihood there equals derive's."""
    pytest.importorskip("gnss_benchmark")
    model, data = loads_model(receiver_model_text()), receiver_data()
    ours = fit(model, data, progress=False)
    score = peer().statsmodels_score(model, data, ours.estimates)
    step = np.linalg.solve(ours.information, score)
    assert np.max(np.abs(step / ours.estimates)) <= 1e-6
    theirs = peer().peer_model(model, data).loglike(ours.estimates)
    assert abs(ours.loglik - theirs) <= 1e-9 * abs(theirs)
    assert np.all(np.linalg.eigvalsh(ours.information) > 0)


def test_the_loglik_and_gradient_equal_statsmodels_loglike_and_score(cv):
    model, tracks, generated = cv
    theta = np.array([0.04, 0.6])
    _, _, lls, dlls = generated.c.run(tracks[1], np.zeros(2), np.zeros((2, 2)), theta)
    assert abs(np.sum(lls) - peer().peer_model(model, tracks[1]).loglike(theta)) <= \
        1e-12 * abs(np.sum(lls))
    score = peer().statsmodels_score(model, tracks[1], theta)
    assert relative(np.sum(dlls, axis=0), score) <= 1e-6


def test_a_fleet_sums_its_tracks_and_fits_one_parameter_set(cv, capsys):
    """Two tracks (one with missing measurements), one parameter set; the progress line
    (asked for: stderr is no terminal here) names each iteration's log-likelihood."""
    model, tracks, generated = cv
    both = fit(model, tracks, progress=True, generated=generated)
    err = capsys.readouterr().err
    assert f"derive fit: iteration {both.iterations}, log-likelihood " in err
    assert err.count("\r") == both.iterations and err.endswith("\n")
    ones = [fit(model, [t], progress=False, generated=generated, start=both.values(),
                gtol=1e12, polish=0) for t in tracks]  # at both's estimate: no step taken
    assert abs(both.loglik - sum(r.loglik for r in ones)) <= 1e-12 * abs(both.loglik)
    assert np.allclose(both.gradient, sum(r.gradient for r in ones), rtol=0,
                       atol=1e-9 * np.max(np.abs(ones[0].gradient)))
    assert np.max(np.abs(both.gradient * both.estimates)) <= 1e-6 * abs(both.loglik)


def test_derive_fit_writes_a_model_file_derive_generate_takes(cv, tmp_path, capsys):
    model, tracks, _ = cv
    data = tmp_path / "track.csv"
    np.savetxt(data, tracks[1], delimiter=",", header="z")
    out = tmp_path / "fitted.toml"
    assert main(["fit", "cv", str(data), "--free", "sq2", "--free", "sr2", "--positive",
                 "sq2", "--positive", "sr2", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    fitted = load_model_file(out)
    assert not fitted.parameters  # nothing free: the fitted values are the model's
    direct = fit(loads_model(CV), tracks[1], progress=False)
    assert fitted.values["sq2"] == pytest.approx(direct.estimates[0], rel=1e-12)
    assert f"{direct.estimates[0]: .10g}" in printed
    assert loads_model(fitted_text(CV, direct.values())).values == fitted.values
    assert main(["generate", str(out), "--filter", "kf", "--out",
                 str(tmp_path / "gen")]) == 0
    assert (tmp_path / "gen" / "cv" / "kf.c").is_file()


@pytest.mark.parametrize("args, message", [
    (["--free", "sq2", "--free", "sr2", "--positive", "sq2", "--positive", "sr2", "COLS"],
     "2 columns, but model 'cv' takes 1"),
    (["--free", "sq2", "--free", "sr2", "--positive", "sq2", "--positive", "sr2", "INF"],
     "row 2 holds an infinite measurement"),
    (["--free", "sq2", "--free", "sx"], "unknown parameter 'sx'"),
    (["--free", "sq2", "--start", "sr2=1"], "unknown parameter 'sr2'"),
    ([], "model 'cv' has no free parameters"),
    (["--free", "sq2", "--free", "sr2", "--start", "sr2=-0.5"],
     "declare a domain for sq2, sr2"),
], ids=["column count", "infinite measurement", "unknown parameter", "unknown start",
        "nothing free", "driven outside"])
def test_bad_input_is_one_line_and_exit_2(cv, tmp_path, capsys, args, message):
    model, tracks, _ = cv
    data = tmp_path / "z.npy"
    values = tracks[0][:40].copy()
    if "COLS" in args:
        values = np.column_stack([values, values])
    if "INF" in args:
        values[2] = np.inf
    np.save(data, values)
    args = [a for a in args if a not in ("COLS", "INF")]
    out = tmp_path / "fitted.toml"
    assert main(["fit", "cv", str(data), *args, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_the_standard_errors_are_those_of_the_observed_information(cv):
    """The fit's forward-difference Hessian of log L against central differences of the
    exact gradient, Richardson-extrapolated: their standard errors agree to 1e-6."""
    model, tracks, generated = cv
    result = fit(model, tracks[0], progress=False, generated=generated)
    theta = result.estimates

    def gradient(t):
        return np.sum(generated.c.run(tracks[0], np.zeros(2), np.zeros((2, 2)), t)[3],
                      axis=0)

    def central(h):
        return np.column_stack([(gradient(theta + h * e) - gradient(theta - h * e))
                                / (2 * h * t) for t, e in zip(theta, np.diag(theta))])

    H = (4 * central(5e-5) - central(1e-4)) / 3
    se = np.sqrt(np.diag(np.linalg.inv(-(H + H.T) / 2)))
    assert relative(result.standard_errors, se) <= 1e-6


def test_a_nonlinear_model_is_fitted_by_its_ekf_and_refuses_missing_measurements():
    """The EKF's log-likelihood maximised (its Gaussian approximation): the NumPy reference
    EKF's log-likelihood is lower a little beside the estimate in each parameter; a NaN
    measurement is refused (the EKF's run does not skip one)."""
    g, r1 = sympy.symbols("g r1", positive=True)  # their domains: optimised as logs
    th, om = sympy.symbols("th om")
    model = NonlinearModel(
        "pendulum", ["th", "om"], ["s", "r"], f=[th + sympy.Symbol("dt") * om,
                                                 om - sympy.Symbol("dt") * g * sympy.sin(th)],
        h=["sin(th)", "th + om**2/4"], Q=[["q", 0], [0, "q"]], R=[[r1, 0], [0, "r2"]],
        values={"dt": 0.1, "q": 0.001, "r2": 0.04}, parameters=["g", "r1"],
        x0=[0.5, 0.0], P0=[[0.1, 0], [0, 0.1]], examples={"g": 9.0, "r1": 0.02})
    scenario = nonlinear_scenario(model.at_values({"g": 9.81, "r1": 0.01}), 150, 3)
    result = fit(model, scenario.zs, x0=scenario.x0, P0=scenario.P0, progress=False)

    def reference_loglik(theta):
        fns = model.at_values(dict(zip(result.names, theta))).numeric_functions()
        run = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"],
                            scenario.x0, scenario.P0, scenario.zs, skip_nan=False)
        return np.sum(innovations_loglik(run.innovations, run.innovation_covariances))

    at = reference_loglik(result.estimates)
    assert abs(at - result.loglik) <= 1e-9 * abs(at)
    for e in np.diag(result.estimates * 1e-3):
        assert reference_loglik(result.estimates + e) < at
        assert reference_loglik(result.estimates - e) < at
    gappy = scenario.zs.copy()
    gappy[4, 1] = np.nan
    with pytest.raises(ModelError, match="row 4 holds a missing"):
        fit(model, gappy, progress=False)


def test_an_input_column_must_be_finite():
    """A model with inputs takes its inputs' columns after the measurements'; a NaN input
    is refused naming its row (an input is never missing), before any generation."""
    model = LinearModel("cart", ["s"], ["z"], F=[[1]], H=[[1]], Q=[["q"]], R=[[1]],
                        B=[[1]], inputs=["a"], parameters=["q"], examples={"q": 0.1})
    data = np.ones((5, 2))
    data[3, 1] = np.nan
    with pytest.raises(ModelError, match="row 3 holds a non-finite input"):
        fit(model, data, progress=False)
    with pytest.raises(ModelError, match="1 columns, but model 'cart' takes 2"):
        fit(model, data[:, :1], progress=False)


def test_a_missing_optional_package_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    """--bench without statsmodels, --anchor robot without pykalman: one line naming the
    package, before any work."""
    for name in ("statsmodels", "statsmodels.tsa.statespace.mlemodel", "pykalman",
                 "pykalman.datasets"):
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.delitem(sys.modules, "derive.apps.fit_peer", raising=False)
    monkeypatch.setattr(fit_anchors, "_robot", fit_anchors._robot.__wrapped__)
    data = tmp_path / "z.npy"
    np.save(data, np.zeros((5, 1)))
    assert main(["fit", "cv", str(data), "--free", "sq2", "--bench", "--no-progress"]) == 2
    assert capsys.readouterr().err == ("derive: error: --bench needs the package statsmodels "
                                       "(pip install statsmodels)\n")
    assert main(["fit", "--anchor", "robot"]) == 2
    assert capsys.readouterr().err == ("derive: error: --anchor robot needs the package "
                                       "pykalman (pip install pykalman)\n")
