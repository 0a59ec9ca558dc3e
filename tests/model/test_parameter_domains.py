"""Declared domains of free parameters (docs/robustness.md, "Free parameters per step").

A free symbol declared nonnegative or positive (sympy's assumptions, or ``domain`` in a
model file's ``[parameters.NAME]`` table) is checked once at the start of every generated
program that reads it: C returns a status naming the parameter, Python raises
NumericalError naming it and its value, a run names the step of the failing row, a NaN
fails; the check is one comparison (``cmp``) in the counts. The NumPy references and the
models' numbers refuse the same values (DomainError, a NumericalError and a ModelError).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import LinearModel, NonlinearModel, Sensor, catalog, catalog_files, reference
from derive.apps.verify import LINEAR_TOLERANCE, relative_error
from derive.domains import check_rows, declared_domain, parameter_domains
from derive.errors import DomainError, ModelError, ModelFileError, NumericalError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.interface import read
from derive.modelfile import load_model_file, loads_model
from derive.pipeline import load_generated

ROOT = Path(__file__).resolve().parents[2]
GCC = shutil.which("gcc")
needs_gcc = pytest.mark.skipif(GCC is None, reason="no C compiler")

DT = sympy.Symbol("dt", nonnegative=True)
Q = sympy.Symbol("q", positive=True)


def _axis(dt, q, name: str = "domaxis") -> LinearModel:
    """A constant-velocity axis with free dt and q (measurement noise fixed)."""
    return LinearModel(name, ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[q]], [[0.25]],
                       G=[[dt ** 2 / 2], [dt]], x0=[0, 1], P0=[[4, 0.5], [0.5, 1]],
                       parameters=[dt, q])


def _modules(generated) -> list:
    return [generated.python] + ([generated.c] if GCC else [])


@pytest.fixture(scope="module")
def axis_kf(tmp_path_factory):
    model = _axis(DT, Q)
    return model, load_generated(model, "kf", None, "all" if GCC else "python",
                                 tmp_path_factory.mktemp("axis"))


def _rows(steps: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0.05, 2.0, steps), rng.uniform(0.001, 0.1, steps)])


def _stepped_reference(model, zs, rows, x0, P0):
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


# -- declarations ---------------------------------------------------------------------------

def test_the_domain_comes_from_the_symbols_assumptions():
    assert declared_domain(DT) == "nonnegative" and declared_domain(Q) == "positive"
    assert declared_domain(sympy.Symbol("w", real=True)) is None
    assert parameter_domains(_axis(DT, Q).parameters) == ((0, "dt", "nonnegative"),
                                                          (1, "q", "positive"))


# -- generated code: step and run, Python and C ------------------------------------------------

def test_a_negative_row_in_the_middle_of_a_run_is_refused_naming_its_step(axis_kf):
    model, generated = axis_kf
    steps, bad = 30, 17
    rows = _rows(steps, 3)
    rows[bad, 0] = -0.25
    zs = np.cumsum(np.random.default_rng(4).normal(size=(steps, 1)), axis=0)
    x0, P0 = np.array([0.0, 1.0]), np.array([[4.0, 0.5], [0.5, 1.0]])
    for module in _modules(generated):
        with pytest.raises(NumericalError,
                           match=re.escape(f"step {bad}: parameter dt must be nonnegative, "
                                           f"got {float(rows[bad, 0])!r}")):
            module.run(zs, x0, P0, rows)
    # the rows before it are filtered as the reference filters them (1e-12 relative)
    xr, Pr = _stepped_reference(model, zs[:bad], rows[:bad], x0, P0)
    for module in _modules(generated):
        xs, Ps = module.run(zs[:bad], x0, P0, rows[:bad])
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(Ps, Pr) <= LINEAR_TOLERANCE


def test_step_refuses_a_negative_or_nan_dt_and_a_zero_q_naming_the_value(axis_kf):
    _, generated = axis_kf
    x, P, z = [0.0, 1.0], [4.0, 0.5, 0.5, 1.0], [0.3]
    for module in _modules(generated):
        for row, text in (([-1e-300, 0.1], "parameter dt must be nonnegative, got -1e-300"),
                          ([float("nan"), 0.1], "parameter dt must be nonnegative, got nan"),
                          ([0.5, 0.0], "parameter q must be positive, got 0.0")):
            with pytest.raises(NumericalError, match=re.escape(text)):
                module.step(x, P, z, row)
        # dt = 0 lies in the domain: a step without motion or noise
        module.step(x, P, z, [0.0, 0.1])


@needs_gcc
def test_c_returns_the_status_the_header_names_for_the_parameter(axis_kf):
    _, generated = axis_kf
    header = generated.paths[".h"].read_text()
    described = read(header)
    domain_statuses = {s.parameter[1]: s for s in described.statuses if s.parameter}
    assert set(domain_statuses) == {"dt", "q"}
    status = domain_statuses["dt"]
    assert status.message == "parameter dt must be nonnegative"
    assert f"    step {status.number}: parameter dt must be nonnegative" in header
    assert f"STATUS_STEP_PARAMETER_DT_MUST_BE_NONNEGATIVE_{status.number} = " \
           f"{status.number}" in header
    lib, ffi = generated.c.lib, generated.c.ffi
    x, P, z = (ffi.new("double[]", v) for v in ([0.0, 1.0], [4.0, 0.5, 0.5, 1.0], [0.3]))
    x_new, P_new = ffi.new("double[2]"), ffi.new("double[4]")
    for value in (-0.5, float("nan")):
        p = ffi.new("double[]", [value, 0.1])
        assert lib.domaxis_kf_step(x, P, z, x_new, P_new, p) == status.number
    assert lib.domaxis_kf_step(x, P, z, x_new, P_new, ffi.new("double[]", [0.5, 0.1])) == 0


@needs_gcc
def test_run_tracks_and_the_batch_path_name_the_step(axis_kf):
    import derive.batch  # noqa: PLC0415 (the batch module, as a user calls it)

    _, generated = axis_kf
    steps, tracks, bad = 12, 4, 7
    rows = _rows(steps, 5)
    rows[bad, 0] = -2.0
    rng = np.random.default_rng(6)
    zs, x0 = rng.normal(size=(tracks, steps, 1)), rng.normal(size=(tracks, 2))
    P0 = np.stack([np.eye(2)] * tracks)
    text = f"step {bad}: parameter dt must be nonnegative, got -2.0"
    with pytest.raises(NumericalError, match=re.escape(text)):
        generated.c.run_tracks(zs, x0, P0, rows)
    with pytest.raises(NumericalError, match=re.escape(text)):
        derive.batch.run_tracks(generated.c, zs, x0, P0, rows, workers=2)


# -- counts ------------------------------------------------------------------------------------

def test_each_declared_parameter_costs_one_comparison_counted_three_ways():
    declared, plain = _axis(DT, Q), _axis(*sympy.symbols("dt q", real=True))
    step = derive_unit(declared, "kf", {}).programs["step"]
    static = count(step, "python")
    before = count(derive_unit(plain, "kf", {}).programs["step"], "python")
    assert static.cmp == before.cmp + len(parameter_domains(declared.parameters))
    assert static.flops == before.flops
    texts = render_filter(declared, "kf", "all")
    scope: dict = {}
    exec(compile(texts["kf.py"], "kf.py", "exec"), scope)  # derive's own generated code
    counter = OpCounter()
    scope["step"](counter.wrap(np.array([0.0, 1.0])), counter.wrap(np.eye(2).ravel()),
                  counter.wrap(np.array([0.3])), counter.wrap(np.array([0.5, 0.1])))
    assert counter.snapshot() == static
    assert count_c_function(texts["kf.c"], "domaxis_kf_step") == count(step, "c")
    assert f"operations per call of step (Python): {static.summary()}" in texts["kf.py"]
    assert f"{count(step, 'c').summary()}" in texts["kf.h"]


def test_the_checks_do_not_change_the_arithmetic(tmp_path):
    """The declared model's run equals the plain model's bit for bit."""
    declared = load_generated(_axis(DT, Q), "kf", None, "python", tmp_path / "a").python
    plain = load_generated(_axis(*sympy.symbols("dt q", real=True)), "kf", None, "python",
                           tmp_path / "b").python
    rows = _rows(50, 8)
    zs = np.random.default_rng(9).normal(size=(50, 1))
    x0, P0 = np.array([0.0, 1.0]), np.eye(2)
    for got, want in zip(declared.run(zs, x0, P0, rows), plain.run(zs, x0, P0, rows)):
        np.testing.assert_array_equal(got, want)


# -- programs that do not read the parameter ---------------------------------------------------

def _attitude(dt) -> NonlinearModel:
    """A 2-D attitude driven by a gyro input with a bias; dt is read by predict only."""
    q0, q1, b, w = sympy.symbols("q0 q1 b w", real=True)
    f = [q0 - dt * (w - b) * q1 / 2, q1 + dt * (w - b) * q0 / 2, b]
    return NonlinearModel(
        "domatt", ["q0", "q1", "b"], f=f, Q=sympy.diag(1e-6, 1e-6, 1e-8) * 10, inputs=["w"],
        Qu=[[1e-4]],
        sensors=[Sensor("mag", ["c", "s"], h=[q0, q1], R=[[0.01, 0], [0, 0.01]]),
                 Sensor("bias", ["zb"], h=[b], R=[[1e-2]])],
        x0=[1, 0, 0], P0=sympy.diag(0.01, 0.01, 1e-4), parameters=[dt])


def test_only_the_programs_that_read_the_parameter_check_it(tmp_path):
    model = _attitude(DT)
    unit = derive_unit(model, "ekf", {})
    plain = derive_unit(_attitude(sympy.Symbol("dt", real=True)), "ekf", {})
    for name, program in unit.programs.items():
        reads = any(s.name == "p[0]" for st in program.body for s in
                    (st.expr if hasattr(st, "expr") else st.value).free_symbols)
        extra = count(program, "c").cmp - count(plain.programs[name], "c").cmp
        assert extra == (1 if name == "predict" else 0), name
        assert reads == (name == "predict"), name
    generated = load_generated(model, "ekf", None, "all" if GCC else "python", tmp_path)
    steps, bad = 40, 23
    rng = np.random.default_rng(12)
    us = 0.3 + 0.05 * rng.normal(size=(steps, 1))
    dt = rng.uniform(0.005, 0.02, (steps, 1))
    dt[bad, 0] = -dt[bad, 0]
    zm = np.c_[np.ones(steps), np.zeros(steps)]
    zm[np.arange(steps) % 3 != 0] = np.nan
    zb = np.full((steps, 1), np.nan)
    x0, P0 = np.array([1.0, 0.0, 0.0]), np.diag([0.01, 0.01, 1e-4])
    text = f"step {bad}: parameter dt must be nonnegative, got {float(dt[bad, 0])!r}"
    # Python's run of several sensors raises predict's error (no step, as for its other
    # checks); derive.build names the step of C's status from the rows of p
    with pytest.raises(NumericalError, match=re.escape(text.split(": ", 1)[1])):
        generated.python.run(zm, zb, us, x0, P0, p=dt)
    if GCC:
        with pytest.raises(NumericalError, match=re.escape(text)):
            generated.c.run(zm, zb, us, x0, P0, p=dt)
    # the reference refuses the same row with the same message
    with pytest.raises(DomainError, match=re.escape(text)):
        reference_run(model, {}, {"mag": zm, "bias": zb}, us, dt, x0, P0)


# -- composed models: identical blocks share the parameter -----------------------------------

def test_a_composed_model_checks_its_shared_parameter_once(tmp_path):
    axes = [LinearModel(f"ax{k}", ["s", "v"], ["z"], [[1, DT], [0, 1]], [[1, 0]],
                        [["q"]], [[0.25]], G=[[DT ** 2 / 2], [DT]], values={"q": 0.01},
                        parameters=[DT])
            for k in range(3)]
    model = LinearModel.compose("domthree", axes, suffixes=["x", "y", "z"])
    assert [p.name for p in model.parameters] == ["dt"]
    step = derive_unit(model, "kf", {}).programs["step"]
    plain = LinearModel.compose("domthree", [LinearModel(
        f"ax{k}", ["s", "v"], ["z"], [[1, "dt"], [0, 1]], [[1, 0]], [["q"]], [[0.25]],
        G=[["dt**2/2"], ["dt"]], values={"q": 0.01}, parameters=["dt"]) for k in range(3)],
        suffixes=["x", "y", "z"])
    # one check of dt for the three blocks that read it
    assert count(step, "c").cmp == count(derive_unit(plain, "kf", {}).programs["step"],
                                         "c").cmp + 1
    # the check reads no block: the blocks still run in the lanes of one vector (C) and
    # compute what they share once (Python)
    texts = render_filter(model, "kf", "all")
    assert "the identical blocks in the lanes of one vector" in texts["kf.c"]
    assert "(derive.runs.shared)" in texts["kf.py"]
    generated = load_generated(model, "kf", None, "all" if GCC else "python", tmp_path)
    num = model.numeric({"dt": 0.5})
    steps = 20
    zs = np.random.default_rng(1).normal(size=(steps, 3))
    rows = np.full((steps, 1), 0.5)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)
    for module in _modules(generated):
        xs, Ps = module.run(zs, num.x0, num.P0, rows)
        assert relative_error(xs, xr) <= LINEAR_TOLERANCE
        assert relative_error(Ps, Pr) <= LINEAR_TOLERANCE
        rows[11, 0] = -0.5
        with pytest.raises(NumericalError, match=r"step 11: parameter dt must be nonnegative"):
            module.run(zs, num.x0, num.P0, rows)
        rows[11, 0] = 0.5


# -- the reference and the model's numbers ---------------------------------------------------

def test_the_reference_refuses_the_same_values():
    model = _axis(DT, Q)
    with pytest.raises(DomainError, match=r"model 'domaxis': parameter dt must be "
                                          r"nonnegative, got -0\.1"):
        model.numeric({"dt": -0.1, "q": 0.01})
    with pytest.raises(NumericalError, match="parameter q must be positive, got 0"):
        model.numeric({"dt": 0.1, "q": 0})
    rows = _rows(6, 2)
    rows[4, 1] = float("nan")
    with pytest.raises(DomainError, match=r"step 4: parameter q must be positive, got nan"):
        check_rows(parameter_domains(model.parameters), rows)
    assert issubclass(DomainError, ModelError)
    with pytest.raises(DomainError, match=r"model 'domaxis' values: parameter dt must be "
                                          r"nonnegative, got -1"):
        LinearModel("domaxis", ["s", "v"], ["z"], [[1, DT], [0, 1]], [[1, 0]], [[Q]],
                    [[0.25]], G=[[DT ** 2 / 2], [DT]], values={DT: -1})
    with pytest.raises(DomainError, match=r"examples: parameter dt must be nonnegative"):
        LinearModel("domaxis", ["s", "v"], ["z"], [[1, DT], [0, 1]], [[1, 0]], [[1]],
                    [[0.25]], G=[[DT ** 2 / 2], [DT]], examples={"dt": -0.01})


# -- model files -----------------------------------------------------------------------------

MODEL_FILE = """
[model]
name = "domfile"
states = ["s", "v"]
measurements = ["z"]

[parameters]
dt = { description = "time step", domain = "nonnegative", example = 0.1 }
q = { domain = "positive" }
r = 0.25

[discrete]
F = [[1, "dt"], [0, 1]]
G = [["dt**2/2"], ["dt"]]
H = [[1, 0]]
Q = "q"
R = "r"
"""


def test_a_model_file_declares_domains_in_the_parameter_table():
    model = loads_model(MODEL_FILE)
    assert parameter_domains(model.parameters) == ((0, "dt", "nonnegative"),
                                                   (1, "q", "positive"))
    step = derive_unit(model, "kf", {}).programs["step"]
    assert [c.message for c in step.body if getattr(c, "parameter", "")] == [
        "parameter dt must be nonnegative", "parameter q must be positive"]


CONTINUOUS = """
[model]
name = "domcont"
states = ["s", "v"]
measurements = ["z"]

[parameters]
{parameters}

[continuous]
Phi = [[0, 1], [0, 0]]
G = [0, 1]
Qc = 0.01
H = [[1, 0]]
R = 0.1
dt = "{dt}"
"""


@pytest.mark.parametrize(("parameters", "dt", "domains"), [
    ('dt = { description = "free step" }', "dt", ((0, "dt", "nonnegative"),)),
    ('dt = { domain = "positive" }', "dt", ((0, "dt", "positive"),)),
    ('h = { description = "half step" }', "2*h", ()),
], ids=["bare dt: nonnegative", "declared", "an expression: not by default"])
def test_the_free_time_step_of_a_continuous_file_is_nonnegative_by_default(parameters, dt,
                                                                           domains):
    model = loads_model(CONTINUOUS.format(parameters=parameters, dt=dt))
    assert parameter_domains(model.parameters) == domains


@pytest.mark.parametrize(("spec", "message"), [
    ('{ domain = "nonneg" }',
     "bad.toml: [parameters] dt domain: must be one of nonnegative, positive, got string "
     "'nonneg'"),
    ("{ domain = 1 }",
     "bad.toml: [parameters] dt domain: must be one of nonnegative, positive, got int 1"),
    ('{ domain = "positive", value = 0 }',
     "bad.toml: [parameters] dt value: must be positive (its domain), got 0"),
    ('{ domain = "nonnegative", example = -0.01 }',
     "bad.toml: [parameters] dt example: must be nonnegative (its domain), got -0.01"),
], ids=["unknown domain", "not a string", "value outside", "example outside"])
def test_a_bad_domain_is_one_line_with_exit_status_2(tmp_path, spec, message):
    path = tmp_path / "bad.toml"
    path.write_text(MODEL_FILE.replace(
        'dt = { description = "time step", domain = "nonnegative", example = 0.1 }',
        f"dt = {spec}"))
    with pytest.raises(ModelFileError) as info:
        load_model_file(path)
    assert str(info.value).endswith(message)
    out = tmp_path / "o"
    done = subprocess.run([sys.executable, "-m", "derive", "generate", str(path), "--filter",
                           "kf", "--out", str(out)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and message in done.stderr
    assert "Traceback" not in done.stderr
    assert not out.exists()


# -- the catalog ---------------------------------------------------------------------------

def test_the_ins_gnss_ekf_checks_dt_in_predict_alone():
    """ins_gnss declares dt nonnegative: its predict (the one program reading dt) checks it,
    one comparison more than the same model without the declaration, arithmetic unchanged;
    its reference refuses a negative row naming the step."""
    text = catalog_files.read_text("ins_gnss")
    declared = catalog.load("ins_gnss")
    assert ', domain = "nonnegative"' in text
    plain = loads_model(text.replace(', domain = "nonnegative"', ""))
    assert parameter_domains(declared.parameters) == ((0, "dt", "nonnegative"),)
    assert parameter_domains(plain.parameters) == ()
    unit, before = derive_unit(declared, "ekf", {}), derive_unit(plain, "ekf", {})
    for name, program in unit.programs.items():
        extra = 1 if name == "predict" else 0
        got, was = count(program, "c"), count(before.programs[name], "c")
        assert (got.cmp, got.flops) == (was.cmp + extra, was.flops), name
    header = (ROOT / "generated" / "ins_gnss" / "ekf.h").read_text()
    assert "int ins_gnss_ekf_predict(" in header
    assert "    predict 1: parameter dt must be nonnegative" in header
    assert f"operations per call of predict (C99, fma through DERIVE_FMA and DERIVE_FNMA): " \
           f"{count(unit.programs['predict'], 'c').summary()}" in header
    steps, bad = 6, 3
    dt = np.full((steps, 1), declared.examples["dt"])
    dt[bad, 0] = -dt[bad, 0]
    us = np.tile([0.0, 0.0, 0.0, 0.0, 0.0, -9.80665], (steps, 1))
    zs = {"gnss": np.full((steps, 6), np.nan), "baro": np.full((steps, 1), np.nan)}
    with pytest.raises(DomainError, match=re.escape(
            f"step {bad}: parameter dt must be nonnegative, got {float(dt[bad, 0])!r}")):
        reference_run(declared, {}, zs, us, dt)
