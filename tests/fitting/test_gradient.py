"""The option ``gradient``: run stores each step's exact d ll / d p beside ll, by the
sensitivity recursion (derive.sensitivity: dx, dP carried, entered as zero).

Checked against central differences of the generated log-likelihood itself (Richardson's
extrapolation of two steps, error O(h^4)), elementwise relative to the gradient's largest
entry, <= 1e-6: on catalog models with parameters freed (noise variances; the time step,
which enters F, G, Q and H) with missing measurements, in Python and C, and on
Hypothesis-generated models (free entries of F, H, Q and R); and by `derive verify`. Its
step is counted as every step is (tests/fitting/test_loglik.py, test_the_loglik_step_counts_agree).
"""

import numpy as np
import pytest
import sympy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import catalog
from derive.apps.simulate import simulate_linear
from derive.apps.verify import verify_modules
from derive.filters import derive_unit
from derive.fitting import free_text
from derive.model import LinearModel, NonlinearModel
from derive.modelfile import loads_model
from derive.pipeline import load_generated
from derive.sensitivity import support

STEPS = 60
TOLERANCE = 1e-6


def freed(name: str, names) -> LinearModel:
    """Catalog model ``name`` with its valued parameters ``names`` free (values: examples)."""
    return loads_model(free_text(catalog.path(name).read_text(), names))


def measurements(model, theta, seed=2, steps=STEPS):
    """``steps`` simulated measurements of ``model`` at ``theta``, a few missing."""
    num = model.numeric(dict(zip([p.name for p in model.parameters], theta)))
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs
    zs[[3, 17, 18]] = np.nan
    return zs


def central(run, theta):
    """d sum(ll) / d theta by central differences, Richardson-extrapolated."""
    out = []
    for j in range(len(theta)):
        def diff(h, j=j):
            e = np.zeros(len(theta))
            e[j] = h
            return (np.sum(run(theta + e)[2]) - np.sum(run(theta - e)[2])) / (2 * h)
        h = 1e-3 * abs(theta[j])
        out.append((4 * diff(h / 2) - diff(h)) / 3)
    return np.array(out)


def assert_gradient(module, zs, theta, x0, P0):
    def run(t):
        return module.run(zs, x0, P0, t)

    xs, Ps, lls, dlls = run(theta)
    assert dlls.shape == (len(zs), len(theta))
    numeric = central(run, theta)
    exact = np.sum(dlls, axis=0)
    assert np.max(np.abs(exact - numeric)) <= TOLERANCE * np.max(np.abs(exact))
    return xs, lls


@pytest.fixture(scope="module")
def cv():
    model = freed("cv", ["sq2", "sr2"])
    return model, load_generated(model, "kf", {"gradient": True, "missing": True})


def test_the_gradient_of_cv_equals_central_differences_in_python_and_c(cv):
    model, generated = cv
    theta = np.array([0.03, 0.4])
    zs = measurements(model, theta)
    x0, P0 = np.zeros(2), np.eye(2)
    plain = load_generated(model.at_values({"sq2": 0.03, "sr2": 0.4}), "kf",
                           {"loglik": True, "missing": True}, "python").python
    xp, _, llp = plain.run(zs, x0, P0)
    for module in (generated.python, generated.c):
        xs, lls = assert_gradient(module, zs, theta, x0, P0)
        np.testing.assert_allclose(xs, xp, rtol=1e-12, atol=1e-12 * np.max(np.abs(xp)))
        np.testing.assert_allclose(lls, llp, rtol=1e-12, atol=1e-12)


def test_the_gradient_through_F_G_H_and_Q_by_the_time_step():
    """gsm2d_b: F = [[1, dt], [0, 1]], G = [dt/2, 1], H = [1, dt]; dt free with the noises."""
    model = freed("gsm2d_b", ["dt", "sq2", "sr2"])
    theta = np.array([0.7, 0.02, 0.3])
    module = load_generated(model, "kf", {"gradient": True, "missing": True},
                            "python").python
    assert_gradient(module, measurements(model, theta), theta, np.array([1.0, -0.5]),
                    np.diag([2.0, 0.5]))


def test_the_sensitivities_exploit_the_zeros():
    """gps_static's three random walks: each noise variance moves only its own axis, so
    dP/d upsilon is non-zero in P[0, 0] alone and the gradient step computes nothing for
    the other axes' entries."""
    text = catalog.path("gps_static").read_text().replace(
        'P0 = [["sx2", 0, 0], [0, "sy2", 0], [0, 0, "sz2"]]',
        "P0 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]")
    model = loads_model(free_text(text, ["upsilon", "tau", "zeta", "sx2", "sy2", "sz2"]))
    step = derive_unit(model, "kf", {"loglik": True}).programs["step"]
    sx, sP = support(step, 3, 6)
    assert sP == [{0}, {4}, {8}, {0}, {4}, {8}] and sx == [{0}, {1}, {2}, {0}, {1}, {2}]


@st.composite
def small_models(draw):
    """1-2 states, 1-2 measurements; a free parameter in F, one in H, Q's and R's
    diagonals free (positive), the rest random numbers."""
    n, m = draw(st.integers(1, 2)), draw(st.integers(1, 2))
    a, b, q, r = sympy.symbols("a b q r")
    num = st.floats(-0.9, 0.9, allow_nan=False).map(lambda v: round(v, 2))
    F = sympy.Matrix(n, n, lambda i, j: draw(num))
    F[draw(st.integers(0, n - 1)), draw(st.integers(0, n - 1))] = a
    H = sympy.Matrix(m, n, lambda i, j: draw(num))
    H[draw(st.integers(0, m - 1)), draw(st.integers(0, n - 1))] = b
    Q = sympy.diag(*[q * (i + 1) for i in range(n)])
    R = sympy.diag(*[r + i for i in range(m)])
    model = LinearModel("hyp", [f"s{i}" for i in range(n)], [f"y{i}" for i in range(m)],
                        F=F, H=H, Q=Q, R=R, parameters=["a", "b", "q", "r"])
    theta = np.array([draw(st.floats(0.3, 0.95)), draw(st.floats(0.5, 2.0)),
                      draw(st.floats(0.05, 1.0)), draw(st.floats(0.1, 1.0))])
    return model, theta


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_models(), st.integers(0, 1000))
def test_the_gradient_of_generated_models_equals_central_differences(case, seed):
    model, theta = case
    module = load_generated(model, "kf", {"gradient": True, "missing": True},
                            "python").python
    rng = np.random.default_rng(seed)
    zs = rng.normal(size=(40, model.m))
    zs[5] = np.nan
    assert_gradient(module, zs, theta, np.zeros(model.n), np.eye(model.n))


def test_the_ekf_gradient_through_f_h_and_the_noises_equals_central_differences():
    """A pendulum with g (in f and so in the Jacobian F), q and r1 free: the EKF's
    dll through f, h, their Jacobians and Q, R (Python; the C prints the same program)."""
    model = NonlinearModel(
        "pendulum", ["th", "om"], ["s", "r"], f=["th + dt*om", "om - dt*g*sin(th)"],
        h=["sin(th)", "th + om**2/4"], Q=[["q", 0], [0, "q"]], R=[["r1", 0], [0, "r2"]],
        values={"dt": 0.1, "r2": 0.04}, parameters=["g", "q", "r1"], x0=[0.5, 0.0],
        P0=[[0.1, 0], [0, 0.1]])
    module = load_generated(model, "ekf", {"gradient": True}, "python").python
    zs = np.random.default_rng(0).normal(size=(STEPS, 2)) * 0.1 + [0.4, 0.5]
    assert_gradient(module, zs, np.array([9.81, 0.001, 0.01]), np.array([0.5, 0.0]),
                    np.eye(2) * 0.1)


def test_the_gradient_is_refused_where_it_is_not_derived(tmp_path, capsys):
    from derive.cli import main

    assert main(["generate", "mpt3d_a", "--filter", "udkf", "--gradient", "--out",
                 str(tmp_path)]) == 2
    assert "gradient" in capsys.readouterr().err
    assert main(["generate", "cv", "--filter", "kf", "--gradient", "--out",
                 str(tmp_path)]) == 2
    assert "no free parameters" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_derive_verify_checks_dlls_against_the_references_differences(cv):
    """verify_modules with the option gradient: the summed dlls against central
    differences of the NumPy reference's log-likelihood at the parameters' examples moved
    (a line ``python dll``); dlls off by 1e-4 of their size fail."""
    model, generated = cv

    class Off:  # run's dlls moved by 1e-4 of their size, the rest untouched
        def run(self, *args, **named):
            xs, Ps, lls, dlls = generated.python.run(*args, **named)
            return xs, Ps, lls, dlls * (1 + 1e-4)

    options = {"gradient": True, "missing": True}
    good = verify_modules(model, "kf", {"python": generated.python}, 200, 7, options)
    bad = verify_modules(model, "kf", {"python": Off()}, 200, 7, options)
    assert [v.lang for v in good] == ["python dll", "python"]
    assert all(v.passed for v in good) and good[0].error <= 1e-8
    assert not bad[0].passed and bad[1].passed
