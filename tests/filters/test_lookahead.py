"""The two-step map (derive.runs.kinds.two_steps): the steady-state C run takes two steps
per pass through the exact two-step map; it must agree with stepping, keep the odd step and
the first step of each pass exact, and not drift over long runs."""

import re
from dataclasses import replace

import numpy as np
import pytest
import sympy
from _backend_kf import steady_unit
from _random_models import stable_models
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import catalog
from derive.apps.simulate import simulate_linear
from derive.apps.verify import relative_error
from derive.filters.steady import baked, steady_gains
from derive.generation import derive_unit, render_filter
from derive.pipeline import load_generated
from derive.program import ProgramError
from derive.reference import steady as reference
from derive.runs.unit import LOOKAHEAD_NEXT as ZNEXT
from derive.statements import Assign


def _two_step(model, name="sskf"):
    """The two-step map the derivation hands over with its unit."""
    return derive_unit(catalog.load(model), name, {}).lookahead


def _outputs(program, port):
    """``port``'s outputs of an optimised program as expressions in the input elements."""
    values = {}
    for statement in program.body:
        if isinstance(statement, Assign):  # a check (z present, a pivot) computes nothing
            values[statement.target] = statement.expr.xreplace(values)
    return [sympy.expand(e.xreplace(values)) for e in program.results[port]]


def test_the_two_step_map_is_exact():
    """x(k+2) = A^2 x + AB z(k) + B z(k+1) with the products of the baked doubles taken
    exactly (rounded once when printed)."""
    model = catalog.load("mpt3d_b")
    A, B = (baked(M) for M in steady_gains(model, "sskf"))
    two = _two_step("mpt3d_b")
    assert [p.name for p in two.inputs] == ["x", "z", ZNEXT]
    x = sympy.Matrix([two.element("x", i) for i in range(2)])
    z = sympy.Matrix([two.element("z", 0)])
    zn = sympy.Matrix([two.element(ZNEXT, 0)])
    new = _outputs(two, "x_new")
    assert new == [sympy.expand(e) for e in (A * A) * x + (A * B) * z + B * zn]


def test_the_pass_runs_the_steps_own_statements_first():
    """In the C pass, x(k+1) is the step's own body (written to x_mid), then the map's
    body; each body's statements are printed once, outside run."""
    model = catalog.load("mpt3d_a")
    c = render_filter(model, "sskf", "c")["sskf.c"]
    run = c[c.index("two steps per pass:"):c.index("an odd last step")]
    step = run.index("mpt3d_a_sskf_step_body(x, zk, x_mid, 1);")
    assert run.index("mpt3d_a_sskf_pass_body(x, zk, znk, x_new, 1);") > step
    assert "const double t" not in run
    for body in ("step", "pass"):
        text = c[c.index(f"mpt3d_a_sskf_{body}_body(const double"):]
        text = text[:text.index("\n}")]
        temps = [int(t) for t in re.findall(r"const double t(\d+) =", text)]
        assert temps == list(range(len(temps)))


def test_the_pass_is_declined_where_it_does_not_apply():
    """Only a derivation that builds the map has one; a run kind without look-ahead
    refuses it."""
    assert _two_step("mpt3d_b", "kf") is None                           # checks, P
    assert steady_unit("jssklf", params=True).lookahead is None
    two = _two_step("mpt3d_b")
    kf = derive_unit(catalog.load("mpt3d_b"), "kf", {})
    with pytest.raises(ProgramError, match="two-step map"):
        replace(kf, lookahead=two)


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    model = catalog.load("mpt3d_a")
    sskf = load_generated(model, "sskf", lang="c", directory=tmp_path_factory.mktemp("la"))
    assert "run: two steps per pass" in sskf.paths[".c"].read_text()
    assert "two steps per pass" not in render_filter(model, "kf", "c")["kf.c"]
    return model, sskf.c


@pytest.mark.parametrize("steps", [0, 1, 2, 7, 200])
def test_c_run_agrees_with_stepping(compiled, steps):
    model, mod = compiled
    num = model.numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, max(steps, 1), 5).zs[:steps]
    x0 = np.random.default_rng(2).normal(size=model.n)
    xs = mod.run(zs, x0)
    assert xs.shape == (steps, model.n)
    x, stepped = x0, []
    for z in zs:
        x = mod.step(x, z)
        stepped.append(x)
    if steps:
        # the first step of every pass is the step's own statements: row 0 is exact, and
        # an odd last step is the step itself from the carried state
        np.testing.assert_array_equal(xs[0], stepped[0])
        if steps % 2 and steps > 1:
            np.testing.assert_array_equal(xs[-1], mod.step(xs[-2], zs[-1]))
        assert relative_error(xs, np.array(stepped)) <= 1e-14


def test_c_run_does_not_drift_over_a_long_run(compiled):
    model, mod = compiled
    num = model.numeric()
    steps = 200_000
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, 9).zs
    xr = reference.sskf(num.F, num.G, num.H, num.Q, num.R, num.x0, zs)
    assert relative_error(mod.run(zs, num.x0), xr) <= 1e-12


@pytest.mark.parametrize("model_name", ["mpt3d_a", "gsm2d_a", "ca"])
def test_the_header_counts_the_pass_as_emitted(model_name):
    """The header's count of a pass equals the operators in the pass's C text (the
    bodies it calls counted as their statements)."""
    from derive.flops import count_c_calls

    c = render_filter(catalog.load(model_name), "sskf", "c")["sskf.c"]
    line = next(ln for ln in c.splitlines() if "operations per pass of run" in ln)
    header = line.split("): ", 1)[1]
    run = c[c.index("two steps per pass:"):c.index("an odd last step")]
    body = run[run.index("{", run.index("for (k = 0")) + 1:run.index("xs[k * ")]
    body = "\n".join(ln for ln in body.splitlines() if "const double *restrict" not in ln)
    assert count_c_calls(c, body).summary() == header


def test_the_predictor_runs_two_steps_per_pass_too(tmp_path):
    """pred: x(N/0) = init(x0), then the same pass as a steady-state filter; the C run
    agrees with init and stepping, and the Python run is bitwise its stepping."""
    model = catalog.load("cv")
    pred = load_generated(model, "pred", {"horizon": 3}, "all", tmp_path)
    assert "run: two steps per pass" in pred.paths[".c"].read_text()
    mod, py = pred.c, pred.python
    num = model.numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 301, 4).zs
    x0 = np.array([1.5, -0.5])
    x, stepped = mod.init(x0), []
    for z in zs:
        x = mod.step(x, z)
        stepped.append(x)
    xs = mod.run(zs, x0)
    np.testing.assert_array_equal(xs[0], stepped[0])
    assert relative_error(xs, np.array(stepped)) <= 1e-14
    x, expected = py.init(list(x0)), []
    for z in zs:
        x = py.step(x, z)
        expected.append(x)
    np.testing.assert_array_equal(py.run(zs, x0), np.array(expected))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stable_models(), st.integers(0, 1000))
def test_random_models_two_step_c_run_matches_reference(tmp_path_factory, model, seed):
    num = model.numeric()
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 301, seed)
    sskf = load_generated(model, "sskf", lang="c", directory=tmp_path_factory.mktemp("la"))
    assert "run: two steps per pass" in sskf.paths[".c"].read_text()
    xs = sskf.c.run(run.zs, num.x0)
    xr = reference.sskf(num.F, num.G, num.H, num.Q, num.R, num.x0, run.zs)
    assert relative_error(xs, xr) <= 1e-12
