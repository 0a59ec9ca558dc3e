"""Missing measurements (option ``missing``): a NaN in z(k)[i] means measurement i is absent
at step k, and the generated KF, LF, JKLF and IKF skip it exactly as the NumPy reference
``reference.kf(skip_nan=True)`` does (rows of H and z, rows and columns of R dropped), for
correlated R too; the selects cost no flop and keep the three counts equal."""

import shutil
import subprocess

import numpy as np
import pytest
import sympy

from derive import LinearModel, catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import LINEAR_TOLERANCE, relative_error
from derive.emit.python_printer import HELPERS, python_function
from derive.emit.render import render_unit
from derive.emit.write import write_files
from derive.expression_lowering import IfPresent, LoweringError, lower
from derive.filters import available, derive_unit
from derive.flops import CountingFloat, OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.pipeline import load_generated
from derive.program import InputElement
from derive.trees import Op, OpCount, Var

r = sympy.Symbol("r")


def correlated() -> LinearModel:
    """Three states, two measurements whose noises are correlated (R off-diagonal 0.2)."""
    return LinearModel("corr", ["s", "v", "a"], ["z1", "z2"],
                       [[1, 1, 0.5], [0, 1, 1], [0, 0, 1]], [[1, 0, 0], [0, 1, 0.5]],
                       [[0.01, 0, 0], [0, 0.02, 0], [0, 0, 0.1]], [[0.5, 0.2], [0.2, 0.3]],
                       P0=np.eye(3).tolist())


def free_noise() -> LinearModel:
    """Two measurements of a constant-velocity axis, the first one's variance r free."""
    return LinearModel("freer", ["s", "v"], ["zs", "zv"], [[1, 1], [0, 1]], [[1, 0], [0, 1]],
                       [[0.01]], [[r, 0], [0, 0.2]], G=[[0.5], [1]], P0=np.eye(2).tolist(),
                       parameters=[r])


def gappy(zs: np.ndarray, seed: int) -> np.ndarray:
    """``zs`` with about a third of the entries NaN, the first step, step 7 and steps
    40..45 entirely NaN.  (Much longer gaps let P grow by orders of magnitude and collapse
    at the next update; the per-step relative error of P then measures that cancellation,
    in the reference as much as in the generated code.)"""
    out = zs.copy()
    rng = np.random.default_rng(seed)
    out[rng.random(out.shape) < 0.3] = np.nan
    out[[0, 7]] = np.nan
    out[40:46] = np.nan
    return out


def scenario(model, steps=300, seed=4, params=None):
    num = model.numeric(params)
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed)
    zs = gappy(run.zs, seed)
    P0 = num.P0 if num.P0.any() else np.eye(model.n)
    xs, Ps = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs, skip_nan=True)
    return num, zs, P0, xs, Ps


CASES = [(name, f, {}) for name in ("mpt3d_a", "gps_static") for f in ("kf", "lf", "jklf", "ikf")
         if f in available(catalog.load(name))]
CASES += [("corr", f, {}) for f in ("kf", "lf", "jklf", "ikf")]
CASES += [("mpt3d_a", "kf", {"joseph": True}), ("corr", "kf", {"joseph": True}),
          ("freer", "kf", {}), ("freer", "lf", {}), ("freer", "ikf", {})]


def load(name):
    return {"corr": correlated, "freer": free_noise}.get(name, lambda: catalog.load(name))()


@pytest.mark.parametrize("name, filter_name, extra", CASES,
                         ids=[f"{n}-{f}{'-joseph' if e else ''}" for n, f, e in CASES])
def test_generated_filters_skip_missing_measurements_like_the_reference(
        name, filter_name, extra):
    model = load(name)
    params = {"r": 0.4} if model.parameters else None
    num, zs, P0, xr, Pr = scenario(model, params=params)
    generated = load_generated(model, filter_name, {"missing": True, **extra})
    p = [[0.4]] if params else []
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs, num.x0, P0, *p)
        assert np.all(np.isfinite(xs)) and np.all(np.isfinite(Ps))
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(np.reshape(Ps, Pr.shape), Pr) <= LINEAR_TOLERANCE


def test_a_missing_step_is_a_pure_prediction():
    model = catalog.load("mpt3d_b")
    num = model.numeric()
    module = load_generated(model, "kf", {"missing": True}, "python").python
    x, P = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    x_new, P_new = module.step(x, P.ravel(), [np.nan])
    np.testing.assert_array_equal(x_new, num.F @ x)
    np.testing.assert_allclose(np.reshape(P_new, (2, 2)), num.F @ P @ num.F.T + num.GQGt,
                               rtol=0, atol=1e-15)


def test_header_states_the_option(tmp_path):
    files = render_filter(catalog.load("mpt3d_a"), "kf", "all", {"missing": True})
    for name in ("kf.py", "kf.c", "kf.h"):
        assert "missing measurements: a NaN in z(k)[i] means measurement i is absent" \
            in files[name], name


def test_tracks_each_skip_their_own_missing_measurements():
    model = correlated()
    num = model.numeric()
    runs = [simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 60, s).zs
            for s in range(4)]
    zs = np.stack([gappy(z, s) for s, z in enumerate(runs)], axis=-1)  # (steps, m, tracks)
    zs[:, :, 3] = runs[3]  # one track without gaps
    module = load_generated(model, "kf", {"missing": True}, "python").python
    x0, P0 = np.zeros((3, 4)), np.repeat(np.eye(3)[:, :, None], 4, axis=2)
    xs, Ps = module.run(zs, x0, P0)
    for t in range(4):
        x1, P1 = module.run(zs[..., t], x0[:, t], P0[..., t])
        np.testing.assert_array_equal(xs[..., t], x1)
        np.testing.assert_array_equal(Ps[..., t], P1)


# -- cost and counting -----------------------------------------------------------------

def test_missing_support_costs_the_kalman_filter_no_flop():
    for name in catalog.names():
        model = catalog.load(name)
        if model.kind != "linear":
            continue
        plain = count(derive_unit(model, "kf", {}).programs["step"], "c")
        missing = count(derive_unit(model, "kf", {"missing": True}).programs["step"], "c")
        assert missing.flops == plain.flops, name
        assert missing.cmp > plain.cmp, name  # the selects (one z == z each)
        # the plain step checks each z once (not NaN), the masks' selects instead
        assert missing.select - plain.select == missing.cmp - plain.cmp + model.m, name
        assert missing.as_dict() | {"cmp": 0, "select": 0} == \
            plain.as_dict() | {"cmp": 0, "select": 0}, name


def _counted_run(program, inputs):
    counter = OpCounter()
    python_function(program)(*(counter.wrap(np.ravel(v)) for v in inputs))
    return counter.snapshot()


@pytest.mark.parametrize("filter_name", ["kf", "lf", "jklf", "ikf"])
def test_static_dynamic_and_c_text_counts_agree(filter_name):
    model = correlated()
    unit = derive_unit(model, filter_name, {"missing": True})
    step = unit.programs["step"]
    static = count(step, "python")
    x, P = np.array([0.3, -1.0, 0.2]), np.eye(3) + 0.1
    for z in ([1.0, 2.0], [np.nan, 2.0], [1.0, np.nan], [np.nan, np.nan]):
        assert _counted_run(step, (x, P, z)) == static
    for use_fma in (True, False):
        source = render_unit(unit, "c", use_fma=use_fma)[f"{filter_name}.c"]
        assert count_c_function(source, f"corr_{filter_name}_step") == \
            count(step, "c", use_fma=use_fma)


# -- the select operation --------------------------------------------------------------

z0, z1 = InputElement("z[0]"), InputElement("z[1]")
a, b = sympy.symbols("a b")


def test_if_present_folds_and_lowers_to_one_comparison_and_one_select():
    assert IfPresent(z0, a, a) == a
    assert IfPresent(sympy.Integer(3), a, b) == a
    assert IfPresent(sympy.nan, a, b) == b
    assert IfPresent(z0, -a, 0) == -IfPresent(z0, a, 0)
    assert IfPresent(z0, a, 0) * 0 == 0
    tree = lower(IfPresent(z0, a + b, 0))
    assert tree == Op("select", (Var("z[0]"), Op("add", (Var("a"), Var("b"))),
                                 lower(sympy.Integer(0))))
    prog_count = count_select(IfPresent(z0, IfPresent(z1, a, 0), 1))
    assert prog_count == OpCount(cmp=2, select=2)
    with pytest.raises(LoweringError, match="input element"):
        lower(IfPresent(a + b, a, 0))


def count_select(expr):
    from derive.trees import count_tree

    return count_tree(lower(expr))


def test_printers_spell_the_select():
    from derive.emit import c_printer, python_printer

    tree = lower(IfPresent(z0, -2 * a, 0))
    assert c_printer.expression(tree) == "-((z[0] == z[0]) ? 2.0*a : 0.0)"
    assert python_printer.expression(tree) == "-_if_present(z[0], 2.0*a, 0.0)"


def test_python_select_helper_on_floats_arrays_and_counting_floats():
    scope = {"np": np}
    exec("\n".join(HELPERS["select"]), scope)
    select = scope["_if_present"]
    assert select(1.0, 2.0, 3.0) == 2.0 and select(float("nan"), 2.0, 3.0) == 3.0
    assert select(np.float64(np.nan), 2.0, 3.0) == 3.0
    z = np.array([1.0, np.nan, 3.0])
    np.testing.assert_array_equal(select(z, np.array([7.0, np.nan, 9.0]), 0.0), [7.0, 0.0, 9.0])
    counter = OpCounter()
    (zc,) = counter.wrap([np.nan])
    result = select(zc, 1.0, 0.0)
    assert counter.snapshot() == OpCount(cmp=1, select=1)
    assert isinstance(result, CountingFloat) and result.value == 0.0
    assert result.counter is counter  # the constant is counted onwards
    (zp,) = counter.wrap([2.0])
    assert select(zp, result, 5.0) is result


def test_counting_float_equality_is_a_counted_comparison():
    counter = OpCounter()
    x, y = counter.wrap([1.0, np.nan])
    assert (x == x) is True and (y == y) is False and (x != y) is True
    assert counter.snapshot() == OpCount(cmp=3)
    with pytest.raises(TypeError):
        hash(CountingFloat(1.0, counter))


def test_c_select_survives_the_strict_flags():
    """``z == z`` compiles under -Wall -Wextra -Werror -pedantic and detects NaN."""
    model = correlated()
    module = load_generated(model, "kf", {"missing": True}, "c").c
    x_new, P_new = module.step(np.zeros(3), np.eye(3).ravel(), [np.nan, np.nan])
    num = model.numeric()
    np.testing.assert_array_equal(x_new, np.zeros(3))
    np.testing.assert_allclose(P_new.reshape(3, 3), num.F @ num.F.T + num.GQGt, atol=1e-15)


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff not installed")
def test_generated_python_with_selects_passes_ruff(tmp_path):
    files = {}
    for filter_name in ("kf", "lf", "ikf"):
        files.update(render_filter(correlated(), filter_name, "python", {"missing": True}))
    paths = [str(p) for p in write_files(tmp_path, "corr", files)]
    proc = subprocess.run([shutil.which("ruff"), "check", "--isolated", *paths],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
