"""derive.emit.python_loop: the single-track run of generated Python is the step's own
statements inline, so it must equal calling ``step`` once per step bit for bit."""

import numpy as np
import pytest
from _backend_kf import ekf_like_unit, kf_unit, steady_unit

from derive import catalog
from derive.errors import NumericalError
from derive.generation import render_filter
from derive.pipeline import load_units

P = [0.5, 0.02, 0.3]


@pytest.fixture(scope="module")
def modules():
    units = {"kf": kf_unit(axes=2), "sskf": steady_unit("sskf"),
             "jssklf": steady_unit("jssklf", params=True), "ekf": ekf_like_unit()}
    return {name: loaded.python
            for name, loaded in zip(units, load_units(list(units.values()), "python"))}


def _stepped_timevarying(module, zs, x0, P0, *extra_rows, p=None):
    x, P = list(x0), list(np.asarray(P0).reshape(-1))
    xs, Ps = [], []
    for k in range(len(zs)):
        args = [x, P, zs[k]] + [rows[k] for rows in extra_rows] + ([p] if p is not None else [])
        x, P = module.step(*args)
        xs.append(x)
        Ps.append(P)
    n = len(x0)
    return np.array(xs), np.array(Ps).reshape(-1, n, n)


def test_kf_run_is_step_by_step_bitwise(modules):
    rng = np.random.default_rng(5)
    zs, x0 = rng.normal(size=(300, 2)), rng.normal(size=4)
    P0 = np.diag([2.0, 1.0, 3.0, 0.5]) + 0.1
    xs, Ps = modules["kf"].run(zs, x0, P0, P)
    xr, Pr = _stepped_timevarying(modules["kf"], zs, x0, P0, p=P)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)
    assert xs.shape == (300, 4) and Ps.shape == (300, 4, 4)


def test_two_input_run_is_step_by_step_bitwise(modules):
    rng = np.random.default_rng(6)
    zs, us, x0 = rng.normal(size=(120, 1)), rng.normal(size=(120, 2)), rng.normal(size=2)
    xs, Ps = modules["ekf"].run(zs, us, x0, np.eye(2))
    xr, Pr = _stepped_timevarying(modules["ekf"], zs, x0, np.eye(2), us)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)


@pytest.mark.parametrize("name, p", [("sskf", None), ("jssklf", [1.5])])
def test_steady_run_is_step_by_step_bitwise(modules, name, p):
    rng = np.random.default_rng(7)
    zs, x0 = rng.normal(size=(200, 1)), rng.normal(size=2)
    module = modules[name]
    xs = module.run(zs, x0) if p is None else module.run(zs, x0, p)
    x, expected = list(x0), []
    for z in zs:
        x = module.step(x, z) if p is None else module.step(x, z, p)
        expected.append(x)
    np.testing.assert_array_equal(xs, np.array(expected))


def test_zero_steps_give_empty_arrays(modules):
    xs, Ps = modules["kf"].run(np.empty((0, 2)), np.zeros(4), np.eye(4), P)
    assert xs.shape == (0, 4) and Ps.shape == (0, 4, 4)
    assert modules["sskf"].run(np.empty((0, 1)), np.zeros(2)).shape == (0, 2)


def test_a_failed_check_names_the_step(modules):
    zs = np.zeros((10, 2))
    # a negative measurement variance makes S's first pivot negative at the first step
    with pytest.raises(NumericalError, match=r"^step 0: S is not positive definite"):
        modules["kf"].run(zs, np.zeros(4), np.zeros((4, 4)), [0.5, 0.02, -0.3])


def test_the_loop_reads_only_what_the_step_reads(tmp_path):
    """The symmetric P is carried by its upper triangle; state and input rows unpacked."""
    model = catalog.load("mpt3d_b")
    text = render_filter(model, "kf", "python", {})["kf.py"]
    branch = text[text.index("if not track:"):text.index("    Ps = np.empty")]
    assert "P_0, P_1, P_3 = P0.reshape(-1)[[0, 1, 3]].tolist()" in branch
    assert "P_2" not in branch
    assert "step(" not in branch
    assert 'for z_0 in array("d", zs.tobytes()):' in branch
