"""`derive verify` on ill-conditioned linear models: the double bound c u64 L G kappa.

Two correct double implementations of a model whose update cancels (a constant-velocity
model with dt = 1e3 s: P(k/k-1) is 1e5 times P(k/k)) differ by more than 1e-12; the
verification holds them to the same rounding bound a float32 filter is held to, at double's
unit roundoff, where that is above 1e-12, and reports a model double cannot carry (bound
>= 1) as failed. A wrong filter still fails. A simulation that leaves the range of a double
is refused with one line naming the step, before any filter runs.
"""

from __future__ import annotations

import tempfile
import warnings

import numpy as np
import pytest
from test_nav_sensors import TWO_SENSORS  # the two-sensor cart of the sensors tests

from derive.apps.float_tolerance import float_tolerance, in_double
from derive.apps.simulate import simulate_linear
from derive.apps.verify import (
    LINEAR_TOLERANCE,
    conditioning_run,
    linear_run,
    reference_run,
    verify_filter,
    verify_modules,
)
from derive.cli import main
from derive.errors import ModelError
from derive.generation import command_unit
from derive.modelfile import loads_model
from derive.options import validate
from derive.pipeline import load_generated
from derive.precision import DOUBLE, FLOAT

CV = """
[model]
name = "cv_dt"
states = ["s", "v"]
measurements = ["z"]

[parameters]
dt = {{ value = {dt} }}

[discrete]
F = [[1, "dt"], [0, 1]]
G = [[0.5], [1]]
H = [[1, 0]]
Q = [[0.01]]
R = [[0.1]]
"""
FREE_DT = 'dt = { description = "step, one value per step in p" }'
STEPS = 400


def cv(dt: str):
    return loads_model(CV.format(dt=dt))


def double_bound(model, name="kf", steps=STEPS):
    """The double bound of ``name`` on verify's own run, derived as verify does."""
    opts = validate(name, {})
    zs = linear_run(model, steps, 7)
    xs, Ps = reference_run(model, name, zs, opts, None)
    unit = command_unit(model, name, opts)
    return in_double(float_tolerance(model, unit, steps,
                                     conditioning_run(model, zs, None, xs, Ps)))


def test_the_double_bound_is_the_float_bound_at_u64_with_the_input_rounding_dropped():
    model = cv("1")
    opts = validate("kf", {})
    zs = linear_run(model, STEPS, 7)
    xs, Ps = reference_run(model, "kf", zs, opts, None)
    unit = command_unit(model, "kf", opts)
    single = float_tolerance(model, unit, STEPS, conditioning_run(model, zs, None, xs, Ps))
    double = in_double(single)
    assert single.unit_roundoff == FLOAT.unit_roundoff
    assert double.unit_roundoff == DOUBLE.unit_roundoff
    assert double.roundings == single.roundings - 1
    assert (double.growth, double.condition) == (single.growth, single.condition)
    assert "u64" in double.text() and "2^-53" in double.text()
    assert double.precision_name == "double" and single.precision_name == "float32"


def test_a_well_conditioned_model_keeps_the_bar_of_1e_12():
    results = verify_filter(cv("1"), "kf", steps=STEPS)
    assert all(v.passed and v.tolerance == LINEAR_TOLERANCE and v.bound is None
               for v in results)


@pytest.mark.parametrize("dt", ["1e3", "1e6"])
def test_an_ill_conditioned_model_is_held_to_its_double_bound(dt):
    """Above 1e-12 the error is judged against c u64 L G kappa, printed on the line."""
    model = cv(dt)
    bound = double_bound(model)
    assert bound.value > LINEAR_TOLERANCE, "the model must be ill-conditioned for this test"
    results = verify_filter(model, "kf", steps=STEPS)
    for v in results:
        assert v.error > LINEAR_TOLERANCE
        assert v.passed, v.line()
        assert v.tolerance == bound.value and v.bound == bound
        assert "c u64 L G kappa" in v.line() and " f32 " not in v.line()


def test_a_wrong_filter_still_fails_against_the_double_bound():
    """The same ill-conditioned model with a filter whose P is 1e-3 off: beyond the bound."""
    model = cv("1e3")
    opts = validate("kf", {})

    class Wrong:
        def __init__(self, module):
            self.module = module

        def run(self, *args):
            xs, Ps = self.module.run(*args)
            return xs, np.asarray(Ps) * (1 + 1e-3)

    with tempfile.TemporaryDirectory() as tmp:
        generated = load_generated(model, "kf", opts, "python", tmp)
        module = generated.module("python")
        (v,) = verify_modules(model, "kf", {"python": Wrong(module)}, STEPS, 7, {},
                              generated.unit)
    assert not v.passed
    assert v.bound is not None and v.error > v.tolerance > LINEAR_TOLERANCE


def test_a_model_double_cannot_carry_fails_and_says_so(tmp_path, capsys):
    model = cv("1e10")
    bound = double_bound(model)
    assert bound.value >= 1
    results = verify_filter(model, "kf", steps=STEPS)
    assert not any(v.passed for v in results)
    assert all("double cannot carry it" in v.line() for v in results)
    path = tmp_path / "cv.toml"
    path.write_text(CV.format(dt="1e10"))
    assert main(["verify", str(path), "--filter", "kf", "--steps", str(STEPS)]) == 1
    err = capsys.readouterr().err
    assert "2 of them on a model their precision cannot carry" in err


def test_a_sensors_model_is_held_to_its_double_bound():
    """The run kind sensors (two sensors at their own rates): the same rule."""
    model = loads_model(TWO_SENSORS.replace(FREE_DT, "dt = { example = 1e3 }"))
    results = verify_filter(model, "kf", steps=300)
    assert all(v.passed for v in results), [v.line() for v in results]
    assert all(v.bound is not None and v.bound.precision_name == "double"
               and v.tolerance == v.bound.value > LINEAR_TOLERANCE for v in results)


def test_a_truth_that_overflows_is_refused_naming_the_step():
    F, G, H = np.array([[1.0, 1e308], [0.0, 1.0]]), np.array([[0.5], [1.0]]), np.eye(1, 2)
    with pytest.raises(ModelError, match=r"not finite at step \d+ of 1000 .*--steps"):
        simulate_linear(F, G, H, [[0.01]], [[0.1]], [0.0, 0.0], 1000, 7)


def test_verify_of_a_truth_that_overflows_is_one_line_and_exit_2(tmp_path, capsys):
    path = tmp_path / "cv.toml"
    path.write_text(CV.format(dt="1e308"))
    with warnings.catch_warnings():   # NumPy's overflow warning printed file and line
        warnings.simplefilter("error")
        assert main(["verify", str(path), "--filter", "kf"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the simulated truth is not finite at step" in err[0]
