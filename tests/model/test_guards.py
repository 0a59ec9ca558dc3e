"""Guarded expressions, angle measurements, state-dependent noise, the UKF with inputs in f
and the iterated EKF (derive.guards, derive.filters.ekf, ukf, nonlinear).

- guards (sign, Max, Min, Piecewise) become selects with the stated side, lower to one
  comparison and one select each, print as C ternaries and Python helpers that count;
- the guarded air-data model (tests/models/air_data.toml: epsilon-guarded airspeed,
  sideslip and angle of attack, starting in hover where the guards act) generates,
  compiles strictly, is counted exactly (static = executed Python = C text) and verifies;
- the CTRV radar tracker through bearing ±π: derive's EKF within 1.5x the textbook EKF's
  position error (the bearing not declared an angle: far outside it);
- FilterPy's radar EKF test (R = 0.05 h(x)), the UKF with inputs in f and the iterated
  EKF against their NumPy references;
- bad declarations: one line naming the component, exit status 2.
"""

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy
from filterpy.kalman import ExtendedKalmanFilter

from derive import catalog, reference
from derive.apps import radar
from derive.apps.verify import nonlinear_scenario, verify_filter
from derive.catalog import read_text
from derive.emit import c_printer, python_printer
from derive.errors import ModelError
from derive.expression_lowering import lower
from derive.filters import derive_unit
from derive.filters.nonlinear import wrap_angle
from derive.flops import OpCounter, count, count_c_function, count_c_text
from derive.generation import render_filter
from derive.guards import GuardGreater, IfAtLeast, IfGreater, selects
from derive.model import NonlinearModel, Sensor
from derive.modelfile import load_model_file, loads_model
from derive.pipeline import load_generated
from derive.symbols import jacobian
from derive.trees import OpCount, count_tree

AIR_DATA = Path(__file__).resolve().parents[1] / "models" / "air_data.toml"
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
x, y = sympy.symbols("x y", real=True)


# -- guards as selects ---------------------------------------------------------------------


def test_guards_become_selects_with_the_stated_side():
    eps = sympy.Rational(1, 1000)
    guarded = selects(sympy.Max(x, eps))
    assert guarded == IfAtLeast(x, eps, x, eps)  # the numeric bound goes last
    assert guarded.diff(x).xreplace({x: eps}) == 1  # at the tie: x's side
    assert selects(sympy.Min(x, y)) == IfAtLeast(y, x, x, y)
    sign = selects(sympy.sign(x))
    assert [sign.xreplace({x: v}) for v in (2, -3, 0)] == [1, -1, 0]
    pw = selects(sympy.Piecewise((x ** 2, x > 0), (-x, True)))
    assert pw.diff(x).xreplace({x: 0}) == -1  # x > 0 false at 0: the default's side
    assert jacobian(sympy.Matrix([sympy.Abs(x)]), [x])[0] == sign  # d|x|/dx = sign(x)


def test_a_branch_divides_only_by_a_divisor_kept_off_zero_where_it_is_not_taken():
    """A divisor of a branch that shares a symbol with the condition is the select's guard
    of it: itself where the branch is taken, else 1; the Jacobian's branches (1/x**2)
    too; the guard's derivative is the divisor's (it is read only where taken)."""
    pw = selects(sympy.Piecewise((y / x, x > 0), (y, True)))
    assert pw == IfGreater(x, 0, y / GuardGreater(x, 0, x, 1), y)
    assert pw.diff(x) == IfGreater(x, 0, -y / GuardGreater(x, 0, x, 1) ** 2, 0)
    assert pw.diff(y) == IfGreater(x, 0, 1 / GuardGreater(x, 0, x, 1), 1)
    other = selects(sympy.Piecewise((x, x > 0), (y / x, True)))  # the default's side
    assert other == IfGreater(x, 0, x, y / GuardGreater(x, 0, 1, x))
    free = selects(sympy.Piecewise((x / y, x > 0), (0, True)))  # y is not the guard's
    assert free == IfGreater(x, 0, x / y, 0)
    assert [pw.xreplace({x: v, y: 3}) for v in (2, 0)] == [sympy.Rational(3, 2), 3]


def test_ctrv_radar_at_a_turn_rate_of_zero_computes_without_dividing_by_it():
    """The catalog's CTRV turn divides by omega where |omega dt| > 0.03: at omega = 0
    exactly the generated Python (plain floats, counting) does not raise, counts what it
    executes as its header does, and predicts the straight line (the small-turn
    expansion at a turn rate of 0)."""
    model = catalog.load("ctrv_radar")
    unit = derive_unit(model, "ekf", {})
    files = render_filter(model, "ekf", "python")
    scope: dict = {}
    exec(compile(files["ekf.py"], "ctrv_radar.py", "exec"), scope)
    x0 = [-700.0, 5.0, 10.0, 0.3, 0.0]
    P0 = (np.eye(5) * 2.0).ravel().tolist()
    counter = OpCounter()
    x_new, P_new = scope["predict"](counter.wrap(x0), counter.wrap(P0))
    assert counter.snapshot() == count(unit.programs["predict"], "python")
    straight = [x0[0] + x0[2] * math.cos(x0[3]), x0[1] + x0[2] * math.sin(x0[3])]
    assert [v.value for v in x_new[:2]] == pytest.approx(straight, rel=1e-15)
    plain_x, plain_P = scope["predict"](x0, P0)
    assert np.all(np.isfinite(plain_x)) and np.all(np.isfinite(plain_P))


def test_ctrv_radar_small_turn_expansion_meets_the_turn_at_its_guard():
    """On either side of |omega dt| = 0.03 the turn and its second-order expansion agree:
    the step to 1e-5 of its v dt (truncation a^3/24), its omega-derivative to 2e-4
    (a^2/8, the size of float32's loss u/a^2 in the turn's there)."""
    v, psi, dt = 10.0, 0.7, 1.0
    for omega in (0.03, -0.03):
        below = radar.ctrv(np.array([0.0, 0.0, v, psi, omega * (1 - 1e-12)]), dt)
        above = radar.ctrv(np.array([0.0, 0.0, v, psi, omega * (1 + 1e-12)]), dt)
        assert np.abs(below[:2] - above[:2]).max() <= 1e-5 * v * dt
        F_below = radar.ctrv_jacobian(np.array([0.0, 0.0, v, psi, omega * (1 - 1e-12)]), dt)
        F_above = radar.ctrv_jacobian(np.array([0.0, 0.0, v, psi, omega * (1 + 1e-12)]), dt)
        assert np.abs(F_below[:2, 4] - F_above[:2, 4]).max() <= 2e-4 * v * dt**2 / 2


def test_a_select_is_one_comparison_and_one_select_printed_and_counted_alike():
    tree = lower(IfGreater(x, 0, x * y, 2 * y))
    text = c_printer.expression(tree)
    assert text == "((x > 0.0) ? x*y : 2.0*y)"
    assert count_tree(tree) == OpCount(mul=2, cmp=1, select=1) == count_c_text(text)
    scope = {"np": np}
    exec("\n".join(python_printer.HELPERS["if_gt"]), scope)  # derive's own helper
    choose = scope["_if_greater"]
    assert choose(1.0, 0.0, 3.0, 4.0) == 3.0 and choose(math.nan, 0.0, 3.0, 4.0) == 4.0
    np.testing.assert_array_equal(choose(np.array([1.0, -1.0, np.nan]), 0.0, 3.0, 4.0),
                                  [3.0, 4.0, 4.0])
    counter = OpCounter()
    (value,) = counter.wrap([-1.0])
    chosen = choose(value, 0.0, 3.0, 4.0)
    assert counter.snapshot() == OpCount(cmp=1, select=1) and chosen.counter is counter


@pytest.mark.parametrize("entry,message", [
    ("Piecewise((x, x > 0))", "h[z]: Piecewise has no default"),
    ("Piecewise(((x, 1), x > 0), (0, True))", "branch 1 of Piecewise is a tuple of 2 values"),
    ("Piecewise((x, x >= 0 ), (1, 2 > 1))", None),  # a constant condition folds
], ids=["no default", "shape", "folded"])
def test_bad_guards_are_refused_naming_the_entry(entry, message):
    def build():
        return NonlinearModel("g", ["x"], ["z"], ["x"], [entry], [[1]], [[1]])
    if message is None:
        assert build().h[0] == IfAtLeast(x, 0, x, 1)
        return
    with pytest.raises(ModelError, match=re.escape(message)):
        build()


# -- the guarded air-data model ------------------------------------------------------------


@pytest.fixture(scope="module")
def air_data():
    return load_model_file(AIR_DATA)


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
def test_guarded_model_is_counted_exactly_and_compiles_strictly(air_data, filter_name,
                                                                tmp_path):
    unit = derive_unit(air_data, filter_name, {})
    files = render_filter(air_data, filter_name, "all")
    scope: dict = {}
    exec(compile(files[f"{filter_name}.py"], "air_data.py", "exec"), scope)  # derive's own
    rng = np.random.default_rng(3)
    selected = 0
    for name, program in unit.programs.items():
        counter = OpCounter()
        args = []
        for port in program.inputs:
            if port.symmetric:
                A = rng.normal(size=port.shape)
                args.append(counter.wrap((A @ A.T + 3 * np.eye(port.shape[0])).ravel()))
            else:  # states around the guards' bounds, measurements nearby
                args.append(counter.wrap(rng.uniform(-0.6, 0.6, port.size)))
        scope[name](*args)
        static = count(program, "python")
        assert counter.snapshot() == static, (name, counter.snapshot().summary())
        assert count_c_function(files[f"{filter_name}.c"], f"air_data_{filter_name}_{name}") \
            == count(program, "c")
        selected += static.select
    assert selected > 0
    (tmp_path / "f.c").write_text(files[f"{filter_name}.c"])
    (tmp_path / f"{filter_name}.h").write_text(files[f"{filter_name}.h"])
    done = subprocess.run(["gcc", *STRICT, "-c", str(tmp_path / "f.c"), "-o",
                           str(tmp_path / "f.o")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_guarded_model_verifies_where_its_guards_act(air_data, tmp_path):
    results = verify_filter(air_data, "ekf", steps=200, workdir=tmp_path)
    assert results and all(r.passed for r in results), [r.line() for r in results]
    truth = nonlinear_scenario(air_data, steps=200).truth
    v_min = 0.5
    slow = np.sum(truth[:, 0] < v_min)  # alpha's guard max(u, v_min) acts
    assert 0 < slow < len(truth)


# -- angles: the CTRV radar tracker through ±π ----------------------------------------------


def test_wrap_angle_generated_is_the_reference_wrap():
    t = sympy.Symbol("t", real=True)
    text = python_printer.expression(lower(wrap_angle(t)))
    values = np.array([math.pi, -math.pi, 3.0, -3.5, 7.0, -9.5, 1e3, 0.0, math.nextafter(
        math.pi, 4.0)])
    got = eval(text, {"np": np, "t": values})  # derive's own printed expression
    assert np.all((got > -math.pi) & (got <= math.pi))
    np.testing.assert_allclose(got, reference.nonlinear.wrap(values), rtol=0, atol=1e-12)
    assert got[1] == got[0] == math.pi


def test_ctrv_radar_ekf_is_within_1_5x_the_textbook_ekf_through_pi():
    errors = radar.compare(seeds=range(2), steps=120)
    assert errors["crossings"] >= 2  # the bearing passes through ±π in the flights
    assert errors["derive"] <= 1.5 * errors["textbook"]
    assert errors["derive_unwrapped"] > 1.5 * errors["textbook"]  # the bar means something


def test_an_angle_of_a_sensor_is_wrapped_by_its_update_and_its_reference(tmp_path):
    """A sensor model (the run kind sensors) through bearing ±π: the target crosses the
    negative x axis in the first steps; Python and C against the sensors reference."""
    model = NonlinearModel(
        "cv_radar", ["px", "py", "vx", "vy"], f=["px + vx", "py + vy", "vx", "vy"],
        Q=[[0.1, 0, 0, 0], [0, 0.1, 0, 0], [0, 0, 0.01, 0], [0, 0, 0, 0.01]],
        sensors=[Sensor("radar", ["range", "bearing"],
                        h=["sqrt(px**2 + py**2)", "atan2(py, px)"], R=[[25, 0], [0, 1e-4]])],
        angles=["bearing"], x0=[-700, 5, 0, -10], P0=np.diag([100.0, 100.0, 4.0, 4.0]))
    results = verify_filter(model, "ekf", steps=100, workdir=tmp_path)
    assert results and all(r.passed for r in results), [r.line() for r in results]
    with pytest.raises(ModelError, match="with sensors, Q and R may not depend on the state"):
        NonlinearModel("moving", ["p"], f=["p"], Q=[["0.1*p**2"]],
                       sensors=[Sensor("s", ["z"], h=["p"], R=[[1]])])


def test_angle_declarations_are_checked():
    base = dict(states=["px", "py"], measurements=["r", "b"], f=["px", "py"],
                h=["sqrt(px**2 + py**2)", "atan2(py, px) + 0.1"], Q=[[1, 0], [0, 1]],
                R=[[1, 0], [0, 1]])
    assert NonlinearModel("ok", angles=["b"], **base).angle_rows() == (False, True)
    with pytest.raises(ModelError, match=r"measurement 'r' is declared an angle but h\[r\]"):
        NonlinearModel("bad", angles=["r"], **base)
    with pytest.raises(ModelError, match="angles names 'c', which is not a measurement"):
        NonlinearModel("bad", angles=["c"], **base)


def test_a_bad_declaration_in_a_model_file_exits_2_in_one_line(tmp_path):
    path = tmp_path / "bad.toml"  # the catalog file, its bearing swapped for the range
    path.write_text(read_text(radar.MODEL).replace('angles = ["bearing"]',
                                                   'angles = ["range"]'))
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "ekf", "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1
    assert "measurement 'range' is declared an angle" in done.stderr
    assert not (tmp_path / "out").exists()


# -- state-dependent R (FilterPy's radar EKF test), the UKF with inputs in f, the IEKF -----


def _filterpy_radar():
    """FilterPy's test_ekf radar: x = [pos, vel, alt], slant range, R = 0.05 h(x)."""
    dt = 0.05
    return NonlinearModel("radar", ["pos", "vel", "alt"], ["slant"],
                          [f"pos + {dt}*vel", "vel", "alt"], ["sqrt(pos**2 + alt**2)"],
                          [[0, 0, 0], [0, "q", 0], [0, 0, "q"]],
                          [["0.05*sqrt(pos**2 + alt**2)"]], values={"q": 0.001})


def _radar_flight(steps: int = 60):
    rng = np.random.default_rng(11)
    pos, vel, alt = 0.0, 100.0, 1000.0
    zs = []
    for _ in range(steps):
        pos += vel * 0.05
        zs.append([math.hypot(pos, alt) + rng.normal(0.0, 5.0)])
    return np.array(zs), np.array([-10.0, 90.0, 1100.0]), np.eye(3) * 50.0


@pytest.fixture(scope="module")
def radar_ekfs():
    model = _filterpy_radar()
    return model, {k: load_generated(model, "ekf", {"iterations": k}, lang="python")
                   .module("python") for k in (0, 2)}


def test_state_dependent_R_is_evaluated_at_the_prediction_as_filterpy(radar_ekfs):
    model, modules = radar_ekfs
    zs, x0, P0 = _radar_flight()
    xs, Ps = modules[0].run(zs, x0, P0)
    fns = model.numeric_functions()
    kf = ExtendedKalmanFilter(3, 1)
    kf.x, kf.P, kf.Q = x0.copy(), P0.copy(), fns["Q"]
    kf.F = np.array([[1.0, 0.05, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    theirs = []
    for z in zs:
        kf.predict()
        kf.update(z, lambda s: fns["H"](s, ()), lambda s: fns["h"](s, ()),
                  R=0.05 * fns["h"](kf.x, ())[0])
        theirs.append(kf.x.ravel().copy())
    assert np.max(np.abs(np.asarray(xs) - theirs) / np.abs(theirs)) <= 1e-10


def test_iterated_ekf_is_its_reference_and_moves_the_estimate(radar_ekfs):
    model, modules = radar_ekfs
    zs, x0, P0 = _radar_flight()
    fns = model.numeric_functions()
    plain, _ = modules[0].run(zs, x0, P0)
    xs, Ps = modules[2].run(zs, x0, P0)
    ref = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"], x0, P0,
                        zs, iterations=2, m=1)
    assert np.max(np.abs(np.asarray(xs) - ref.xs) / np.abs(ref.xs)) <= 1e-12
    assert np.max(np.abs(np.asarray(Ps).reshape(ref.Ps.shape) - ref.Ps)) <= \
        1e-10 * np.max(np.abs(ref.Ps))
    assert np.max(np.abs(np.asarray(plain) - xs)) > 1e-6  # the relinearisation counts


def test_ukf_with_inputs_in_f_is_its_reference():
    model = NonlinearModel("unicycle", ["px", "py", "th"], ["zx", "zy"],
                           ["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w"],
                           ["px", "py"], [["q", 0, 0], [0, "q", 0], [0, 0, "q"]],
                           [["r", 0], [0, "r"]], values={"dt": 0.1, "q": 1e-4, "r": 0.25},
                           inputs=["v", "w"])
    module = load_generated(model, "ukf", lang="python").module("python")
    rng = np.random.default_rng(5)
    us = np.column_stack([rng.uniform(1.0, 2.0, 80), rng.uniform(-0.5, 0.5, 80)])
    zs = rng.normal(0.0, 0.5, (80, 2)) + np.cumsum(us[:, :1] * 0.1, axis=0)
    x0, P0 = np.array([0.0, 0.0, 0.1]), np.diag([1.0, 1.0, 0.1])
    xs, Ps = module.run(zs, us, x0, P0)
    fns = model.numeric_functions()
    ref = reference.ukf(fns["f"], fns["h"], fns["Q"], fns["R"], x0, P0, zs, inputs=list(us),
                        f_inputs=True)
    assert np.max(np.abs(np.asarray(xs) - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))


def test_an_input_dependent_Q_is_bound_in_predict():
    model = loads_model('''
[model]
name = "drift"
states = ["p"]
measurements = ["z"]
[nonlinear]
inputs = ["s"]
f = ["p + s"]
h = ["p"]
Q = [["0.01*s**2 + 0.001"]]
R = [[1]]
''')
    unit = derive_unit(model, "ekf", {})
    assert any("Q at x(k-1/k-1), u(k)" in line for line in unit.facts)
    assert [p.name for p in unit.programs["predict"].inputs][:3] == ["x", "P", "u"]
