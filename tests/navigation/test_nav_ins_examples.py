"""A free parameter's ``example`` (``dt = { example = 0.01 }``): the parameter stays free in
the generated code, and derive verify simulates and runs with the example (one p row per
step) — so ``derive verify ins_gnss`` works with dt free. Refusals name the key."""

from __future__ import annotations

import re

import pytest

from derive import LinearModel, Sensor, catalog
from derive.apps.targets.data import verification_data
from derive.apps.verify import verify_filter
from derive.cli import main
from derive.errors import ModelError, SymbolError
from derive.modelfile import loads_model

CART = """
[model]
name = "cart_free_dt"
states = ["p", "v"]

[parameters]
dt = {{ description = "step (s), free"{example} }}
q = 0.01

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["q*dt", 0], [0, "q*dt"]]

[sensors.gps]
measurements = ["zp"]
H = [[1, 0]]
R = 4

[sensors.speed]
measurements = ["zv"]
H = [[0, 1]]
R = 0.25

[initial]
x0 = [0, 0]
P0 = [[1, 0], [0, 1]]
"""


def test_a_free_parameter_keeps_its_example_and_stays_free():
    model = loads_model(CART.format(example=", example = 0.1"))
    assert [p.name for p in model.parameters] == ["dt"]
    assert model.examples == {"dt": 0.1}
    assert catalog.load("ins_gnss").examples == {"dt": 0.01}


def test_verify_runs_a_free_parameter_at_its_example():
    model = loads_model(CART.format(example=", example = 0.1"))
    results = verify_filter(model, "kf", steps=200)
    assert [r.lang for r in results] == ["python", "c"]
    assert all(r.passed for r in results), results


def test_verify_without_an_example_names_the_parameter_and_the_remedy():
    model = loads_model(CART.format(example=""))
    with pytest.raises(SymbolError, match=r"none for \['dt'\] \(give each an example.*"
                                          r"or --values dt=V\)"):
        verify_filter(model, "kf", steps=20)


PLAIN = """
[model]
name = "plain_free_dt"
states = ["p", "v"]
measurements = ["zp"]

[parameters]
dt = {{ description = "step (s), free"{example} }}
q = {{ description = "noise, free", example = 0.01 }}

[discrete]
F = [[1, "dt"], [0, 1]]
Q = [["q*dt", 0], [0, "q*dt"]]
H = [[1, 0]]
R = [[4]]

[initial]
P0 = [[1, 0], [0, 1]]
"""


def test_verify_runs_a_model_without_sensors_at_its_examples_or_values(tmp_path, capsys):
    """Any filter of a model with free parameters is verified at their examples (or
    --values): the reference at those values, the generated code given them as p."""
    path = tmp_path / "plain.toml"
    path.write_text(PLAIN.format(example=", example = 0.1"))
    assert main(["verify", str(path), "--filter", "kf", "--steps", "100"]) == 0
    out = capsys.readouterr().out
    assert [line.split()[:2] for line in out.splitlines()].count(["ok", "plain_free_dt"]) == 2
    results = verify_filter(loads_model(PLAIN.format(example="")), "udkf", steps=100,
                            langs=("python",), values={"dt": 0.5, "q": 0.2})
    assert [r.passed for r in results] == [True], results


@pytest.mark.parametrize("values, message", [
    ([], r"none for \['dt'\] \(give each an example.*or --values dt=V\)$"),
    (["--values", "speed=1"], r"--values names 'speed', which is not a free parameter"),
    (["--values", "dt=fast"], r"--values 'dt=fast': expected NAME=V"),
])
def test_verify_without_a_value_or_with_a_bad_one_is_one_line(tmp_path, capsys, values,
                                                             message):
    path = tmp_path / "plain.toml"
    path.write_text(PLAIN.format(example=""))
    assert main(["verify", str(path), "--filter", "kf", "--steps", "20", *values]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err


def test_derive_verify_ins_gnss_passes(capsys):
    assert main(["verify", "ins_gnss", "--steps", "200"]) == 0
    out = capsys.readouterr().out
    assert [line.split()[:4] for line in out.splitlines() if line.startswith("ok")][:2] == [
        ["ok", "ins_gnss", "ekf", "python"], ["ok", "ins_gnss", "ekf", "c"]]


@pytest.mark.parametrize("entry, message", [
    ('dt = { value = 0.1, example = 0.1 }', r"\[parameters\] dt example: only a free parameter"),
    ('dt = { example = "fast" }', r"\[parameters\] dt example: must be a number, got string"),
])
def test_bad_examples_in_a_model_file_are_refused(entry, message):
    text = CART.format(example="").replace('dt = { description = "step (s), free" }', entry)
    with pytest.raises(ModelError, match=message):
        loads_model(text)


def test_bad_examples_through_the_api_are_refused():
    kwargs = dict(F=[[1, "dt"], [0, 1]], Q=[[1, 0], [0, 1]], parameters=["dt"],
                  sensors=[Sensor("gps", ["zp"], H=[[1, 0]], R=[[1]])])
    with pytest.raises(SymbolError, match="example given for 'q', which is not a free"):
        LinearModel("m", ["p", "v"], **kwargs, examples={"q": 1.0})
    with pytest.raises(SymbolError, match="example of 'dt' must be a finite number"):
        LinearModel("m", ["p", "v"], **kwargs, examples={"dt": float("nan")})



def test_the_data_of_size_and_library_run_the_examples_as_verify_does():
    """derive size --qemu and --layout library embed run's arguments: p one row per step
    of the examples for a model without sensors too."""
    model = loads_model(PLAIN.format(example=", example = 0.1"))
    data = verification_data(model, "kf", {"precision": "double"}, steps=20)
    assert list(data.inputs) == ["z", "x0", "P0", "p"]
    assert (data.inputs["p"] == [[0.1, 0.01]] * 20).all()
