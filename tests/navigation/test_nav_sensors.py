"""Several sensors: predict and update_<sensor> per sensor, run over per-sensor rows
(NaN rows: no measurement), per-step dt, counts, verify, and the registry's refusals."""

import numpy as np
import pytest
import sympy

from derive import LinearModel, NonlinearModel, Sensor
from derive.cli import main
from derive.errors import FilterError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.modelfile import loads_model
from derive.pipeline import load_generated

TWO_SENSORS = """
[model]
name = "cart2"
states = ["p", "v"]

[parameters]
dt = { description = "step, one value per step in p" }
q = 0.01

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["q*dt", 0], [0, "q*dt"]]
inputs = ["a", "off"]
B = [["dt**2/2", 0], ["dt", 0]]

[sensors.gps]
measurements = ["zp"]
H = [[1, 0]]
R = 4
inputs = ["off"]
D = [[1]]

[sensors.speed]
measurements = ["zv"]
H = [[0, 1]]
R = 0.25

[initial]
x0 = [0, 0]
P0 = [[1, 0], [0, 1]]
"""


def attitude(dt="dt"):
    """A 2-D attitude (unit vector q0, q1) driven by a gyro input, with a gyro bias;
    sensors: a vector measurement of the attitude and a bias measurement."""
    q0, q1, b, w = sympy.symbols("q0 q1 b w", real=True)
    dt = sympy.Symbol(dt, real=True) if isinstance(dt, str) else dt
    f = [q0 - dt * (w - b) * q1 / 2, q1 + dt * (w - b) * q0 / 2, b]
    return NonlinearModel(
        "att", ["q0", "q1", "b"], f=f, Q=sympy.diag(1e-6, 1e-6, 1e-8) * 10, inputs=["w"],
        Qu=[[1e-4]], unit_norm=[["q0", "q1"]],
        sensors=[Sensor("mag", ["c", "s"], h=[q0**2 - q1**2, 2 * q0 * q1],
                        R=[["r", 0], [0, "r"]]),
                 Sensor("bias", ["zb"], h=[b], R=[[1e-2]])],
        values={"r": 0.01}, x0=[1, 0, 0], P0=sympy.diag(0.01, 0.01, 1e-4), parameters=[dt])


def relative(a, b):
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


def rates(steps, rng, m, period, scale=1.0):
    z = scale * rng.normal(size=(steps, m))
    z[np.arange(steps) % period != 0] = np.nan
    return z


@pytest.fixture(scope="module")
def linear_filter():
    model = loads_model(TWO_SENSORS)
    return model, load_generated(model, "kf")


@pytest.fixture(scope="module")
def ekf_filter():
    model = attitude()
    return model, load_generated(model, "ekf")


def test_two_sensors_give_predict_and_one_update_per_sensor():
    model = loads_model(TWO_SENSORS)
    unit = derive_unit(model, "kf")
    assert unit.run_kind == "sensors"
    assert list(unit.programs) == ["predict", "update_gps", "update_speed"]
    ports = {name: [p.name for p in prog.inputs] for name, prog in unit.programs.items()}
    assert ports == {"predict": ["x", "P", "u", "p"], "update_gps": ["x", "P", "z", "u", "p"],
                     "update_speed": ["x", "P", "z", "p"]}


def test_linear_run_with_rates_and_per_step_dt_matches_the_reference(linear_filter):
    model, generated = linear_filter
    rng = np.random.default_rng(3)
    steps = 3000
    us = rng.uniform(-1, 1, (steps, 2))
    dt = rng.uniform(0.005, 0.05, (steps, 1))  # dt varies from step to step
    zs = {"gps": rates(steps, rng, 1, 20, 3.0), "speed": rates(steps, rng, 1, 5)}
    x0, P0 = np.zeros(2), np.eye(2)
    ref = reference_run(model, {}, zs, us, dt, x0, P0)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs["gps"], zs["speed"], us, x0, P0, p=dt)
        assert relative(xs, ref.xs) <= 1e-12
        assert relative(Ps, ref.Ps) <= 1e-12


def test_a_run_is_the_functions_called_step_by_step(linear_filter):
    model, generated = linear_filter
    py = generated.python
    rng = np.random.default_rng(5)
    steps = 30
    us, dt = rng.uniform(-1, 1, (steps, 2)), rng.uniform(0.01, 0.1, (steps, 1))
    zg, zv = rates(steps, rng, 1, 3), rates(steps, rng, 1, 2)
    xs, Ps = py.run(zg, zv, us, np.zeros(2), np.eye(2), dt)
    x, P = np.zeros(2), np.eye(2).ravel()
    for k in range(steps):
        x, P = py.predict(x, P, us[k], dt[k])
        if not np.isnan(zg[k]).any():
            x, P = py.update_gps(x, P, zg[k], us[k, [1]], dt[k])
        if not np.isnan(zv[k]).any():
            x, P = py.update_speed(x, P, zv[k], dt[k])
        assert np.array_equal(xs[k], np.asarray(x, float))
        assert np.array_equal(Ps[k], np.asarray(P, float))


def test_ekf_with_unit_norm_and_per_step_dt_matches_the_reference_over_a_long_run(ekf_filter):
    model, generated = ekf_filter
    rng = np.random.default_rng(11)
    steps = 5000
    us = 0.3 + 0.05 * rng.normal(size=(steps, 1))
    dt = rng.uniform(0.005, 0.02, (steps, 1))
    angle = np.cumsum(us[:, 0] * dt[:, 0])
    zm = np.c_[np.cos(angle), np.sin(angle)] + 0.1 * rng.normal(size=(steps, 2))
    zm[np.arange(steps) % 5 != 0] = np.nan
    zb = rates(steps, rng, 1, 20, 0.1)
    x0, P0 = np.array([1.0, 0.0, 0.0]), np.diag([0.01, 0.01, 1e-4])
    ref = reference_run(model, {}, {"mag": zm, "bias": zb}, us, dt, x0, P0)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zm, zb, us, x0, P0, p=dt)
        assert relative(xs, ref.xs) <= 1e-9
        assert relative(Ps, ref.Ps) <= 1e-9
    updated = ~np.isnan(zm[:, 0])
    norms = np.hypot(ref.xs[updated, 0], ref.xs[updated, 1])
    assert np.max(np.abs(norms - 1.0)) <= 1e-15  # renormalised after every update


def test_unit_norm_is_part_of_the_update_program_and_counted():
    unit = derive_unit(attitude(), "ekf")
    update = count(unit.programs["update_mag"], "c")
    assert update.sqrt >= 1  # the norm of (q0, q1)
    plain = derive_unit(attitude().__class__(
        "att", ["q0", "q1", "b"], f=["q0", "q1", "b"], Q=sympy.eye(3),
        sensors=[Sensor("mag", ["c", "s"], h=["q0**2 - q1**2", "2*q0*q1"], R=sympy.eye(2)),
                 Sensor("bias", ["zb"], h=["b"], R=[[1]])]), "ekf")
    assert count(plain.programs["update_mag"], "c").sqrt == 0


@pytest.mark.parametrize("options", [{}, {"gate": 0.999}, {"start": "update"}])
@pytest.mark.parametrize("which", ["kf", "ekf"])
def test_counts_in_the_header_are_those_of_the_code(which, options):
    model = loads_model(TWO_SENSORS) if which == "kf" else attitude()
    unit = derive_unit(model, which, options)
    files = render_filter(model, which, "all", options)
    text, c_text = files[f"{which}.py"], files[f"{which}.c"]
    scope: dict = {}
    exec(compile(text, f"{unit.prefix}.py", "exec"), scope)  # derive's own generated code
    rng = np.random.default_rng(2)
    for name, program in unit.programs.items():
        static_py, static_c = count(program, "python"), count(program, "c")
        counter = OpCounter()
        args = []
        for port in program.inputs:
            if port.symmetric:
                A = rng.normal(size=port.shape)
                args.append((A @ A.T + port.shape[0] * np.eye(port.shape[0])).ravel())
            else:
                args.append(rng.uniform(0.5, 1.0, port.size))
        scope[name](*[counter.wrap(v) for v in args])
        assert counter.snapshot() == static_py, name
        assert count_c_function(c_text, f"{unit.prefix}_{name}") == static_c, name
        assert f"operations per call of {name} (Python): {static_py.summary()}" in text
        assert f"operations per call of {name} (C99, fma through DERIVE_FMA and DERIVE_FNMA): " \
               f"{static_c.summary()}" in c_text


def test_the_two_sensor_toml_model_generates_compiles_strictly_and_verifies(tmp_path, capsys):
    path = tmp_path / "cart2.toml"
    path.write_text(TWO_SENSORS.replace('dt = { description = "step, one value per step in p" }',
                                        "dt = 0.1"))
    out = tmp_path / "out"
    assert main(["generate", str(path), "--filter", "kf", "--lang", "all", "--out",
                 str(out)]) == 0
    assert sorted(p.name for p in (out / "cart2").iterdir()) == ["kf.c", "kf.h", "kf.py"]
    assert main(["verify", str(path), "--filter", "kf"]) == 0  # builds with the strict flags
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[:4] for line in lines if line.startswith("ok")] == [
        ["ok", "cart2", "kf", "python"], ["ok", "cart2", "kf", "c"]]


def test_the_c_header_describes_run_for_derive_build(linear_filter):
    _, generated = linear_filter
    run = generated.c.functions["run"]
    assert [a.name for a in run.arguments] == [
        "z_gps", "z_speed", "u", "x0", "P0", "xs", "Ps", "p"]
    assert [a.name for a in run.arguments if a.optional] == ["Ps"]
    assert sorted(generated.c.functions) == ["predict", "run", "update_gps", "update_speed"]


@pytest.mark.parametrize("name", ["ukf", "lf", "rts", "sskf"])
def test_filters_without_sensor_support_refuse_several_sensors(name):
    plain = LinearModel("plain", ["p", "v"], F=[[1, 1], [0, 1]], Q=np.eye(2),
                        sensors=[Sensor("gps", ["zp"], H=[[1, 0]], R=4),
                                 Sensor("speed", ["zv"], H=[[0, 1]], R=1)])
    model = attitude() if name == "ukf" else plain
    with pytest.raises(FilterError, match=rf"filter '{name}' takes no model with several "
                                          r"sensors; model '\w+' declares sensors "
                                          r"\['\w+', '\w+'\] \(the filters that do: kf, ekf\)"):
        derive_unit(model, name)


def test_one_sensor_models_keep_the_step_and_run():
    model = NonlinearModel("one", ["x"], f=["x"], Q=[[1]],
                           sensors=[Sensor("s", ["z"], h=["x**2"], R=[[1]])])
    unit = derive_unit(model, "ekf")
    assert unit.run_kind == "timevarying" and "step" in unit.programs


ONE_GROUP_WITH_UNIT_NORM = """
[model]
name = "att1"
states = ["q0", "q1", "b"]
measurements = ["c", "s", "zb"]

[parameters]
dt = 0.01

[nonlinear]
inputs = ["w"]
f = ["q0 - dt*(w - b)*q1/2", "q1 + dt*(w - b)*q0/2", "b"]
h = ["q0**2 - q1**2", "2*q0*q1", "b"]
Q = [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-8]]
R = [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]
Qu = [[1e-4]]
unit_norm = [["q0", "q1"]]

[initial]
x0 = [1, 0, 0]
P0 = [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.0001]]
"""


def test_a_one_group_model_with_unit_norm_keeps_step_and_verifies(tmp_path, capsys):
    path = tmp_path / "att1.toml"
    path.write_text(ONE_GROUP_WITH_UNIT_NORM)
    unit = derive_unit(loads_model(ONE_GROUP_WITH_UNIT_NORM), "ekf")
    assert unit.run_kind == "timevarying"
    assert "unit-norm groups, renormalised at the end of every update: (q0, q1)" in unit.facts
    assert count(unit.programs["step"], "c").sqrt == 1
    assert main(["verify", str(path), "--filter", "ekf"]) == 0
    out = capsys.readouterr().out
    assert "ok   att1               ekf     c" in out


def test_R_given_per_call_is_an_input_of_the_update_and_a_per_step_array_of_run(tmp_path):
    text = TWO_SENSORS.replace("R = 4\n", 'R = "argument"\n').replace(
        'dt = { description = "step, one value per step in p" }', "dt = 0.1")
    model = loads_model(text)
    assert [g.R_argument for g in model.sensors] == [True, False]
    generated = load_generated(model, "kf")
    ports = [p.name for p in generated.unit.programs["update_gps"].inputs]
    assert ports == ["x", "P", "z", "R", "u"]
    rng = np.random.default_rng(6)
    steps = 500
    us = rng.uniform(-1, 1, (steps, 2))
    zs = {"gps": rates(steps, rng, 1, 4, 2.0), "speed": rates(steps, rng, 1, 1)}
    Rs = {"gps": rng.uniform(0.5, 8.0, (steps, 1, 1))}  # R changes from call to call
    x0, P0 = np.zeros(2), np.eye(2)
    ref = reference_run(model, {}, zs, us, None, x0, P0, Rs)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs["gps"], Rs["gps"], zs["speed"], us, x0, P0)
        assert relative(xs, ref.xs) <= 1e-12 and relative(Ps, ref.Ps) <= 1e-12
    path = tmp_path / "cart2r.toml"
    path.write_text(text)
    assert main(["verify", str(path), "--filter", "kf"]) == 0
    one = LinearModel("one", ["p"], F=[[1]], Q=[[1]],
                      sensors=[Sensor("gps", ["zp"], H=[[1]], R="argument")])
    assert derive_unit(one, "kf").run_kind == "sensors"
    with pytest.raises(FilterError, match="filter 'lf' takes no R given per call; model "
                                          "'one' declares sensor R = 'argument'"):
        derive_unit(one, "lf")


def test_per_step_dt_in_the_one_group_step_and_run_and_in_predict():
    """Item 3: p one row per step reaches step/run, predict and update1 of today's EKF."""
    q0, q1, b, w, dt = sympy.symbols("q0 q1 b w dt", real=True)
    model = NonlinearModel(
        "att1", ["q0", "q1", "b"], ["c", "s", "zb"],
        f=[q0 - dt * (w - b) * q1 / 2, q1 + dt * (w - b) * q0 / 2, b],
        h=[q0**2 - q1**2, 2 * q0 * q1, b], Q=sympy.diag(1e-5, 1e-5, 1e-7),
        R=sympy.eye(3) / 100, inputs=["w"], Qu=[[1e-4]], parameters=["dt"])
    generated = load_generated(model, "ekf")
    assert generated.unit.run_kind == "timevarying"
    rng = np.random.default_rng(12)
    steps = 1000
    us = 0.3 + 0.05 * rng.normal(size=(steps, 1))
    dt = rng.uniform(0.005, 0.05, (steps, 1))
    angle = np.cumsum(us[:, 0] * dt[:, 0])
    zs = np.c_[np.cos(angle), np.sin(angle), np.zeros(steps)] + 0.1 * rng.normal(size=(steps, 3))
    x0, P0 = np.array([1.0, 0.0, 0.0]), np.diag([0.01, 0.01, 1e-4])
    ref = reference_run(model, {}, {"all": zs}, us, dt, x0, P0)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs, us, x0, P0, p=dt)
        assert relative(xs, ref.xs) <= 1e-9 and relative(Ps, ref.Ps) <= 1e-9
    x, P = generated.python.predict(x0, P0.ravel(), us[0], dt[0])
    x_ref, P_ref = generated.python.predict(x0, P0.ravel(), us[0], dt[1])
    assert not np.allclose(x, x_ref)  # predict reads its own row of p


def test_R_symbolic_in_free_parameters_follows_p_per_step():
    model = LinearModel("l", ["p", "v"], F=[[1, "dt"], [0, 1]], Q=np.eye(2) * 0.01,
                        sensors=[Sensor("a", ["z1"], H=[[1, 0]], R="ra"),
                                 Sensor("b", ["z2"], H=[[0, 1]], R=[["rb"]])],
                        parameters=["dt", "ra", "rb"])
    generated = load_generated(model, "kf")
    rng = np.random.default_rng(0)
    steps = 300
    p = np.c_[rng.uniform(0.01, 0.1, steps), rng.uniform(0.5, 2, steps),
              rng.uniform(0.1, 1, steps)]
    z1, z2 = rates(steps, rng, 1, 3), rates(steps, rng, 1, 1)
    ref = reference_run(model, {}, {"a": z1, "b": z2}, None, p, np.zeros(2), np.eye(2))
    for module in (generated.python, generated.c):
        xs, Ps = module.run(z1, z2, np.zeros(2), np.eye(2), p=p)
        assert relative(xs, ref.xs) <= 1e-12 and relative(Ps, ref.Ps) <= 1e-12
