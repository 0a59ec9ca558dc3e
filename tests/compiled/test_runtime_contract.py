"""The generated code's runtime contract: which P0 it accepts, per-step parameters, the
argument shapes of run and step, derive.load_python, and header guards unique per model.

Item by item (issue "No silent wrong answers, no hangs, no tracebacks"):

1. code that relies on P's structural zeros refuses a P0 (or P) with a non-zero entry
   outside the pattern (Python: PatternError naming the entry; C: the status the header
   names), and a P0 inside the pattern still matches the reference;
2. run takes p as one row for every step or one row per step (C: p_stride);
3. zs of shape (steps,) when m = 1 and a 2-D (n, n) P are accepted, other shapes refused;
4. derive.load_python(path);
5. include guards and macros unique per model and filter, whatever the case of the names.
"""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy

import derive
from derive import LinearModel, NonlinearModel, catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import LINEAR_TOLERANCE, relative_error
from derive.build import STRICT_CFLAGS, build_c, load_python
from derive.errors import ModelError, PatternError, ShapeError
from derive.filters import derive_unit
from derive.flops import OpCounter, count, count_c_function
from derive.generation import generate, render_filter
from derive.pipeline import Generated, load_generated

ROOT = Path(__file__).resolve().parents[2]
GENERATED = ROOT / "generated"
GCC = shutil.which("gcc")

needs_gcc = pytest.mark.skipif(GCC is None, reason="no C compiler")


def _spd(n: int, seed: int) -> np.ndarray:
    A = np.random.default_rng(seed).normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def _loaded(tmp_path, model, name: str, options=None) -> Generated:
    """The filter written into tmp_path and loaded: its Python, and its C where gcc is."""
    return load_generated(model, name, options, "all" if GCC else "python", tmp_path)


def _modules(generated: Generated) -> list:
    return [generated.python] + ([generated.c] if GCC else [])


def _outside(unit) -> list[tuple[int, int]]:
    """(i, j), i <= j, of P that the step requires to be zero (its pattern checks)."""
    n = unit.n
    step = unit.programs["step"]
    flat = [int(str(c.value)[2:-1]) for c in step.body if getattr(c, "relation", "") == "zero"]
    return [divmod(k, n) for k in flat]


def _inside(P: np.ndarray, outside) -> np.ndarray:
    P = P.copy()
    for i, j in outside:
        P[i, j] = P[j, i] = 0.0
    return P


def _pattern_status(header: str) -> int:
    match = re.search(r"step (\d+): P has a non-zero entry outside the pattern", header)
    assert match, "the header names the pattern status"
    return int(match[1])


# -- 1. P0 outside the declared pattern ----------------------------------------------------


def test_mpt3d_a_kf_refuses_a_dense_P0_in_python_naming_the_entry():
    module = load_python(GENERATED / "mpt3d_a" / "kf.py")
    num = catalog.load("mpt3d_a").numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 20, 1).zs
    dense = _spd(6, 0)
    with pytest.raises(PatternError) as run_error:
        module.run(zs, num.x0, dense)
    message = str(run_error.value)
    assert message.startswith(f"P0[0][2] = {float(dense[0, 2])!r}: ")
    assert "xx....|xx....|..xx..|..xx..|....xx|....xx" in message
    assert "--P0-pattern dense" in message and "upper triangle" in message
    assert isinstance(run_error.value, ValueError)
    with pytest.raises(PatternError, match=re.escape(f"P[0][2] = {float(dense[0, 2])!r}: ")):
        module.step(num.x0, dense.ravel(), zs[0])
    one = dense * 0 + np.diag(np.diag(dense))
    one[5, 3] = one[3, 5] = 0.25  # one entry outside: named, wherever it is
    with pytest.raises(PatternError, match=r"P0\[3\]\[5\] = 0.25: "):
        module.run(zs, num.x0, one)
    nan = np.diag(np.diag(dense))
    nan[0, 4] = np.nan
    with pytest.raises(PatternError, match=r"P0\[0\]\[4\] = nan: "):
        module.run(zs, num.x0, nan)


@needs_gcc
def test_mpt3d_a_kf_refuses_a_dense_P0_in_c_with_the_status_the_header_names():
    module = build_c(GENERATED / "mpt3d_a" / "kf.c")
    header = (GENERATED / "mpt3d_a" / "kf.h").read_text()
    status = _pattern_status(header)
    assert ("P0 accepted: exactly those zero outside P's pattern "
            "xx....|xx....|..xx..|..xx..|....xx|....xx") in header
    num = catalog.load("mpt3d_a").numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 20, 1).zs
    dense = _spd(6, 0)
    ffi, lib = module.ffi, module.lib
    xs, Ps = np.zeros((20, 6)), np.zeros((20, 6, 6))
    buf = ffi.from_buffer
    raw = lib.mpt3d_a_kf_run(20, buf("double[]", np.ascontiguousarray(zs)),
                             buf("double[]", num.x0), buf("double[]", dense),
                             buf("double[]", xs), buf("double[]", Ps))
    assert raw == status != 0
    assert not xs.any(), "refused before the first step"
    x_new, P_new = np.zeros(6), np.zeros(36)
    assert lib.mpt3d_a_kf_step(buf("double[]", num.x0), buf("double[]", dense.ravel()),
                               buf("double[]", np.ascontiguousarray(zs[0])),
                               buf("double[]", x_new), buf("double[]", P_new)) == status
    with pytest.raises(PatternError, match=re.escape(f"P0[0][2] = {float(dense[0, 2])!r}")):
        module.run(zs, num.x0, dense)
    with pytest.raises(PatternError, match=re.escape(f"P[0][2] = {float(dense[0, 2])!r}")):
        module.step(num.x0, dense, zs[0])
    tracks = np.stack([_inside(dense, _outside(derive_unit(catalog.load("mpt3d_a"), "kf", {})))
                       ] * 3 + [dense])
    with pytest.raises(PatternError, match=r"P0\[0\]\[2\] = .* \(track 3\)"):
        module.run_tracks(np.stack([zs] * 4), np.zeros((4, 6)), tracks)


def test_run_checks_P0_once_and_its_loop_holds_no_pattern_check():
    c_text = (GENERATED / "mpt3d_a" / "kf.c").read_text()
    for function in ("mpt3d_a_kf_run", "mpt3d_a_kf_run_tracks"):
        body = re.search(rf"\b{function}\(size_t steps.*?\n}}\n", c_text, re.S)[0]
        loop = body[body.index("for (k = 0"):]
        assert "== 0.0" not in loop and "== 0.0" in body[:body.index("for (k = 0")]
    py_text = (GENERATED / "mpt3d_a" / "kf.py").read_text()
    run = py_text[py_text.index("def run("):]
    assert run.count("_require_zero(") == 1
    assert run.index("_require_zero(") < run.index("for k")
    assert "_require_zero" not in py_text[py_text.index("def _step_in_pattern("):
                                           py_text.index("def run(")]


@pytest.mark.parametrize("model_name, name", [("mpt3d_a", "kf"), ("mpt3d_a", "lf"),
                                               ("mpt3d_a", "jklf"), ("gps_static", "kf"),
                                               ("gps_static", "lf"), ("gps_static", "jklf"),
                                               ("gps_static", "ikf")])
def test_a_P0_inside_the_pattern_matches_the_reference_and_outside_is_refused(
        tmp_path, model_name, name):
    model = catalog.load(model_name)
    num = model.numeric()
    outside = _outside(derive_unit(model, name, {}))
    assert outside, "the declared pattern closes to a sparse P"
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 200, 5).zs
    dense = _spd(model.n, 3)
    inside = _inside(dense, outside)
    xr, Pr = getattr(reference, name)(num.F, num.G, num.H, num.Q, num.R, num.x0, inside, zs)
    generated = _loaded(tmp_path, model, name)
    modules = _modules(generated)
    for module in modules:
        xs, Ps = module.run(zs, num.x0, inside)
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(Ps, Pr) <= LINEAR_TOLERANCE
        i, j = outside[0]
        with pytest.raises(PatternError, match=re.escape(f"P0[{i}][{j}] = {float(dense[i, j])!r}")):
            module.run(zs, num.x0, dense)
    if GCC:  # run_tracks checks every track's P0 before the first step
        tracks = modules[-1].run_tracks(np.stack([zs] * 5), np.stack([num.x0] * 5),
                                        np.stack([inside] * 5))
        np.testing.assert_array_equal(tracks[0][4], modules[-1].run(zs, num.x0, inside)[0])
        with pytest.raises(PatternError, match=r"\(track 4\)"):
            modules[-1].run_tracks(np.stack([zs] * 5), np.stack([num.x0] * 5),
                                   np.stack([inside] * 4 + [dense]))


def _axis(name: str) -> LinearModel:
    dt = 0.5
    return LinearModel(name, ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[0.02]], [[0.3]],
                       G=[[dt / 2], [1]], x0=[0, 0], P0=[[1, 0.2], [0.2, 2]],
                       P0_pattern="dense")


def test_a_composed_model_refuses_cross_terms_between_its_blocks(tmp_path):
    model = LinearModel.compose("pair", [_axis("a"), _axis("b")], suffixes=["a", "b"])
    assert model.P0_pattern == "block"
    num = model.numeric()
    unit = derive_unit(model, "kf", {})
    outside = _outside(unit)
    assert sorted(outside) == [(0, 2), (0, 3), (1, 2), (1, 3)]
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 150, 2).zs
    dense = _spd(4, 9)
    inside = _inside(dense, outside)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, inside, zs)
    generated = _loaded(tmp_path, model, "kf")
    for module in _modules(generated):
        with pytest.raises(PatternError, match=re.escape(f"P0[0][2] = {float(dense[0, 2])!r}")):
            module.run(zs, num.x0, dense)
        xs, Ps = module.run(zs, num.x0, inside)
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(Ps, Pr) <= LINEAR_TOLERANCE
    # the counts still agree three ways: static, CountingFloat on the Python, the C text
    step = unit.programs["step"]
    static = count(step, "python")
    # two pivots, one comparison per entry outside, one per measurement (not NaN)
    assert static.cmp == 2 + len(outside) + model.m
    texts = render_filter(model, "kf", "all")
    scope: dict = {}
    exec(compile(texts["kf.py"], "kf.py", "exec"), scope)
    counter = OpCounter()
    P = counter.wrap(inside.ravel())
    scope["step"](counter.wrap(num.x0), P, counter.wrap(zs[0]))
    assert counter.snapshot() == static
    assert count_c_function(texts["kf.c"], "pair_kf_step") == count(step, "c")
    assert f"operations per call of step (Python): {static.summary()}" in texts["kf.py"]


def test_a_dense_closed_pattern_emits_no_check(tmp_path):
    model = catalog.load("mpt3d_a")
    unit = derive_unit(model, "kf", {"P0_pattern": "dense"})
    assert not _outside(unit)
    texts = render_filter(model, "kf", "all", {"P0_pattern": "dense"})
    assert "_require_zero" not in texts["kf.py"] and "== 0.0" not in texts["kf.c"]
    assert "outside the pattern" not in texts["kf.h"]
    assert "P0 accepted: any symmetric P0" in texts["kf.h"]


def _two_blocks_nonlinear(name: str = "twin", pattern: str = "diagonal") -> NonlinearModel:
    a, b = sympy.symbols("a b")
    return NonlinearModel(name, ["a", "b"], ["ya", "yb"],
                          [a + sympy.Rational(1, 10) * sympy.sin(a), b],
                          [sympy.sqrt(a ** 2 + 1), b], [[0.01, 0], [0, 0.02]],
                          [[0.1, 0], [0, 0.2]], x0=[0.5, -0.3], P0=[[1, 0], [0, 2]],
                          P0_pattern=pattern)


def _nonlinear_reference(model, unit, name, zs, x0, P0):
    fns = model.numeric_functions()
    if name == "ekf":
        return reference.ekf(fns["f"], fns["F"], lambda x: fns["h"](x), lambda x: fns["H"](x),
                             fns["Q"], fns["R"], x0, P0, zs, skip_nan=False)
    w = unit.options
    return reference.ukf(fns["f"], lambda x: fns["h"](x), fns["Q"], fns["R"], x0, P0, zs,
                         alpha=w["alpha"], beta=w["beta"], kappa=w["kappa"], skip_nan=False)


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_nonlinear_filters_refuse_P_outside_the_pattern_in_every_function(tmp_path, name):
    """The EKF keeps a diagonal P diagonal here, so its step, predict and run check P; so
    does the UKF: its spreads in difference form are D = g(x + δ) - g(x), structurally
    zero in b for a sigma point that moves only a (f and h of two independent blocks),
    so its sigma-point covariance folds to the same diagonal pattern."""
    model = _two_blocks_nonlinear()
    unit = derive_unit(model, name, {})
    assert _outside(unit) == [(0, 1)]
    generated = _loaded(tmp_path, model, name)
    zs = np.random.default_rng(1).normal(size=(30, 2))
    x0, P0 = np.array([0.5, -0.3]), np.array([[1.0, 0.3], [0.3, 2.0]])
    diag = np.diag(np.diag(P0))
    modules = _modules(generated)
    for module in modules:
        with pytest.raises(PatternError, match=r"P0\[0\]\[1\] = 0.3"):
            module.run(zs, x0, P0)
        for function, args in (("step", (x0, P0.ravel(), zs[0])), ("predict", (x0, P0))):
            assert function in unit.programs
            with pytest.raises(PatternError, match=r"P\[0\]\[1\] = 0.3"):
                getattr(module, function)(*args)
        start = diag
        res = _nonlinear_reference(model, unit, name, zs, x0, start)
        xs, Ps = module.run(zs, x0, start)
        assert relative_error(xs, res.xs) <= 1e-10 and relative_error(Ps, res.Ps) <= 1e-10


# -- 2. per-step parameters -----------------------------------------------------------------


def _free_axis() -> LinearModel:
    """A constant-velocity axis with free dt and q (measurement noise fixed)."""
    dt, q = sympy.symbols("dt q")
    return LinearModel("freeaxis", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]],
                       [[q]], [[0.25]], G=[[dt ** 2 / 2], [dt]], x0=[0, 1],
                       P0=[[4, 0.5], [0.5, 1]], parameters=[dt, q])


def _stepped_reference_kf(model, zs, rows, x0, P0):
    """reference.kf one step at a time, the model at each step's parameters (dt, q)."""
    x, P = np.asarray(x0, float), np.asarray(P0, float)
    xs, Ps = [], []
    for z, (dt, q) in zip(zs, rows):
        num = model.numeric({"dt": float(dt), "q": float(q)})
        x_next, P_next = reference.kf(num.F, num.G, num.H, num.Q, num.R, x, P, z[None, :])
        x, P = x_next[0], P_next[0]
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)


def test_run_takes_one_parameter_row_per_step(tmp_path):
    model = _free_axis()
    generated = _loaded(tmp_path, model, "kf")
    rng = np.random.default_rng(11)
    steps = 120
    rows = np.column_stack([rng.uniform(0.05, 2.0, steps), rng.uniform(0.001, 0.1, steps)])
    zs = np.cumsum(rng.normal(size=(steps, 1)), axis=0)
    x0, P0 = np.array([0.0, 1.0]), np.array([[4.0, 0.5], [0.5, 1.0]])
    xr, Pr = _stepped_reference_kf(model, zs, rows, x0, P0)
    modules = _modules(generated)
    for module in modules:
        xs, Ps = module.run(zs, x0, P0, rows)
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(Ps, Pr) <= LINEAR_TOLERANCE
        # one row for every step is the same as that row repeated, bit for bit
        one = module.run(zs, x0, P0, rows[0])
        repeated = module.run(zs, x0, P0, np.repeat(rows[:1], steps, axis=0))
        np.testing.assert_array_equal(one[0], repeated[0])
        np.testing.assert_array_equal(one[1], repeated[1])
        with pytest.raises(ShapeError, match=r"'?p'? must have shape \(2,\) or \(120, 2\)|"
                                             r"p must have shape \(2,\) or \(steps, 2\)"):
            module.run(zs, x0, P0, rows[:-1])
    header = generated.paths[".h"].read_text()
    assert "p[2] rows p_stride" in header and "p_stride 0" in header
    assert "size_t p_stride);" in header


@needs_gcc
def test_run_tracks_takes_parameter_rows_shared_by_the_tracks(tmp_path):
    model = _free_axis()
    module = _loaded(tmp_path, model, "kf").c
    rng = np.random.default_rng(2)
    steps, tracks = 40, 6
    rows = np.column_stack([rng.uniform(0.1, 1.0, steps), rng.uniform(0.01, 0.1, steps)])
    zs = rng.normal(size=(tracks, steps, 1))
    x0 = rng.normal(size=(tracks, 2))
    P0 = np.stack([np.eye(2) * (1 + t) for t in range(tracks)])
    xs, Ps = module.run_tracks(zs, x0, P0, rows)
    for t in range(tracks):
        x1, P1 = module.run(zs[t], x0[t], P0[t], rows)
        np.testing.assert_array_equal(xs[t], x1)
        np.testing.assert_array_equal(Ps[t], P1)


def _free_nonlinear() -> NonlinearModel:
    a, b, q = sympy.symbols("a b q")
    return NonlinearModel("freenl", ["a", "b"], ["y"], [a + sympy.Rational(1, 10) * b, b],
                          [sympy.sqrt(a ** 2 + 1) + b], [[q, 0], [0, q]], [[0.1]],
                          x0=[0.5, 0.1], P0=[[1, 0.1], [0.1, 1]], parameters=[q])


def test_ekf_run_takes_one_parameter_row_per_step(tmp_path):
    model = _free_nonlinear()
    generated = _loaded(tmp_path, model, "ekf")
    rng = np.random.default_rng(4)
    steps = 60
    rows = rng.uniform(0.001, 0.05, (steps, 1))
    zs = 1.0 + rng.normal(size=(steps, 1)) * 0.3
    x, P = np.array([0.5, 0.1]), np.array([[1.0, 0.1], [0.1, 1.0]])
    xr, Pr = [], []
    for z, (q,) in zip(zs, rows):
        fns = model.numeric_functions({"q": float(q)})
        res = reference.ekf(fns["f"], fns["F"], lambda s, f=fns: f["h"](s),
                            lambda s, f=fns: f["H"](s), fns["Q"], fns["R"], x, P, z[None, :],
                            skip_nan=False)
        x, P = res.xs[0], res.Ps[0]
        xr.append(x)
        Pr.append(P)
    modules = _modules(generated)
    for module in modules:
        xs, Ps = module.run(zs, np.array([0.5, 0.1]), np.array([[1.0, 0.1], [0.1, 1.0]]), rows)
        assert relative_error(xs, np.array(xr)) <= 1e-12
        assert relative_error(Ps, np.array(Pr)) <= 1e-12


# -- 3. shapes users try ------------------------------------------------------------------


def test_scalar_measurements_and_a_square_P_are_accepted(tmp_path):
    model = catalog.load("mpt3d_b")
    num = model.numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 50, 8).zs
    P0 = _spd(2, 1)
    generated = _loaded(tmp_path, model, "kf")
    modules = _modules(generated)
    for module in modules:
        xs, Ps = module.run(zs, num.x0, P0)
        xs1, Ps1 = module.run(zs[:, 0], num.x0, P0)  # (steps,) for m = 1
        np.testing.assert_array_equal(xs, xs1)
        np.testing.assert_array_equal(Ps, Ps1)
        x_flat, P_flat = module.step(num.x0, P0.ravel(), zs[0])
        x_square, P_square = module.step(num.x0, P0, zs[0])  # 2-D (n, n) P
        np.testing.assert_array_equal(np.asarray(x_flat, float), np.asarray(x_square, float))
        np.testing.assert_array_equal(np.asarray(P_flat, float), np.asarray(P_square, float))


def test_wrong_shapes_are_refused_naming_the_argument_and_the_shapes(tmp_path):
    model = catalog.load("mpt3d_a")
    num = model.numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 10, 8).zs
    generated = _loaded(tmp_path, model, "kf")
    py = generated.python
    cases = [((zs.T, num.x0, np.eye(6)), "zs", r"\(steps, 3\)", r"\(3, 10\)"),
             ((zs, num.x0[:4], np.eye(6)), "x0", r"\(6,\)", r"\(4,\)"),
             ((zs, num.x0, np.eye(5)), "P0", r"\(6, 6\)", r"\(5, 5\)")]
    for args, name, want, got in cases:
        with pytest.raises(ShapeError, match=rf"run: {name} must have shape {want}.*got {got}"):
            py.run(*args)
    if GCC:
        c = generated.c
        c_cases = [((zs.T, num.x0, np.eye(6)), "z", r"\(3, 3\)", r"\(3, 10\)"),
                   ((zs, num.x0[:4], np.eye(6)), "x0", r"\(6,\)", r"\(4,\)"),
                   ((zs, num.x0, np.eye(5)), "P0", r"\(6, 6\)", r"\(5, 5\)")]
        for args, name, want, got in c_cases:
            with pytest.raises(ShapeError, match=rf"argument '{name}' must have shape {want}"
                                                 rf".*got {got}"):
                c.run(*args)


# -- 4. a public loader ---------------------------------------------------------------------


def test_load_python_is_public_and_loads_each_file_as_its_own_module(tmp_path):
    assert derive.load_python is load_python
    a = load_python(GENERATED / "mpt3d_a" / "kf.py")
    b = load_python(GENERATED / "mpt3d_b" / "kf.py")
    assert a is not b and a.__name__ != b.__name__
    assert a.run.__doc__ and b.step is not a.step
    with pytest.raises(ModelError, match="nope.py"):
        load_python(tmp_path / "nope.py")
    with pytest.raises(ModelError, match="kf.c"):
        load_python(GENERATED / "mpt3d_a" / "kf.c")


# -- 5. header guards and macros ------------------------------------------------------------


@needs_gcc
def test_two_models_differing_only_in_case_can_be_included_together(tmp_path):
    for name, folder in (("Axis", "one"), ("axis", "two")):
        generate(_axis(name), ["kf", "sskf"], "c", tmp_path / folder)
    main = tmp_path / "main.c"
    main.write_text(
        '#include "one/Axis/kf.h"\n#include "two/axis/kf.h"\n'
        '#include "one/Axis/sskf.h"\n#include "two/axis/sskf.h"\n'
        "int main(void)\n{\n"
        "    double x[Axis_kf_N] = {0.0, 0.0}, P[Axis_kf_N * axis_kf_N] = {1.0, 0.0, 0.0, 1.0};\n"
        "    double z[axis_kf_M] = {1.0}, x1[2], P1[4], x2[2], P2[4], x3[2];\n"
        "    int status = Axis_kf_step(x, P, z, x1, P1) + axis_kf_step(x, P, z, x2, P2);\n"
        "    axis_sskf_step(x, z, x3);\n"
        "    return status != 0 || x1[0] != x2[0] || Axis_sskf_N != 2;\n}\n")
    objects = []
    for c_file in [main] + sorted(tmp_path.glob("*/*/*.c")):
        obj = c_file.with_suffix(".o")
        subprocess.run([GCC, *STRICT_CFLAGS, "-I", str(tmp_path), "-c", str(c_file),
                        "-o", str(obj)], check=True, capture_output=True, text=True)
        objects.append(str(obj))
    program = tmp_path / "both"
    subprocess.run([GCC, *objects, "-o", str(program), "-lm"], check=True)
    assert subprocess.run([str(program)], timeout=60).returncode == 0
    headers = [p.read_text() for p in sorted(tmp_path.glob("*/*/kf.h"))]
    guards = {re.search(r"#ifndef (\w+)", h)[1] for h in headers}
    assert guards == {"DERIVE_Axis_kf_H", "DERIVE_axis_kf_H"}
