"""Generated EKF and UKF (derive.filters.ekf, .ukf): against the NumPy reference, FilterPy
and the scalar-update stand-ins of derive.apps.gnss; Cholesky failures; exact op counts."""

import numpy as np
import pytest
import sympy
from _backend_kf import unit_fields
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import NonlinearModel, catalog
from derive.apps.gnss import ScalarEkf, ScalarUkf, drive
from derive.apps.gnss.generated import generated_filters
from derive.apps.gnss.measurements import Epoch
from derive.apps.gnss.run import FilterSettings, numpy_filters
from derive.apps.simulate import gnss_scenario
from derive.apps.verify import (
    FLOOR_MARGIN,
    NONLINEAR_TOLERANCE,
    generated_run,
    nonlinear_reference,
    nonlinear_scenario,
    relative_error,
    rounding_floor,
    verify_filter,
)
from derive.emit.render import render_files, render_unit
from derive.errors import FilterError, NumericalError
from derive.filters import derive_unit
from derive.filters.nonlinear import scalar_measurement
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.pipeline import load_units
from derive.program import ProgramError
from derive.reference.nonlinear import sigma_points as reference_sigma_points
from derive.reference.nonlinear import sigma_weights
from derive.runs.unit import Unit

GNSS = catalog.load("gnss_pseudorange")
STEPS = 500


SCALED = {"alpha": 0.5, "beta": 2.0, "kappa": 0.0}


@pytest.fixture(scope="module")
def units():
    """{(filter, options key): Unit} for the GNSS model, derived once."""
    return {("ekf", "paper"): derive_unit(GNSS, "ekf"), ("ukf", "paper"): derive_unit(GNSS, "ukf"),
            ("ukf", "scaled"): derive_unit(GNSS, "ukf", SCALED)}


@pytest.fixture(scope="module")
def generated(units, tmp_path_factory):
    """{(filter, options key): {"python": module, "c": FilterModule}} for the GNSS model."""
    tmp = tmp_path_factory.mktemp("ekf_ukf")
    out = {}
    for (name, key), unit in units.items():
        (loaded,) = load_units([unit], "all", tmp / key)
        out[name, key] = {"python": loaded.python, "c": loaded.c}
    return out


@pytest.fixture(scope="module")
def scenario():
    return nonlinear_scenario(GNSS, STEPS, seed=11)


# -- against the NumPy reference --------------------------------------------------------


@pytest.mark.parametrize("name", ["ekf", "ukf"])
@pytest.mark.parametrize("lang", ["python", "c"])
def test_generated_equals_reference_over_500_steps(generated, scenario, name, lang):
    xs_ref, Ps_ref = nonlinear_reference(GNSS, name, scenario, {})
    xs, Ps = generated_run(generated[name, "paper"][lang], name, scenario.zs, GNSS, lang,
                           scenario)
    assert xs.shape == (STEPS, 4) and Ps.shape == (STEPS, 4, 4)
    assert relative_error(xs, xs_ref) <= NONLINEAR_TOLERANCE
    floor = rounding_floor(GNSS, name, scenario, {}, xs_ref, Ps_ref)
    if name == "ekf":
        assert floor < 1e-13
        assert relative_error(Ps, Ps_ref) <= NONLINEAR_TOLERANCE
    else:
        # one rounding of h moves the reference's P by ~3e-10 (see derive.apps.verify)
        assert 1e-11 < floor < 1e-9
        assert relative_error(Ps, Ps_ref) <= FLOOR_MARGIN * floor
    # the filter converges: about 1 m after 500 s from a 10 m start
    assert np.max(np.abs(xs[-1] - scenario.truth[-1])) < 5.0


def test_scaled_weights_equal_reference(generated, scenario):
    options = SCALED
    xs_ref, Ps_ref = nonlinear_reference(GNSS, "ukf", scenario, options)
    floor = rounding_floor(GNSS, "ukf", scenario, options, xs_ref, Ps_ref)
    for lang in ("python", "c"):
        xs, Ps = generated_run(generated["ukf", "scaled"][lang], "ukf", scenario.zs, GNSS,
                               lang, scenario)
        assert relative_error(xs, xs_ref) <= NONLINEAR_TOLERANCE
        assert relative_error(Ps, Ps_ref) <= max(NONLINEAR_TOLERANCE, FLOOR_MARGIN * floor)


def test_verify_command_path_passes():
    results = verify_filter(GNSS, "ekf", steps=200)
    assert [r.lang for r in results] == ["python", "c"]
    assert all(r.passed and r.tolerance == NONLINEAR_TOLERANCE for r in results)


# -- a model with nonlinear f and no inputs: the general predict paths -------------------

PENDULUM = NonlinearModel(
    "pendulum", ["th", "om"], ["s", "r"],
    f=["th + dt*om", "om - dt*g*sin(th)"],
    h=["sin(th)", "th + om**2/4"],
    Q=[["q", 0], [0, "q"]], R=[["r1", 0], [0, "r2"]],
    values={"dt": 0.1, "g": 9.81, "q": 0.001, "r1": 0.01, "r2": 0.04},
    x0=[0.5, 0.0], P0=[[0.1, 0], [0, 0.1]])


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_nonlinear_dynamics_equal_reference(name, tmp_path):
    results = verify_filter(PENDULUM, name, steps=STEPS, workdir=tmp_path)
    for r in results:
        assert r.passed and r.tolerance == NONLINEAR_TOLERANCE, r.line()
    unit = derive_unit(PENDULUM, name)
    assert set(unit.programs) == {"step", "predict"}      # rows differ: no update1
    assert any("no update1" in f for f in unit.facts)
    assert unit.step_inputs == ("z",)


def test_ukf_of_nonlinear_dynamics_draws_sigma_points_in_predict():
    predict = derive_unit(PENDULUM, "ukf").programs["predict"]
    assert count(predict, "python").sqrt == 2            # Cholesky of P: one root per pivot
    assert predict.has_checks


def test_ukf_of_identity_dynamics_predicts_p_plus_q(units):
    assert count(units["ukf", "paper"].programs["predict"], "python").flops == 4   # P + Q


# -- against FilterPy ---------------------------------------------------------------------


def _filterpy(name, sc, alpha=1.0, beta=0.0, kappa=-1.0):
    from filterpy.kalman import (
        ExtendedKalmanFilter,
        MerweScaledSigmaPoints,
        UnscentedKalmanFilter,
    )

    fns = GNSS.numeric_functions()
    sats = sc.us.reshape(len(sc.zs), 4, 3)
    if name == "ekf":
        kf = ExtendedKalmanFilter(4, 4)
    else:
        points = MerweScaledSigmaPoints(4, alpha=alpha, beta=beta, kappa=kappa)
        kf = UnscentedKalmanFilter(4, 4, 1.0, lambda x, u: fns["h"](x, u), lambda x, dt: x,
                                   points)
    kf.x, kf.P, kf.Q, kf.R = sc.x0.copy(), sc.P0.copy(), fns["Q"], fns["R"]
    xs, Ps = [], []
    for z, u in zip(sc.zs, sats):
        kf.predict()
        if name == "ekf":
            kf.update(z, lambda x, u: fns["H"](x, u.ravel()), lambda x, u: fns["h"](x, u.ravel()),
                      args=(u,), hx_args=(u,))
        else:
            kf.update(z, u=u.ravel())
        xs.append(np.array(kf.x).ravel())
        Ps.append(np.array(kf.P))
    return np.array(xs), np.array(Ps)


@pytest.mark.parametrize("name, key", [("ekf", "paper"), ("ukf", "paper"), ("ukf", "scaled")])
def test_generated_equals_filterpy(generated, scenario, name, key):
    weights = SCALED if key == "scaled" else {}
    xs_fp, Ps_fp = _filterpy(name, scenario, **weights)
    for lang in ("python", "c"):
        xs, Ps = generated_run(generated[name, key][lang], name, scenario.zs, GNSS, lang,
                               scenario)
        assert np.max(np.abs(xs - xs_fp)) <= 1e-6           # metres
        assert np.max(np.abs(Ps - Ps_fp)) <= 1e-6           # m² (FilterPy: Joseph form)


# -- the Cholesky of the UKF fails loudly --------------------------------------------------


INDEFINITE = np.diag([4.0, 4.0, -1.0, 4.0])


def _step_inputs(P):
    sc = gnss_scenario(1, seed=2)
    return sc.x0, np.ravel(P), sc.pseudoranges[0], sc.satellites[0].ravel()


def test_ukf_cholesky_failure_python_raises(generated):
    module = generated["ukf", "paper"]["python"]
    with pytest.raises(NumericalError, match="pivot 2 of its Cholesky"):
        module.step(*_step_inputs(INDEFINITE))
    with pytest.raises(NumericalError, match="not positive definite"):
        module.update1(np.zeros(4) + 1e6, np.ravel(INDEFINITE), [2e7], [1e7, 1e7, 1e7])
    nan = np.full((4, 4), np.nan)
    with pytest.raises(NumericalError):
        module.step(*_step_inputs(nan))


def test_ukf_cholesky_failure_c_status(generated):
    module = generated["ukf", "paper"]["c"]
    ffi, lib = module.ffi, module.lib
    x, P, z, u = (np.ascontiguousarray(a, dtype=float) for a in _step_inputs(INDEFINITE))
    x_new, P_new = np.zeros(4), np.zeros(16)
    status = lib.gnss_pseudorange_ukf_step(*(ffi.from_buffer("double[]", a)
                                             for a in (x, P, z, u, x_new, P_new)))
    assert status == 3                    # the third check: pivot 2 of the Cholesky
    assert "pivot 2 of its Cholesky" in " ".join(module.statuses[status])
    with pytest.raises(NumericalError, match="status 3"):
        module.step(x, P, z, u)
    # the run stops at the failing step with the same status
    zs, us = np.tile(z, (3, 1)), np.tile(u, (3, 1))
    with pytest.raises(NumericalError, match="status 3"):
        module.run(zs, us, x, INDEFINITE)
    ok = module.step(x, np.ravel(np.diag([4.0, 4.0, 1.0, 4.0])), z, u)
    assert np.all(np.isfinite(ok[0]))


def test_reference_agrees_that_the_covariance_is_indefinite(scenario):
    from derive.reference import ukf

    fns = GNSS.numeric_functions()
    with pytest.raises(NumericalError):
        ukf(None, fns["h"], fns["Q"] * 0, fns["R"], scenario.x0, INDEFINITE, scenario.zs[:1],
            inputs=list(scenario.us[:1]))


def test_ukf_options_are_checked():
    with pytest.raises(FilterError, match="alpha"):
        derive_unit(GNSS, "ukf", {"alpha": 0})
    with pytest.raises(FilterError, match="n \\+ kappa"):
        derive_unit(GNSS, "ukf", {"kappa": -4})
    with pytest.raises(FilterError, match="real number"):
        derive_unit(GNSS, "ukf", {"beta": "two"})


# -- one square root per satellite, exact counts -------------------------------------------


def test_ekf_step_has_one_sqrt_per_satellite(units):
    unit = units["ekf", "paper"]
    for lang in ("python", "c"):
        assert count(unit.programs["step"], lang).sqrt == GNSS.m
        assert count(unit.programs["update1"], lang).sqrt == 1
    c = render_unit(unit, "c")["ekf.c"]
    body = c.split("gnss_pseudorange_ekf_step_body(", 2)[1].split("\n}\n")[0]
    assert body.count("sqrt(") == GNSS.m == c.count("sqrt(") - 1  # step once; update1: 1
    assert count_c_function(c, "gnss_pseudorange_ekf_step") == count(unit.programs["step"], "c")


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_counting_float_reproduces_the_static_count(units, generated, name):
    unit = units[name, "paper"]
    module = generated[name, "paper"]["python"]
    x, P, z, u = _step_inputs(np.diag([4.0, 4.0, 9.0, 4.0]))
    for program, args in (("step", (x, P, z, u)), ("predict", (x, P)),
                          ("update1", (x, P, z[:1], u[:3]))):
        counter = OpCounter()
        getattr(module, program)(*(counter.wrap(np.ravel(a)) for a in args))
        assert counter.snapshot() == count(unit.programs[program], "python"), program
    c = render_unit(unit, "c")[f"{name}.c"]
    for program in ("step", "predict", "update1"):
        assert count_c_function(c, f"gnss_pseudorange_{name}_{program}") == \
            count(unit.programs[program], "c")


def test_unit_interface(units):
    unit = units["ekf", "paper"]
    assert unit.step_inputs == ("z", "u")
    assert [p.name for p in unit.programs["step"].inputs] == ["x", "P", "z", "u"]
    assert unit.programs["step"].port("u").shape == (12,)
    assert [p.name for p in unit.programs["update1"].inputs] == ["x", "P", "z", "u"]
    assert unit.programs["update1"].port("u").shape == (3,)
    with pytest.raises(ProgramError, match="no program 'update1'"):
        Unit(model="m", filter="kf", **unit_fields("kf"), n=4, m=4,
             programs={"step": unit.programs["step"], "update1": unit.programs["update1"]},
             step_inputs=("z", "u"))


def test_scalar_measurement_needs_interchangeable_rows():
    meas, why = scalar_measurement(GNSS)
    assert meas is not None and why == "" and [s.name for s in meas.inputs] == [
        "xs1", "ys1", "zs1"]
    model = NonlinearModel("two", ["x", "y", "z", "b"], ["D1", "D2"], f=["x", "y", "z", "b"],
                           h=["sqrt((a1 - x)**2 + y**2 + z**2) + b", "(a2 - x) + b"],
                           Q=np.eye(4).tolist(), R=[[1, 0], [0, 1]], inputs=["a1", "a2"])
    assert scalar_measurement(model) == (None, "measurement 'D2' is not 'D1' of its own inputs")


# -- sequential scalar updates against derive.apps.gnss.scalar_updates ---------------------------


def _catalog_pairs(generated, lang):
    """(predict, update1) of the catalog model's generated code (Q = 0.01 I, σ = 10 m)."""
    def pair(module):
        def predict(x, P):
            x_new, P_new = module.predict(x, np.ravel(P))
            return np.asarray(x_new, float), np.reshape(np.asarray(P_new, float), (4, 4))

        def update1(x, P, rho, sat):
            out = module.update1(x, np.ravel(P), [rho], np.ravel(sat))
            x_new, P_new, nu, s = (np.asarray(a, float) for a in out)
            return x_new, P_new.reshape(4, 4), float(nu[0]), float(s[0])
        return predict, update1
    return {"EKF": pair(generated["ekf", "paper"][lang]),
            "UKF": pair(generated["ukf", "paper"][lang])}


def _varying_epochs(steps=120, seed=5):
    """Twelve moving satellites; each epoch keeps a random 6 to 12 of them."""
    elev = (80.0, 35.0, 45.0, 55.0, 20.0, 65.0, 30.0, 15.0, 50.0, 25.0, 70.0, 40.0)
    azim = tuple((37.0 * i + 10.0) % 360.0 for i in range(12))
    sc = gnss_scenario(steps, seed, elevations_deg=elev, azimuths_deg=azim, moving=True)
    rng = np.random.default_rng(seed)
    names = tuple(f"G{i + 1:02d}" for i in range(12))
    epochs = []
    for k in range(steps):
        keep = np.sort(rng.permutation(12)[: rng.integers(6, 13)])
        zeros = np.zeros(len(keep))
        epochs.append(Epoch(float(k + 1), tuple(names[i] for i in keep), sc.satellites[k][keep],
                            sc.pseudoranges[k][keep], zeros, zeros, zeros))
    return sc, epochs


@pytest.mark.parametrize("lang", ["python", "c"])
def test_sequential_updates_equal_the_numpy_stand_ins(generated, lang):
    sc, epochs = _varying_epochs()
    counts = {len(e.prns) for e in epochs}
    assert min(counts) == 6 and max(counts) == 12
    ours = _catalog_pairs(generated, lang)
    stand_ins = {"EKF": ScalarEkf(0.01 * np.eye(4), 10.0), "UKF": ScalarUkf(0.01 * np.eye(4), 10.0)}
    for name in ("EKF", "UKF"):
        mine = drive(*ours[name], epochs, sc.x0, sc.P0, 10.0)
        ref = drive(stand_ins[name].predict, stand_ins[name].update1, epochs, sc.x0, sc.P0, 10.0)
        assert np.max(np.abs(mine.states - ref.states)) <= 1e-6
        assert relative_error(mine.covariances, ref.covariances) <= 1e-8
        both = np.isfinite(ref.innovations)
        assert np.array_equal(both, np.isfinite(mine.innovations))
        assert np.max(np.abs(mine.normalized_innovations[both]
                             - ref.normalized_innovations[both])) <= 1e-8
    assert np.max(np.abs(mine.states[-1] - sc.truth[-1])) < 5.0


@pytest.fixture(scope="module")
def parametrised():
    """derive.apps.gnss.generated: Q and σ as runtime parameters, both languages."""
    s = FilterSettings(sigma=4.0, q_position=1e-4, q_clock=0.5)
    return s, {lang: generated_filters(s, lang) for lang in ("python", "c")}


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1))
def test_parametrised_update1_equals_stand_ins(parametrised, seed):
    s, gen = parametrised
    rng = np.random.default_rng(seed)
    x = np.append(rng.uniform(-6.4e6, 6.4e6, 3), rng.normal(0, 1e3))
    sat = x[:3] + rng.normal(size=3) / 1e-7 * 2.2
    A = rng.normal(size=(4, 4)) * rng.uniform(0.1, 30)
    P = A @ A.T + 0.1 * np.eye(4)
    rho = np.linalg.norm(sat - x[:3]) + x[3] + rng.normal(0, 5)
    ref = numpy_filters(s)
    for name in ("EKF", "UKF"):
        xr, Pr = ref[name][0](x, P)
        r = ref[name][1](xr, Pr, rho, sat)
        for lang in ("python", "c"):
            xp, Pp = gen[lang][name][0](x, P)
            np.testing.assert_allclose(Pp, Pr, rtol=0, atol=1e-15 * np.abs(Pr).max())
            g = gen[lang][name][1](xp, Pp, rho, sat)
            assert np.max(np.abs(g.x - r.x)) <= 1e-6
            assert np.max(np.abs(g.P - r.P)) <= 1e-8 * np.abs(r.P).max()
            assert abs(g.innovation - r.innovation) <= 1e-6
            floor = _stand_in_variance_floor(s, xr, Pr, sat) if name == "UKF" else 0.0
            assert abs(g.variance - r.variance) <= 1e-10 * r.variance + floor


def _stand_in_variance_floor(s, x, P, sat) -> float:
    """How far the NumPy stand-in's UKF variance may be from the exact one: it forms each
    spread h(X_i) - y_hat from two values of size |h| (ranges up to 4e7 m), each within
    u |h| of exact, so Σ Wc dy² may be off by 2 Σ |Wc_i| |dy_i| 2 u max|h|. The generated
    UKF computes the spreads in difference form, without that cancellation (measured
    against an exact mpmath evaluation: 1e-17 where the stand-in is 6e-10 off)."""
    c, Wm, Wc = sigma_weights(4, s.alpha, s.beta, -1.0 if s.kappa is None else s.kappa)
    X = reference_sigma_points(x, P, c, 0)
    Y = np.linalg.norm(np.asarray(sat) - X[:, :3], axis=1) + X[:, 3]
    dy = Y - Wm @ Y
    return 4 * np.finfo(float).eps / 2 * np.abs(Y).max() * float(np.abs(Wc) @ np.abs(dy))


def test_generated_filters_drive_like_the_stand_ins(parametrised):
    s, gen = parametrised
    sc, epochs = _varying_epochs(60, seed=9)
    ref = numpy_filters(s)
    for name in ("EKF", "UKF"):
        a = drive(*gen["c"][name], epochs, sc.x0, sc.P0, s.sigma)
        b = drive(*ref[name], epochs, sc.x0, sc.P0, s.sigma)
        assert np.max(np.abs(a.states - b.states)) <= 1e-6


def test_model_is_regenerated_deterministically(units):
    a = render_filter(GNSS, "ukf", "all", {})
    b = render_filter(GNSS, "ukf", "all", {})
    assert a == b
    assert a["ukf.c"].split("*/", 1)[1] == render_files(units["ukf", "paper"])["ukf.c"].split(
        "*/", 1)[1]
    assert "n + lambda = 3" in a["ukf.c"] and "Wm0 = -1/3" in a["ukf.py"]


def _roots(expr):
    return [a for a in sympy.preorder_traversal(expr)
            if a.is_Pow and abs(a.exp) == sympy.Rational(1, 2)]


def test_jacobian_entries_are_shared_symbols():
    """H is built from h's shared subexpressions: one root per row, none in H itself."""
    from derive.filters.nonlinear import linearise

    lin = linearise(GNSS.subs(GNSS.h), GNSS.state_symbols)
    assert sum(len(_roots(e)) for _, e in lin.shared) == GNSS.m
    assert not any(_roots(e) for e in list(lin.jacobian) + list(lin.values))
    values, jac = lin.expanded()
    assert (values - GNSS.subs(GNSS.h)).applyfunc(sympy.simplify) == sympy.zeros(4, 1)
    assert (jac - GNSS.subs(GNSS.H_jacobian)).applyfunc(sympy.simplify) == sympy.zeros(4, 4)
