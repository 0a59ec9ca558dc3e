"""Sequential scalar updates (option ``update``, ``Sensor.update``, a model file's
``[sensors.NAME] update``): a sensor with a diagonal R fused one measurement at a time,
compared with the batch NumPy reference (derive.reference.sensors, unchanged): states and
covariances, NIS, gating, statuses, counts, and the refusals."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from derive import LinearModel, NonlinearModel, Sensor
from derive.apps.ins import compare, flight, reference
from derive.apps.ins.run import AGREEMENT, generated_run
from derive.catalog import load as load_catalog
from derive.cli import main
from derive.errors import ModelError, ModelFileError, NumericalError, OptionError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.modelfile import loads_model
from derive.options import takers
from derive.pipeline import load_generated
from derive.reference import sensors as batch

SEQUENTIAL = {"update": "sequential"}
LINEAR_AGREEMENT = 1e-12
"""Generated sequential against the batch reference, linear double filters (relative)."""


def relative(got, expected) -> float:
    return float(np.max(np.abs(np.asarray(got) - expected)) / np.max(np.abs(expected)))


def two_sensor_model(rng, n: int, m1: int, m2: int) -> LinearModel:
    """A random stable linear model with two sensors (short decimals): ``a`` with a
    correlated constant R (decorrelated at generation), ``b`` with a diagonal R."""
    F = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.6) + np.eye(n)
    F *= 0.95 / max(1.0, np.max(np.abs(np.linalg.eigvals(F))))
    L = rng.normal(size=(n, n))
    Q = L @ L.T / n + 0.1 * np.eye(n)
    sensors = []
    for name, m in (("a", m1), ("b", m2)):
        H = rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.7)
        H[np.arange(m), rng.permutation(n)[:m]] = 1.0
        R = np.diag(np.round(rng.uniform(0.2, 2.0, m), 3))
        if name == "a":
            A = rng.normal(size=(m, m))
            R = np.round(A @ A.T / m, 3) + R
        sensors.append(Sensor(name, [f"{name}{i}" for i in range(m)],
                              H=np.round(H, 3).tolist(), R=R.tolist()))
    return LinearModel("seq", [f"x{i}" for i in range(n)], F=np.round(F, 3).tolist(),
                       Q=np.round((Q + Q.T) / 2, 3).tolist(), sensors=sensors,
                       x0=np.zeros(n).tolist(), P0=np.eye(n).tolist())


def spd(rng, n: int) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T + 0.5 * np.eye(n)


@settings(max_examples=12, deadline=None)
@given(n=st.integers(1, 5), m1=st.integers(1, 4), m2=st.integers(1, 3),
       seed=st.integers(0, 2**32 - 1))
def test_random_two_sensor_models_match_the_batch_reference(n, m1, m2, seed):
    rng = np.random.default_rng(seed)
    model = two_sensor_model(rng, n, min(m1, n), min(m2, n))
    generated = load_generated(model, "kf", SEQUENTIAL)
    num = {g.name: (np.array(g.H.tolist(), float), np.array(g.R.tolist(), float))
           for g in model.sensors}
    for name, (H, R) in num.items():  # one update from a random x and SPD P
        x, P = rng.normal(size=n), spd(rng, n)
        z = H @ x + rng.normal(size=H.shape[0])
        x_ref, P_ref, _, _ = batch.update(x, P, z, H @ x, H, R)
        for module in (generated.python, generated.c):
            x_new, P_new = (np.asarray(v, float) for v in
                            getattr(module, f"update_{name}")(x, P.ravel(), z))
            assert relative(x_new, x_ref) <= LINEAR_AGREEMENT
            assert relative(P_new.reshape(n, n), P_ref) <= LINEAR_AGREEMENT
    steps = 40  # a run with both sensors at their own rates (NaN rows: absent)
    zs = {}
    for k, (name, (H, _)) in enumerate(num.items()):
        z = rng.normal(size=(steps, H.shape[0]))
        z[np.arange(steps) % (k + 2) != 0] = np.nan
        zs[name] = z
    ref = reference_run(model, {}, zs)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs["a"], zs["b"], np.zeros(n), np.eye(n))
        assert relative(xs, ref.xs) <= LINEAR_AGREEMENT
        assert relative(Ps, ref.Ps) <= LINEAR_AGREEMENT


# -- gating: a 50-sigma GNSS outlier ----------------------------------------------------------

SIGMA_GNSS = 2.0
OUTLIER_STEP = 60


def car() -> LinearModel:
    dt = 0.1
    F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    return LinearModel(
        "car", ["x", "y", "vx", "vy"], F=F, Q=np.diag([1e-4, 1e-4, 1e-2, 1e-2]),
        sensors=[Sensor("gnss", ["e", "n"], H=[[1, 0, 0, 0], [0, 1, 0, 0]],
                        R=np.diag([SIGMA_GNSS**2, 1.5 * SIGMA_GNSS**2])),
                 Sensor("odo", ["ve", "vn"], H=[[0, 0, 1, 0], [0, 0, 0, 1]],
                        R=np.eye(2) * 0.01)],
        x0=[0, 0, 1, 0], P0=np.eye(4))


def car_data(steps=200):
    rng = np.random.default_rng(21)
    truth = np.c_[0.1 * np.arange(1, steps + 1), np.zeros(steps)]
    gnss = truth + SIGMA_GNSS * rng.normal(size=(steps, 2))
    gnss[np.arange(steps) % 10 != 0] = np.nan
    gnss[OUTLIER_STEP] = truth[OUTLIER_STEP] + 50 * SIGMA_GNSS
    odo = np.tile([1.0, 0.0], (steps, 1)) + 0.1 * rng.normal(size=(steps, 2))
    odo[np.arange(steps) % 2 != 0] = np.nan
    return {"gnss": gnss, "odo": odo}


@pytest.fixture(scope="module")
def gated_car():
    return load_generated(car(), "kf", {**SEQUENTIAL, "gate_sensors": "gnss=0.999"})


def test_the_outlier_is_rejected_with_the_gate_and_nis_is_the_batch_nis(gated_car):
    zs, x0, P0 = car_data(), np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    ref = reference_run(car(), {"gate_sensors": "gnss=0.999"}, zs, x0=x0, P0=P0)
    threshold = chi2.ppf(0.999, 2)
    fixes = ~np.isnan(zs["gnss"][:, 0])
    for module in (gated_car.python, gated_car.c):
        xs, Ps, nis, applied = module.run(zs["gnss"], zs["odo"], x0, P0)
        assert nis[OUTLIER_STEP] > threshold and applied[OUTLIER_STEP] == 0.0
        assert applied[fixes].sum() == fixes.sum() - 1  # only the outlier is rejected
        assert np.array_equal(np.isnan(nis), ~fixes)
        np.testing.assert_allclose(nis[fixes], ref.nis["gnss"][fixes], rtol=1e-12, atol=0)
        assert relative(xs, ref.xs) <= LINEAR_AGREEMENT
        assert relative(Ps, ref.Ps) <= LINEAR_AGREEMENT


def test_without_the_gate_the_outlier_is_applied(gated_car):
    zs, x0, P0 = car_data(), np.array([0.0, 0.0, 1.0, 0.0]), np.eye(4)
    plain = load_generated(car(), "kf", SEQUENTIAL)
    ref = reference_run(car(), {}, zs, x0=x0, P0=P0)
    assert ref.applied["gnss"][OUTLIER_STEP] == 1.0
    xs_plain, _ = plain.c.run(zs["gnss"], zs["odo"], x0, P0)
    xs_gated, *_ = gated_car.c.run(zs["gnss"], zs["odo"], x0, P0)
    assert relative(xs_plain, ref.xs) <= LINEAR_AGREEMENT
    assert xs_plain[OUTLIER_STEP, 0] - xs_gated[OUTLIER_STEP, 0] > 2 * SIGMA_GNSS


def test_a_rejected_update_returns_x_and_P_unchanged(gated_car):
    x, P = np.array([0.0, 0.0, 1.0, 0.0]), spd(np.random.default_rng(3), 4)
    S = P[:2, :2] + np.diag([SIGMA_GNSS**2, 1.5 * SIGMA_GNSS**2])
    for z in ([0.5, -0.3], [100.0, 0.0]):
        nu = np.array(z)
        expected = nu @ np.linalg.solve(S, nu)
        for module in (gated_car.python, gated_car.c):
            x_new, P_new, nis, applied = module.update_gnss(x, P.ravel(), z)
            assert nis[0] == pytest.approx(expected, rel=1e-12)
            assert applied[0] == float(expected <= chi2.ppf(0.999, 2))
            if not applied[0]:
                assert np.array_equal(np.asarray(x_new, float), x)
                assert np.array_equal(np.asarray(P_new, float), P)


def test_a_variance_not_positive_is_the_status_of_its_measurement(gated_car):
    x = np.zeros(4)
    P = np.diag([1.0, -10.0, 1.0, 1.0])  # s of the second GNSS measurement: -10 + 6 < 0
    described = [s for s in gated_car.c.interface.statuses if s.program == "update_gnss"]
    assert [s.message for s in described] == [
        f"S is not positive definite: the variance s of measurement {i} ({name}) of the "
        "sequential update is not positive" for i, name in enumerate(("e", "n"))]
    for module in (gated_car.python, gated_car.c):
        with pytest.raises(NumericalError, match=r"measurement 1 \(n\) of the sequential"):
            module.update_gnss(x, P.ravel(), [0.0, 0.0])


# -- counts ------------------------------------------------------------------------------------


@pytest.mark.parametrize("options", [SEQUENTIAL, {**SEQUENTIAL, "gate": 0.99}])
def test_counts_in_the_header_are_those_of_the_code(options):
    model = car()
    unit = derive_unit(model, "kf", options)
    files = render_filter(model, "kf", "all", options)
    scope: dict = {}
    exec(compile(files["kf.py"], "kf.py", "exec"), scope)  # derive's own generated code
    rng = np.random.default_rng(2)
    for name, program in unit.programs.items():
        static_py, static_c = count(program, "python"), count(program, "c")
        counter = OpCounter()
        args = [spd(rng, p.shape[0]).ravel() if p.symmetric else rng.uniform(0.5, 1.0, p.size)
                for p in program.inputs]
        scope[name](*[counter.wrap(v) for v in args])
        assert counter.snapshot() == static_py, name
        assert count_c_function(files["kf.c"], f"{unit.prefix}_{name}") == static_c, name
        assert f"operations per call of {name} (C99, fma through DERIVE_FMA and DERIVE_FNMA): " \
               f"{static_c.summary()}" in files["kf.c"]


def test_a_dense_scalar_update_costs_one_division_and_a_rank_one_fma_per_measurement():
    # n states, m selector rows (H_i a unit row), P dense: per measurement 1 add (s), 1
    # division, n multiplications (the gain), 1 (the weight), n(n+1)/2 fma (P) and n (x,
    # n multiplications the first time), and m - 1 additions of the innovations moved
    n, m = 4, 2
    model = LinearModel("sel", [f"x{i}" for i in range(n)], F=np.eye(n).tolist(),
                        Q=np.eye(n).tolist(),
                        sensors=[Sensor("s", ["a", "b"], H=np.eye(n)[:m].tolist(),
                                        R=np.diag([1.0, 2.0]).tolist()),
                                 Sensor("t", ["c"], H=[[0, 0, 0, 1]], R=[[1]])],
                        x0=np.zeros(n).tolist(), P0=np.eye(n).tolist())
    ops = count(derive_unit(model, "kf", SEQUENTIAL).programs["update_s"], "c")
    assert ops.div == m
    assert ops.fma == m * n * (n + 1) // 2 + (m - 1) * n
    assert ops.mul == m * (n + 1) + n
    assert (ops.add + ops.sub) == m + (m - 1) + n + m  # s, nu, x - back, z - H x


# -- the ins_gnss flight, in the form the catalog does not use ---------------------------------


@pytest.fixture(scope="module")
def ins_flight():
    """The flight (seed 0) and its NumPy reference run, shared by both forms."""
    fl = flight.simulate(seed=0)
    return fl, reference.run(fl)


@pytest.mark.parametrize("form", ["batch", "sequential"])
def test_ins_gnss_whole_flight_matches_the_numpy_reference(tmp_path, form, ins_flight):
    fl, ref = ins_flight
    generated = load_generated("ins_gnss", "ekf", {"update": form}, "c", tmp_path)
    facts = "\n".join(generated.unit.facts)
    assert ("update of gnss: sequential" in facts) == (form == "sequential")
    xs, Ps = generated_run(generated.c, fl)
    assert compare.state_agreement(xs, ref.xs).max() <= AGREEMENT
    assert compare.covariance_agreement(Ps, ref.Ps) <= AGREEMENT


def test_an_ekf_sensor_is_updated_at_the_prior_linearisation():
    # h nonlinear: sequential uses h and H at the prior x for every scalar (so it equals
    # the batch EKF update, not an iterated one)
    model = NonlinearModel(
        "rng", ["px", "py"], f=["px", "py"], Q=np.eye(2).tolist(),
        sensors=[Sensor("r", ["d", "e"], h=["sqrt(px**2 + py**2)", "px*py"],
                        R=[[0.1, 0], [0, 0.2]], update="sequential")],
        x0=[3, 4], P0=np.eye(2).tolist())
    generated = load_generated(model, "ekf")
    x, P, z = np.array([3.0, 4.0]), np.array([[1.0, 0.3], [0.3, 2.0]]), np.array([5.3, 11.0])
    H = np.array([[0.6, 0.8], [4.0, 3.0]])
    x_ref, P_ref, _, _ = batch.update(x, P, z, np.array([5.0, 12.0]), H, np.diag([0.1, 0.2]))
    for module in (generated.python, generated.c):
        x_new, P_new = (np.asarray(v, float) for v in module.update_r(x, P.ravel(), z))
        assert relative(x_new, x_ref) <= 1e-13
        assert relative(P_new.reshape(2, 2), P_ref) <= 1e-13


# -- the option and the declarations, and their refusals ----------------------------------------


def test_the_option_is_taken_by_the_filters_with_sensors():
    assert takers("update") == ["kf", "ekf", "eskf"]
    assert derive_unit(car(), "kf").programs.keys() == derive_unit(car(), "kf", SEQUENTIAL
                                                                   ).programs.keys()
    with pytest.raises(OptionError, match=r"option 'update' \(--update\) must be one of batch, "
                                          r"sequential, got 'sequental'"):
        derive_unit(car(), "kf", {"update": "sequental"})


def test_a_one_sensor_model_gets_predict_and_its_update():
    model = LinearModel("a", ["x"], ["z"], F=[[1]], H=[[1]], Q=[[0.01]], R=[[1]],
                        x0=[0], P0=[[1]])
    assert list(derive_unit(model, "kf", SEQUENTIAL).programs) == ["predict", "update_all"]
    assert list(derive_unit(model, "kf", {"update": "batch"}).programs) == ["step"]


def correlated() -> LinearModel:
    return LinearModel("c", ["x", "y"], F=np.eye(2).tolist(), Q=np.eye(2).tolist(),
                       sensors=[Sensor("pos", ["a", "b"], H=np.eye(2).tolist(),
                                       R=[[1, 0.25], [0.25, 1]]),
                                Sensor("vel", ["c"], H=[[1, 1]], R=[[1]])])


def test_a_constant_correlated_R_is_decorrelated_by_its_ldl_factors():
    # R = L D L^T (exact rationals): the update fuses L^-1 z with noise D; a variance not
    # positive names the decorrelated measurement
    generated = load_generated(correlated(), "kf", {**SEQUENTIAL, "gate": 0.99})
    assert "(R = L D L^T not diagonal: L^-1 z fused, its noise D;" in \
        "\n".join(generated.unit.facts)
    rng = np.random.default_rng(5)
    x, P, z = rng.normal(size=2), spd(rng, 2), rng.normal(size=2)
    R = np.array([[1, 0.25], [0.25, 1]])
    x_ref, P_ref, nis_ref, _ = batch.update(x, P, z, x, np.eye(2), R)
    for module in (generated.python, generated.c):
        x_new, P_new, nis, _ = module.update_pos(x, P.ravel(), z)
        assert relative(x_new, x_ref) <= LINEAR_AGREEMENT
        assert relative(np.asarray(P_new).reshape(2, 2), P_ref) <= LINEAR_AGREEMENT
        assert nis[0] == pytest.approx(nis_ref, rel=1e-12)
        with pytest.raises(NumericalError, match=r"measurement 0 \(a, decorrelated by R's "
                                                 r"LDL\^T factor\) of the sequential"):
            module.update_pos(x, -10 * P.ravel(), z)  # s_0 = R_00 - 10 P_00 < 0


def test_a_correlated_R_that_is_not_constant_is_refused_naming_the_entry(capsys, tmp_path):
    symbolic = LinearModel("c", ["x", "y"], F=np.eye(2).tolist(), Q=np.eye(2).tolist(),
                           parameters=["r"],
                           sensors=[Sensor("pos", ["a", "b"], H=np.eye(2).tolist(),
                                           R=[["r", 0.25], [0.25, 1]]),
                                    Sensor("vel", ["c"], H=[[1, 1]], R=[[1]])])
    with pytest.raises(OptionError, match=r"^option 'update' \(--update\) sequential: sensor "
                                          r"'pos': the sequential update needs R diagonal or "
                                          r"constant \(to decorrelate it when the code is "
                                          r"generated\), but R\[0, 1\] = 1/4 is not zero and R "
                                          r"depends on r$"):
        derive_unit(symbolic, "kf", SEQUENTIAL)
    assert derive_unit(symbolic, "kf")  # batch takes it
    with pytest.raises(ModelError, match=r"sensor 'pos': the sequential update needs R "
                                         r"diagonal or constant .* R\[0, 1\] = 1/4"):
        LinearModel("c", ["x", "y"], F=np.eye(2).tolist(), Q=np.eye(2).tolist(),
                    parameters=["r"],
                    sensors=[Sensor("pos", ["a", "b"], H=np.eye(2).tolist(),
                                    R=[["r", 0.25], [0.25, 1]], update="sequential")])
    path = tmp_path / "bad.toml"
    path.write_text(TOML.replace('R = [[4, 0], [0, 9]]', 'R = [["r", 1], [1, 9]]').replace(
        "dt = 0.1", 'dt = 0.1\nr = { description = "free" }'))
    assert main(["generate", str(path), "--filter", "kf", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensor 'gps': the sequential update needs R diagonal or " \
                             "constant" in err[0] and "R[0, 1] = 1 is not zero" in err[0], err
    assert not (tmp_path / "x").exists()


def test_an_R_given_per_call_is_refused():
    model = LinearModel("c", ["x"], F=[[1]], Q=[[1]],
                        sensors=[Sensor("pos", ["a"], H=[[1]], R="argument"),
                                 Sensor("vel", ["c"], H=[[1]], R=[[1]])])
    with pytest.raises(OptionError, match=r"sensor 'pos': the sequential update needs R "
                                          r"diagonal or constant, but its R is given per call"):
        derive_unit(model, "kf", SEQUENTIAL)


TOML = """
[model]
name = "two"
states = ["p", "v"]

[parameters]
dt = 0.1

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [[0.01, 0], [0, 0.01]]

[sensors.gps]
measurements = ["zp", "zv"]
H = [[1, 0], [0, 1]]
R = [[4, 0], [0, 9]]
update = "sequential"

[sensors.speed]
measurements = ["s"]
H = [[0, 1]]
R = 0.25
"""


def test_a_model_file_declares_a_sequential_sensor_and_the_option_overrides_it():
    model = loads_model(TOML)
    assert [g.update for g in model.sensors] == ["sequential", "batch"]
    facts = "\n".join(derive_unit(model, "kf").facts)
    assert "update of gps: sequential" in facts and "update of speed" not in facts
    assert "update of gps" not in "\n".join(derive_unit(model, "kf", {"update": "batch"}).facts)
    with pytest.raises(ModelFileError, match=r"\[sensors.gps\] update.*must be one of batch, "
                                             r"sequential, got string 'scalar'"):
        loads_model(TOML.replace('update = "sequential"', 'update = "scalar"'))


def test_the_catalog_ins_gnss_declares_its_gnss_sequential():
    assert {g.name: g.update for g in load_catalog("ins_gnss").sensors} == {
        "gnss": "sequential", "baro": "batch"}
