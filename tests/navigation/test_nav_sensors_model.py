"""Several sensors and unit-norm groups in the model API and in model files."""

import re
from pathlib import Path

import pytest
import sympy

from derive import LinearModel, NonlinearModel, Sensor
from derive.cli import main
from derive.errors import ModelError, ModelFileError
from derive.modelfile import loads_model

DOCS = Path(__file__).resolve().parents[2] / "docs" / "model-files.md"

TWO_SENSORS = """
[model]
name = "cart2"
states = ["p", "v"]

[parameters]
dt = { description = "step, per step in p" }
q = 0.01

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["q", 0], [0, "q"]]
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
"""

ATTITUDE = """
[model]
name = "att"
states = ["q0", "q1", "b"]

[parameters]
dt = 0.01
r = 0.1

[nonlinear]
inputs = ["w"]
f = ["q0 - dt*(w - b)*q1/2", "q1 + dt*(w - b)*q0/2", "b"]
Q = [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-8]]
Qu = [[1e-4]]
unit_norm = [["q0", "q1"]]

[sensors.mag]
measurements = ["c", "s"]
h = ["q0**2 - q1**2", "2*q0*q1"]
R = [["r", 0], [0, "r"]]

[sensors.bias]
measurements = ["zb"]
h = ["b"]
R = 0.01
"""


def test_linear_sensors_from_a_file_stack_H_R_and_D():
    model = loads_model(TWO_SENSORS)
    assert [s.name for s in model.sensors] == ["gps", "speed"]
    assert model.measurements == ("zp", "zv")
    assert model.H == sympy.Matrix([[1, 0], [0, 1]])
    assert model.R == sympy.diag(4, sympy.Rational(1, 4))
    assert model.D == sympy.Matrix([[0, 1], [0, 0]])
    gps, speed = model.sensors
    assert [u.name for u in gps.inputs] == ["off"] and gps.D == sympy.Matrix([[1]])
    assert speed.inputs == () and speed.rows == (1, 2)


def test_nonlinear_sensors_and_unit_norm_from_a_file():
    model = loads_model(ATTITUDE)
    assert model.unit_norm == (("q0", "q1"),)
    mag, bias = model.sensors
    assert mag.m == 2 and bias.m == 1
    assert model.h.shape == (3, 1)
    assert mag.h[1, 0] == 2 * model.symbol("q0") * model.symbol("q1")


def test_sensors_and_stacked_measurements_together_are_refused():
    with pytest.raises(ModelError, match="either sensors or measurements, h, R"):
        NonlinearModel("t", ["x"], ["z"], f=["x"], h=["x"], Q=[[1]], R=[[1]],
                       sensors=[Sensor("a", ["y"], h=["x"], R=[[1]])])


def test_a_sensor_of_the_wrong_kind_is_refused():
    with pytest.raises(ModelError, match="sensor 'a': h is for a nonlinear model"):
        LinearModel("t", ["x"], F=[[1]], Q=[[1]], sensors=[Sensor("a", ["y"], h=["x"], R=1)])


def test_a_sensor_input_outside_the_model_inputs_is_refused():
    with pytest.raises(ModelError, match="sensor 'a': input 'u' is not one of the model's"):
        NonlinearModel("t", ["x"], f=["x"], Q=[[1]],
                       sensors=[Sensor("a", ["y"], h=["x"], R=1, inputs=["u"])])


def test_h_using_another_sensors_input_is_refused():
    with pytest.raises(ModelError, match="h of sensor 'a' uses input 'u'"):
        NonlinearModel("t", ["x"], f=["x"], Q=[[1]], inputs=["u"],
                       sensors=[Sensor("a", ["y"], h=["x + u"], R=1, inputs=[])])


def test_a_sensor_R_that_is_not_definite_is_named():
    with pytest.raises(ModelError, match="R of sensor 'b' must be positive definite"):
        NonlinearModel("t", ["x"], f=["x"], Q=[[1]],
                       sensors=[Sensor("a", ["y"], h=["x"], R=1),
                                Sensor("b", ["w"], h=["x"], R=-1)])


@pytest.mark.parametrize("groups, message", [
    ([["q0"]], "at least two states"),
    ([["q0", "zz"]], "'zz', which is not a state"),
    ([["q0", "q1"], ["q1", "b"]], "state 'q1' is in two groups"),
    ("q0", "must be a list of groups"),
])
def test_bad_unit_norm_groups_are_refused(groups, message):
    with pytest.raises(ModelError, match=message):
        NonlinearModel("t", ["q0", "q1", "b"], ["z"], f=["q0", "q1", "b"], h=["b"],
                       Q=sympy.eye(3), R=1, unit_norm=groups)


@pytest.mark.parametrize("edit, message", [
    (("[sensors.speed]\n", "[sensors.speed]\nh = [\"v\"]\n"),
     r"\[sensors.speed\]: unknown key 'h'"),
    (('measurements = ["zv"]\n', ""), r"\[sensors.speed\]: missing required key 'measurements'"),
    (('states = ["p", "v"]\n', 'states = ["p", "v"]\nmeasurements = ["z"]\n'),
     r"\[model\] measurements: not allowed with \[sensors.NAME\]"),
    (('inputs = ["off"]\n', 'inputs = ["of"]\n'), r"\[sensors.gps\] inputs: 'of' is not one"),
])
def test_bad_sensor_tables_give_one_line_naming_the_key(edit, message):
    with pytest.raises(ModelFileError, match=message):
        loads_model(TWO_SENSORS.replace(*edit))


def test_bad_unit_norm_in_a_file_names_the_key():
    with pytest.raises(ModelFileError, match=r"\[nonlinear\] unit_norm\[0\]: 'q9' is not a state"):
        loads_model(ATTITUDE.replace('[["q0", "q1"]]', '[["q0", "q9"]]'))


def test_the_documented_sensor_examples_load_and_verify(tmp_path, capsys):
    blocks = dict(
        (re.match(r"# file: (\S+)", block).group(1), block)
        for block in re.findall(r"```toml\n(.*?)```", DOCS.read_text(encoding="utf-8"), re.S))
    for name, filter_name, sensors in (("cart2.toml", "kf", ["gps", "speed"]),
                                       ("attitude.toml", "ekf", ["mag", "bias"])):
        path = tmp_path / name
        path.write_text(blocks[name], encoding="utf-8")
        model = loads_model(blocks[name])
        assert [s.name for s in model.sensors] == sensors
        assert main(["verify", str(path), "--filter", filter_name]) == 0
    assert loads_model(blocks["attitude.toml"]).unit_norm == (("q0", "q1"),)
    out = capsys.readouterr().out
    for model, filter_name in (("cart2", "kf"), ("att", "ekf")):
        for lang in ("python", "c"):
            assert re.search(rf"^ok +{model} +{filter_name} +{lang} ", out, re.M)
