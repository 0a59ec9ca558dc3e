"""Linear models with per-step known inputs u: x(k+1) = F x(k) + B u(k) + G w(k),
z(k+1) = H x(k+1) + D u(k) + v (row k of us goes with row k of zs).

pykalman's robot data (time-varying transition offsets, a constant observation offset)
is reproduced through inputs by the NumPy reference and the generated Python and C KF;
a hand-derived scalar offset model checks the convention; wrong shapes are refused naming
the matrix; a model file with inputs generates, compiles with the strict flags and
verifies; every filter without input support refuses an input model.
"""

import subprocess
import sys

import numpy as np
import pytest
import sympy

from derive import reference
from derive.apps.verify import verify_filter
from derive.errors import FilterError, ModelError
from derive.filters import FILTERS, available, derive_unit, why_not
from derive.model import LinearModel
from derive.modelfile import load_model_file
from derive.pipeline import load_generated

STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ROBOT_TOLERANCE = 1e-9


def relative(a, b) -> float:
    """max |a - b| / max |b|."""
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


@pytest.fixture(scope="module")
def robot():
    """pykalman's load_robot as a LinearModel with inputs [transition offsets (5),
    observation offset (2)], started from pykalman's first filtered state (its step 0 is
    an update without a prediction), with zs and us for the 500 steps after it."""
    datasets = pytest.importorskip("pykalman.datasets")
    data = datasets.load_robot()
    n, m = data.transition_matrix.shape[0], data.observation_matrix.shape[0]
    model = LinearModel(
        "robot", [f"s{i}" for i in range(n)], ["z0", "z1"], data.transition_matrix,
        data.observation_matrix, data.transition_covariance, data.observation_covariance,
        B=np.hstack([np.eye(n), np.zeros((n, m))]), D=np.hstack([np.zeros((m, n)), np.eye(m)]),
        inputs=[f"b{i}" for i in range(n)] + [f"d{j}" for j in range(m)],
        x0=data.filtered_state_means[0], P0=data.filtered_state_covariances[0])
    observations = data.observations
    assert not np.ma.getmaskarray(observations)[1:].any()
    zs = np.ma.getdata(observations)[1:]
    # pykalman predicts into step t with transition_offsets[t - 1]; step t's observation
    # offset is the constant observation_offset
    us = np.hstack([data.transition_offsets, np.tile(data.observation_offset, (len(zs), 1))])
    return model, zs, us, data.filtered_state_means[1:], data.filtered_state_covariances[1:]


def test_reference_kf_reproduces_pykalman_robot_through_inputs(robot):
    model, zs, us, means, covariances = robot
    num = model.numeric()
    xs, Ps = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs,
                          B=num.B, D=num.D, us=us)
    assert relative(xs, means) < ROBOT_TOLERANCE
    assert relative(Ps, covariances) < ROBOT_TOLERANCE
    # the offsets matter: without them the answer is far off
    plain = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)[0]
    assert relative(plain, means) > 1e-3


@pytest.mark.parametrize("lang", ["python", "c"])
def test_generated_kf_reproduces_pykalman_robot_through_inputs(robot, lang, tmp_path):
    model, zs, us, means, covariances = robot
    num = model.numeric()
    module = load_generated(model, "kf", {}, lang, tmp_path).module(lang)
    xs, Ps = module.run(zs, us, num.x0, num.P0)
    assert relative(xs, means) < ROBOT_TOLERANCE
    assert relative(np.asarray(Ps).reshape(covariances.shape), covariances) < ROBOT_TOLERANCE


def scalar_offset_model(**kw):
    """x(k+1) = x(k) + b(k) + w, z(k+1) = x(k+1) + d(k) + v; inputs [b, d]."""
    return LinearModel("offsets", ["x"], ["z"], [[1]], [[1]], [["q"]], [["r"]],
                       values={"q": 0.25, "r": 2}, B=[[1, 0]], D=[[0, 1]], inputs=["b", "d"],
                       x0=[1.0], P0=[[3.0]], **kw)


def hand_derived(zs, us, x=1.0, P=3.0, q=0.25, r=2.0):
    """The scalar KF with the offsets written out by hand."""
    xs, Ps = [], []
    for z, (b, d) in zip(zs, us):
        xp, Pp = x + b, P + q
        K = Pp / (Pp + r)
        x, P = xp + K * (z - xp - d), (1 - K) * Pp
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)


def test_offset_model_matches_the_hand_derived_filter_in_reference_python_and_c(tmp_path):
    model = scalar_offset_model()
    rng = np.random.default_rng(3)
    zs, us = rng.normal(size=(40, 1)) * 3, rng.normal(size=(40, 2))
    xs_hand, Ps_hand = hand_derived(zs[:, 0], us)
    num = model.numeric()
    xs, Ps = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs,
                          B=num.B, D=num.D, us=us)
    assert np.allclose(xs[:, 0], xs_hand, rtol=1e-13, atol=0)
    assert np.allclose(Ps[:, 0, 0], Ps_hand, rtol=1e-13, atol=0)
    generated = load_generated(model, "kf", {}, "all", tmp_path)
    for lang in ("python", "c"):
        xs, Ps = generated.module(lang).run(zs, us, num.x0, num.P0)
        assert np.allclose(np.asarray(xs)[:, 0], xs_hand, rtol=1e-13, atol=0), lang
        assert np.allclose(np.asarray(Ps).reshape(-1), Ps_hand, rtol=1e-13, atol=0), lang
    # step takes the same row of u as run: step(x, P, z, u)
    x_new, P_new = generated.module("python").step(num.x0, num.P0, zs[0], us[0])
    assert np.isclose(np.asarray(x_new)[0], xs_hand[0], rtol=1e-13, atol=0)


def test_header_states_the_input_convention():
    unit = derive_unit(scalar_offset_model(), "kf")
    assert unit.step_inputs == ("z", "u")
    assert unit.run_tracks  # (tests/fitting/test_tracks.py: each track its own run's)
    assert any("x(k+1) = F x(k) + B u(k), z(k+1) = H x(k+1) + D u(k)" in f for f in unit.facts)


@pytest.mark.parametrize("kw,message", [
    ({"B": [[1, 0, 0]], "inputs": ["a", "b"]}, "matrix B must be 1x2 (states x inputs), got 1x3"),
    ({"D": [[1], [0]], "inputs": ["a"]}, "matrix D must be 1x1 (measurements x inputs), got 2x1"),
    ({"B": [[1]]}, "matrix B is given but the model declares no inputs"),
    ({"D": [[1]]}, "matrix D is given but the model declares no inputs"),
    ({"B": [["a"]], "inputs": ["a"]}, "symbol 'a' is a per-step input"),
    ({"inputs": ["x"]}, "input 'x' has the name of a state or measurement"),
], ids=["B shape", "D shape", "B without inputs", "D without inputs", "input in a matrix",
        "input named as a state"])
def test_model_errors_name_the_matrix_or_input(kw, message):
    with pytest.raises(ModelError, match=message.replace("(", r"\(").replace(")", r"\)")):
        LinearModel("bad", ["x"], ["z"], [[1]], [[1]], [[1]], [[1]], **kw)


def test_filters_without_input_support_refuse_an_input_model():
    model = scalar_offset_model()
    refused = [name for name, spec in FILTERS.items()
               if spec.model_kind == "linear" and name not in ("kf", "rts")]
    assert refused
    for name in refused:
        assert f"filter {name!r} takes no per-step inputs" in why_not(model, name)
        with pytest.raises(FilterError, match="takes no per-step inputs"):
            derive_unit(model, name)
    assert available(model) == ["kf", "rts"]


def test_compose_refuses_input_models():
    with pytest.raises(ModelError, match="has per-step inputs"):
        LinearModel.compose("two", [scalar_offset_model(), scalar_offset_model()])


CART = """\
[model]
name = "cart"
states = ["pos", "vel"]
measurements = ["y"]

[parameters]
dt = 0.5
q = 0.01

[discrete]
F = [[1, "dt"], [0, 1]]
H = [[1, 0]]
Q = [["q", 0], [0, "q"]]
R = 1
inputs = ["acc", "bias"]
B = [["dt**2/2", 0], ["dt", 0]]
D = [[0, 1]]
"""


def test_model_file_with_inputs_generates_compiles_strictly_and_verifies(tmp_path):
    path = tmp_path / "cart.toml"
    path.write_text(CART)
    model = load_model_file(path)
    assert [u.name for u in model.inputs] == ["acc", "bias"]
    assert model.matrix("B")[0, 0] == sympy.Rational(1, 8)
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "kf", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    c_file = out / "cart" / "kf.c"
    compiled = subprocess.run(["gcc", *STRICT, "-c", str(c_file), "-o", str(tmp_path / "kf.o")],
                              capture_output=True, text=True, timeout=120)
    assert compiled.returncode == 0, compiled.stderr
    header = (out / "cart" / "kf.h").read_text()
    assert "int cart_kf_step(x[2], P[2*2], z[1], u[2], x_new[2] out" in header
    assert "int cart_kf_run(steps, z[steps*1], u[steps*2], x0[2], P0[2*2]," in header
    results = verify_filter(model, "kf", steps=300, workdir=tmp_path)
    assert results and all(r.passed for r in results), [r.line() for r in results]


@pytest.mark.parametrize("table,extra,message", [
    ("discrete", 'inputs = ["a"]\nB = [[1, 2]]\n', "matrix B must be 2x1"),
    ("discrete", 'B = [[1], [2]]\n', "matrix B is given but the model declares no inputs"),
    ("continuous", 'inputs = ["a"]\n', "unknown key 'inputs'"),
], ids=["B shape", "B without inputs", "continuous inputs"])
def test_model_file_input_errors_are_one_line_with_exit_status_2(tmp_path, table, extra,
                                                                  message):
    body = {"discrete": 'F = [[1, 1], [0, 1]]\nH = [[1, 0]]\nQ = [[1, 0], [0, 1]]\nR = 1\n',
            "continuous": 'Phi = [[0, 1], [0, 0]]\nQc = 1\nG = [0, 1]\nH = [[1, 0]]\nR = 1\n'
                          'dt = 1\n'}[table]
    path = tmp_path / "bad.toml"
    path.write_text('[model]\nname = "bad"\nstates = ["p", "v"]\nmeasurements = ["y"]\n\n'
                    f"[{table}]\n{body}{extra}")
    with pytest.raises(ModelError, match=message):
        load_model_file(path)
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "kf", "--out", str(tmp_path / "o")], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2
    assert message in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "o").exists()
