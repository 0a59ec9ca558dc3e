"""A NaN in z without the option ``missing``: before, every later state was NaN and the
status 0. Now every program that reads z checks each element is not NaN (one comparison
per measurement per step, after the checks the program had, one status for them all): C
returns the status the header lists, derive.build's wrappers and the generated Python run
name the step and the measurement. With ``missing`` (a NaN means absent), in a sensors run
(a NaN row is a silent sensor) and in the FIR (finite memory) there is no such check."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from derive import LinearModel, Sensor, batch, build_c, catalog, load_python
from derive.errors import NumericalError
from derive.filters import derive_unit, kind
from derive.flops import count
from derive.options import validate
from derive.runs.unit import LOOKAHEAD_NEXT
from derive.statements import PRESENT, Check

ROOT = Path(__file__).resolve().parents[2]
MODEL = "gps_static"
#: a covariance filter, a steady one with a two-step pass and run_tracks, the UD filter
#: (enter and store programs), the smoother and the predictor
FILTERS = ("kf", "sskf", "udkf", "rts", "pred")


@pytest.fixture(scope="module")
def c_module():
    """The catalog's generated files of MODEL's FILTERS and ctrv_radar's EKF, one build."""
    return build_c([ROOT / "generated" / MODEL / f"{f}.c" for f in FILTERS]
                   + [ROOT / "generated" / "ctrv_radar" / "ekf.c"])


def _nan_run(model, step: int, index: int, steps: int = 12):
    zs = np.random.default_rng(step).normal(size=(steps, model.m))
    zs[step, index] = np.nan
    return (zs, np.array(model.x0, dtype=float).ravel(),
            np.array(model.P0, dtype=float))


@pytest.mark.parametrize("step", [6, 7], ids=["first of a pass", "second of a pass"])
@pytest.mark.parametrize("name", FILTERS + ("ekf",))
def test_a_nan_in_z_is_refused_naming_the_step_and_the_measurement(c_module, name, step):
    """Both steps of a two-step pass (the steady filters' C run), every run kind that reads
    z, Python and C: the error names the step, the measurement and its index; the C status
    is the one the header's interface lists for the step's measurements."""
    model_name = "ctrv_radar" if name == "ekf" else MODEL
    model = catalog.load(model_name)
    index = model.m - 1
    zs, x0, P0 = _nan_run(model, step, index)
    module = c_module[f"{model_name}_{name}"]
    takes_P0 = any(a.name == "P0" for a in module.functions["run"].arguments)
    args = (zs, x0) + ((P0,) if takes_P0 else ())
    python = load_python(ROOT / "generated" / model_name / f"{name}.py")
    expected = f"step {step}: {model.measurements[index]} (z[{index}]): measurement is NaN ("
    (status,) = [s for s in module.interface.statuses
                 if s.program == "step" and s.present == ("z", tuple(model.measurements))]
    with pytest.raises(NumericalError) as raised:
        module.run(*args)
    assert str(raised.value).startswith(
        f"{model_name}_{name}_run failed with status {status.number}: {expected}")
    with pytest.raises(NumericalError) as raised:
        python.run(*args)
    assert str(raised.value).startswith(expected)


def test_run_tracks_names_the_step_and_the_track(c_module):
    """run_tracks names the track (its index in the arrays given, as for a pattern
    failure); derive.batch puts the slice of tracks in front."""
    model = catalog.load(MODEL)
    zs, x0, _ = _nan_run(model, 5, 1)
    tracks = np.stack([np.nan_to_num(zs, nan=0.0), zs])  # track 1 holds the NaN
    sskf = c_module[f"{MODEL}_sskf"]
    expected = rf"step 5 \(track 1\): {model.measurements[1]} \(z\[1\]\): measurement is NaN"
    with pytest.raises(NumericalError, match=expected):
        sskf.run_tracks(tracks, np.stack([x0, x0]))
    with pytest.raises(NumericalError, match=r"^tracks 1 to 1 .*step 5 \(track 0\): "):
        batch.run_tracks(sskf, tracks, np.stack([x0, x0]), workers=2)


@pytest.mark.parametrize("name", ["kf", "sskf", "ekf"])
def test_each_measurement_costs_one_comparison_and_nothing_else(name):
    """The step's count with the checks is the count without them, plus m comparisons
    (static count, C and Python); the two-step map checks z(k+1) alone (z(k) is its
    step's), numbered as the step's checks of the same measurement."""
    model = catalog.load("ctrv_radar" if name == "ekf" else MODEL)
    spec = kind(name)
    checked = derive_unit(model, name)
    plain = spec.derive(model, spec, validate(name, None))
    for lang in ("c", "python"):
        with_checks = count(checked.programs["step"], lang)
        without = count(plain.programs["step"], lang)
        assert with_checks == replace(without, cmp=without.cmp + model.m), lang
    if plain.lookahead is not None:
        map_checks = [c for c in checked.lookahead.body if c not in plain.lookahead.body]
        assert [c.value for c in map_checks] == [
            checked.lookahead.element(LOOKAHEAD_NEXT, i) for i in range(model.m)]


def _presence_checks(unit) -> list[Check]:
    return [c for program in unit.programs.values() for c in program.body
            if isinstance(c, Check) and c.relation == PRESENT]


def test_no_check_where_a_nan_means_absent():
    """``missing``, a sensors run (two sensors) and the FIR read NaN as they did."""
    model = catalog.load(MODEL)
    assert _presence_checks(derive_unit(model, "kf"))
    assert not _presence_checks(derive_unit(model, "kf", {"missing": True}))
    assert not _presence_checks(derive_unit(model, "fir"))
    cart = LinearModel("cart", ["p", "v"], F=[[1, 0.1], [0, 1]], Q=[[0.01, 0], [0, 0.01]],
                       sensors=[Sensor("gps", ["zp"], H=[[1, 0]], R=4),
                                Sensor("speed", ["zv"], H=[[0, 1]], R=0.25)])
    assert not _presence_checks(derive_unit(cart, "kf"))
