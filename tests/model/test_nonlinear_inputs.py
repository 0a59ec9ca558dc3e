"""Nonlinear models whose f uses per-step inputs, with noise Qu on the inputs:
x(k) = f(x(k-1), u(k)) + w, z(k) = h(x(k), u(k)) + v, and the EKF's prediction
P(k/k-1) = F P F^T + Fu Qu Fu^T + Q with Fu = df/du at x(k-1/k-1), u(k) (the IMU
convention; row k of us goes with row k of zs, as for the linear KF).

A unicycle (planar position and heading driven by a measured speed and turn rate) is
filtered by the NumPy reference EKF and by the generated Python and C EKF; the mapped
process noise is checked against a finite-difference Jacobian of a hand-written f; the
prediction's u is the row given with z; the UKF refuses noise Qu on the inputs of f in one
line (it takes inputs in f without it: tests/model/test_guards.py); wrong Qu
is refused naming it; a model file with inputs in f and Qu generates, compiles with the
strict flags and verifies.
"""

import subprocess
import sys

import numpy as np
import pytest

from derive import reference
from derive.apps.verify import verify_filter
from derive.errors import FilterError, ModelError, ShapeError, SymbolError
from derive.filters import available, derive_unit, why_not
from derive.model import NonlinearModel
from derive.modelfile import load_model_file
from derive.pipeline import load_generated

STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
TOLERANCE = 1e-10
DT, Q_VAR, R_VAR = 0.1, 1e-6, 0.25
QU = np.diag([0.01, 0.0004])  # given at run time through p = [sv, sw]


def unicycle(**kw):
    """[px, py, th] driven by inputs v (speed), w (turn rate); GNSS-like position fixes."""
    args = {"inputs": ["v", "w"], "Qu": [["sv", 0], [0, "sw"]], "x0": [0, 0, 0.1],
            "P0": [[1, 0, 0], [0, 1, 0], [0, 0, 0.1]], **kw}
    args.setdefault("parameters", ["sv", "sw"] if "Qu" not in kw else [])
    return NonlinearModel("unicycle", ["px", "py", "th"], ["zx", "zy"],
                          ["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w"],
                          ["px", "py"], [["q", 0, 0], [0, "q", 0], [0, 0, "q"]],
                          [["r", 0], [0, "r"]], values={"dt": DT, "q": Q_VAR, "r": R_VAR},
                          **args)


def f_by_hand(x, u):
    px, py, th = x
    v, w = u
    return np.array([px + DT * v * np.cos(th), py + DT * v * np.sin(th), th + DT * w])


def relative(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, float) - b)) / np.max(np.abs(b)))


def scenario(steps=200, seed=5):
    rng = np.random.default_rng(seed)
    us = np.column_stack([1.0 + 0.2 * rng.normal(size=steps),
                          0.3 + 0.05 * rng.normal(size=steps)])
    x, zs = np.array([0.0, 0.0, 0.1]), []
    for u in us:
        x = f_by_hand(x, u + rng.normal(size=2) * np.sqrt(np.diag(QU)))
        zs.append(x[:2] + rng.normal(size=2) * np.sqrt(R_VAR))
    return np.array(zs), us


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    return load_generated(unicycle(), "ekf", {}, "all", tmp_path_factory.mktemp("unicycle"))


def reference_run(model, zs, us):
    fns = model.numeric_functions({"sv": QU[0, 0], "sw": QU[1, 1]})
    return reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"],
                         [0, 0, 0.1], np.diag([1, 1, 0.1]), zs, inputs=us,
                         Fu_jac=fns["Fu"], Qu=fns["Qu"])


@pytest.mark.parametrize("lang", ["python", "c"])
def test_generated_ekf_with_inputs_in_f_matches_the_reference(generated, lang):
    model = unicycle()
    zs, us = scenario()
    ref = reference_run(model, zs, us)
    p = np.diag(QU)
    xs, Ps = generated.module(lang).run(zs, us, np.array([0, 0, 0.1]), np.diag([1, 1, 0.1]), p)
    assert relative(xs, ref.xs) < TOLERANCE
    assert relative(np.asarray(Ps).reshape(ref.Ps.shape), ref.Ps) < TOLERANCE
    # the inputs and their noise matter: without Qu, or with us shifted by a row, it differs
    fns = model.numeric_functions({"sv": 0, "sw": 0})
    no_qu = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"],
                          [0, 0, 0.1], np.diag([1, 1, 0.1]), zs, inputs=us,
                          Fu_jac=fns["Fu"], Qu=fns["Qu"])
    assert relative(no_qu.Ps, ref.Ps) > 1e-3
    shifted = reference_run(model, zs, np.roll(us, 1, axis=0))
    assert relative(shifted.xs, ref.xs) > 1e-3


@pytest.mark.parametrize("lang", ["python", "c"])
def test_predict_adds_fu_qu_fut_from_a_finite_difference_jacobian(generated, lang):
    """P = 0 isolates the mapped noise: P_new = Fu Qu Fu^T + Q; Fu by central differences
    of the hand-written f (independent of sympy)."""
    rng = np.random.default_rng(11)
    module, p = generated.module(lang), np.diag(QU)
    for _ in range(20):
        x = rng.uniform(-3, 3, 3)
        u = rng.uniform(-2, 2, 2)
        eps = 1e-6
        Fu = np.column_stack([(f_by_hand(x, u + eps * e) - f_by_hand(x, u - eps * e)) / (2 * eps)
                              for e in np.eye(2)])
        want = Fu @ QU @ Fu.T + Q_VAR * np.eye(3)
        x_new, P_new = module.predict(x, np.zeros((3, 3)), u, p)
        assert np.allclose(np.asarray(x_new), f_by_hand(x, u), rtol=1e-14, atol=1e-14)
        assert relative(np.asarray(P_new).reshape(3, 3), want) < 1e-8


def test_step_uses_the_input_row_given_with_z(generated):
    """step(x, P, z(k), u(k)) = predict(x, P, u(k)) then the update with z(k)."""
    zs, us = scenario(steps=3)
    model = unicycle()
    ref = reference_run(model, zs[:1], us[:1])
    for lang in ("python", "c"):
        x_new, P_new = generated.module(lang).step(
            np.array([0, 0, 0.1]), np.diag([1, 1, 0.1]), zs[0], us[0], np.diag(QU))
        assert relative(x_new, ref.xs[0]) < TOLERANCE, lang
        assert relative(np.asarray(P_new).reshape(3, 3), ref.Ps[0]) < TOLERANCE, lang


def test_header_states_the_convention_and_predict_takes_u():
    unit = derive_unit(unicycle(), "ekf")
    assert [p.name for p in unit.programs["predict"].inputs] == ["x", "P", "u", "p"]
    assert any(f.startswith("row k of us goes with row k of zs: u(k) drives the prediction")
               for f in unit.facts)


def test_ukf_refuses_noise_on_the_inputs_of_f_in_one_line():
    model = unicycle()
    reason = why_not(model, "ukf")
    assert reason == ("filter 'ukf' does not take noise Qu on the inputs of f (model "
                      "'unicycle'); use the ekf, which maps it through df/du")
    with pytest.raises(FilterError, match="does not take noise Qu"):
        derive_unit(model, "ukf")
    assert available(model) == ["ekf"]
    assert "ukf" in available(unicycle(Qu=None))


@pytest.mark.parametrize("kw,error,message", [
    ({"Qu": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, ShapeError, "matrix Qu must be 2x2"),
    ({"Qu": [1, 1]}, ShapeError, "matrix Qu must be 2x2"),
    ({"inputs": None, "Qu": [[1]]}, ShapeError,
     "matrix Qu is given but the model declares no inputs"),
    ({"Qu": [["px", 0], [0, 1]]}, SymbolError, "matrix Qu depends on state or input 'px'"),
    ({"Qu": [[-1, 0], [0, 1]]}, ModelError, "Qu"),
    ({"Qu": [[1, 2], [0, 1]]}, ModelError, "Qu"),
], ids=["3x3", "vector", "no inputs", "state", "negative", "asymmetric"])
def test_bad_qu_is_refused_naming_it(kw, error, message):
    if kw.get("inputs", 1) is None:
        with pytest.raises(error, match=message):
            NonlinearModel("still", ["x"], ["z"], ["x"], ["x"], [[1]], [[1]], **kw)
        return
    with pytest.raises(error, match=message):
        unicycle(**kw)


UNICYCLE_FILE = """\
[model]
name = "unicycle_file"
states = ["px", "py", "th"]
measurements = ["zx", "zy"]

[parameters]
dt = 0.1
q = 1e-6
r = 0.25
sv = 0.01
sw = 0.0004

[nonlinear]
inputs = ["v", "w"]
f = ["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w"]
h = ["px", "py"]
Q = [["q", 0, 0], [0, "q", 0], [0, 0, "q"]]
R = [["r", 0], [0, "r"]]
Qu = [["sv", 0], [0, "sw"]]

[initial]
x0 = [0, 0, 0.1]
P0 = [[1, 0, 0], [0, 1, 0], [0, 0, 0.1]]
"""


def test_model_file_with_inputs_in_f_and_qu_generates_compiles_strictly_and_verifies(
        tmp_path):
    path = tmp_path / "unicycle_file.toml"
    path.write_text(UNICYCLE_FILE)
    model = load_model_file(path)
    assert [u.name for u in model.f_inputs] == ["v", "w"]
    assert model.numeric_functions()["Qu"].tolist() == [[0.01, 0], [0, 0.0004]]
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "ekf", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    compiled = subprocess.run(["gcc", *STRICT, "-c", str(out / "unicycle_file" / "ekf.c"),
                               "-o", str(tmp_path / "ekf.o")],
                              capture_output=True, text=True, timeout=120)
    assert compiled.returncode == 0, compiled.stderr
    header = (out / "unicycle_file" / "ekf.h").read_text()
    assert "unicycle_file_ekf_predict(x[3], P[3*3], u[2], x_new[3] out" in header
    results = verify_filter(model, "ekf", steps=300, workdir=tmp_path)
    assert results and all(r.passed for r in results), [r.line() for r in results]


@pytest.mark.parametrize("extra,message", [
    ('Qu = [[1, 0], [0, 1]]\n', "matrix Qu must be 1x1"),
    ('Qu = [["x", 0]]\n', "unknown symbol"),
])
def test_model_file_qu_errors_are_one_line_with_exit_status_2(tmp_path, extra, message):
    path = tmp_path / "bad.toml"
    path.write_text('[model]\nname = "bad"\nstates = ["x"]\nmeasurements = ["y"]\n\n'
                    '[nonlinear]\ninputs = ["a"]\nf = ["x + a"]\nh = ["x"]\nQ = 1\nR = 1\n'
                    + extra)
    with pytest.raises(ModelError, match=message):
        load_model_file(path)
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "ekf", "--out", str(tmp_path / "o")], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2
    assert message in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_show_prints_the_input_jacobian_and_qu(tmp_path):
    path = tmp_path / "unicycle_file.toml"
    path.write_text(UNICYCLE_FILE)
    done = subprocess.run([sys.executable, "-m", "derive", "show", str(path)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Fu_jacobian =" in done.stdout and "Qu =" in done.stdout
    assert "dt*cos(th)" in done.stdout


def test_inputs_in_f_and_h_together_keep_update1_and_match_the_reference(tmp_path):
    """Ranges to two beacons whose positions are inputs of h, a speed input of f: step and
    run take every input, predict only f's (v), update1 only its beacon's."""
    model = NonlinearModel(
        "ranger", ["x", "y"], ["r1", "r2"], ["x + dt*v", "y"],
        ["sqrt((x - a1)**2 + (y - b1)**2)", "sqrt((x - a2)**2 + (y - b2)**2)"],
        [["q", 0], [0, "q"]], [["r", 0], [0, "r"]], values={"dt": 0.5, "q": 1e-3, "r": 0.01},
        inputs=["a1", "b1", "v", "a2", "b2"], Qu=np.diag([0, 0, 0.04, 0, 0]), x0=[0, 0],
        P0=[[1, 0], [0, 1]])
    unit = derive_unit(model, "ekf")
    ports = {name: [p.name for p in program.inputs] for name, program in unit.programs.items()}
    assert ports == {"step": ["x", "P", "z", "u"], "predict": ["x", "P", "u"],
                     "update1": ["x", "P", "z", "u"]}
    assert [p.shape for p in unit.programs["predict"].inputs][2] == (1,)
    assert [p.shape for p in unit.programs["update1"].inputs][3] == (2,)
    rng = np.random.default_rng(2)
    steps = 30
    us = np.column_stack([rng.uniform(5, 10, steps), rng.uniform(5, 10, steps),
                          rng.uniform(0.5, 1, steps), rng.uniform(-10, -5, steps),
                          rng.uniform(5, 10, steps)])
    zs = rng.uniform(5, 15, (steps, 2))
    fns = model.numeric_functions()
    ref = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"], [0, 0],
                        np.eye(2), zs, inputs=us, Fu_jac=fns["Fu"], Qu=fns["Qu"])
    generated = load_generated(model, "ekf", {}, "all", tmp_path)
    for lang in ("python", "c"):
        module = generated.module(lang)
        xs, Ps = module.run(zs, us, np.zeros(2), np.eye(2))
        assert relative(xs, ref.xs) < TOLERANCE, lang
        assert relative(np.asarray(Ps).reshape(ref.Ps.shape), ref.Ps) < TOLERANCE, lang
        # predict with v, then one update1 per beacon: the first update is the batch's
        # (both linearise at x(1/0)); one measurement at a time agrees to first order only
        x, P = module.predict(np.zeros(2), np.eye(2), us[0, [2]])
        Fu = fns["Fu"](np.zeros(2), us[0])
        want = fns["F"](np.zeros(2), us[0]) @ fns["F"](np.zeros(2), us[0]).T \
            + Fu @ fns["Qu"] @ Fu.T + fns["Q"]
        assert relative(np.asarray(P).reshape(2, 2), want) < TOLERANCE, lang
        _, _, innovation, _ = module.update1(x, P, zs[0, [0]], us[0, [0, 1]])
        assert np.isclose(np.asarray(innovation)[0],
                          zs[0, 0] - fns["h"](np.asarray(x), us[0])[0], rtol=1e-13), lang
