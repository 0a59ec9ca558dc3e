"""The dynamic proof of the static counts (issue 4, item 2).

Every generated Python filter of the catalog (and paper mode's) is executed for one
call of each of its functions on CountingFloat inputs; the operations counted at run
time must equal :func:`derive.flops.count` of the program exactly, kind by kind. The
emitted C text is counted by its operators with the same rules and must equal the
static C count too.
"""

import numpy as np
import pytest

from derive import catalog
from derive.apps import paper
from derive.domains import parameter_domains
from derive.filters import available, derive_unit
from derive.flops import OpCounter, count, count_c_function
from derive.generation import render_filter
from derive.model import LinearModel, NonlinearModel
from derive.program import ZERO, Check


def _input_model():
    """A linear model with per-step inputs (acceleration through B, a measurement offset
    through D) and a free parameter in B: the KF's u port is counted too."""
    return LinearModel("accel_offset", ["pos", "vel"], ["y"], [["1", "dt"], ["0", "1"]],
                       [[1, 0]], [["q", 0], [0, "q"]], [[1]],
                       B=[["dt**2/2", 0], ["dt", 0]], D=[[0, 1]], inputs=["acc", "bias"],
                       values={"q": 0.01}, parameters=["dt"])


def _unicycle_model():
    """A nonlinear model whose f uses per-step inputs (speed v, turn rate w) with input
    noise Qu, a free parameter in Qu: the EKF's predict takes u and maps Qu through df/du."""
    return NonlinearModel("unicycle", ["px", "py", "th"], ["zx", "zy"],
                          ["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w"],
                          ["px", "py"], [["q", 0, 0], [0, "q", 0], [0, 0, "q"]],
                          [["r", 0], [0, "r"]], values={"dt": 0.1, "q": 1e-6, "r": 0.25},
                          inputs=["v", "w"], Qu=[["sv", 0], [0, "sw"]], parameters=["sv", "sw"])


INPUT_MODELS = {"accel_offset": _input_model, "unicycle": _unicycle_model}
CASES = [(name, f) for name in catalog.names() for f in available(catalog.load(name))]
INPUT_CASES = [(name, f) for name, make in INPUT_MODELS.items() for f in available(make())]
PAPER_CASES = [(name, f) for name in ("mpt3d_a", "cv") for f in paper.PAPER_FILTERS]
PAPER_FIR_ORDER = 3

_CACHE: dict = {}


def _generated(model_name: str, filter_name: str, mode: str):
    """(unit, files) of one filter, derived and rendered once per session."""
    key = (model_name, filter_name, mode)
    if key not in _CACHE:
        model = (INPUT_MODELS[model_name]() if model_name in INPUT_MODELS
                 else catalog.load(model_name))
        if mode == "paper":
            N = PAPER_FIR_ORDER if filter_name == "fir" else None
            unit = paper.model_unit(model, filter_name, N=N)
            files = paper.render(model, filter_name, "all", N=N)
        else:
            unit = derive_unit(model, filter_name, {})
            files = render_filter(model, filter_name, "all")
        _CACHE[key] = (model, unit, files)
    return _CACHE[key]


def _outside_pattern(program, name="P", symmetric=True):
    """Flat indices of the square input ``name`` that the program requires to be zero
    (both triangles of a symmetric one)."""
    n = program.port(name).shape[0]
    element = f"{name}["
    flat = [int(str(c.value)[len(element):-1]) for c in program.body
            if isinstance(c, Check) and c.relation == ZERO
            and str(c.value).startswith(element)]
    pairs = [divmod(k, n) for k in flat]
    return [i * n + j for i, j in pairs] + ([j * n + i for i, j in pairs] if symmetric else [])


def _inputs(model, program, unit, mode, rng):
    """Plausible values for every input port (each symmetric one positive definite, zero
    outside its pattern; a UD factor U unit upper triangular, zero outside its pattern,
    and D positive; so every check passes and every operation runs)."""
    values = []
    for port in program.inputs:
        if port.symmetric:
            n = port.shape[0]
            A = rng.normal(size=(n, n))
            P = (A @ A.T + n * np.eye(n)).ravel()
            P[_outside_pattern(program, port.name)] = 0.0
            values.append(P)
        elif port.name == "U" and unit.family == "udkf":
            n = port.shape[0]
            U = (np.triu(rng.uniform(-1.0, 1.0, (n, n)), 1) + np.eye(n)).ravel()
            U[_outside_pattern(program, "U", symmetric=False)] = 0.0
            values.append(U)
        elif port.name == "D" and unit.family == "udkf":
            values.append(rng.uniform(0.5, 1.5, port.size))
        elif port.name == "p" and mode == "paper":
            N = PAPER_FIR_ORDER if unit.family == "fir" else None
            values.append(paper.parameter_values(model, unit.family, N=N))
        elif port.name == "u":  # satellite coordinates, far from the receiver
            values.append(rng.uniform(1e3, 2e3, port.size))
        elif port.name == "p":
            row = rng.uniform(-1.0, 1.0, port.size)
            for index, _, _ in parameter_domains(model.parameters):  # in its declared domain
                row[index] = abs(row[index])
            values.append(row)
        else:
            values.append(rng.uniform(-1.0, 1.0, port.size))
    return values


def _python_functions(files, unit):
    scope: dict = {}
    text = files[f"{unit.filter}.py"]
    exec(compile(text, f"{unit.prefix}.py", "exec"), scope)  # derive's own generated code
    return text, scope


def _check(model_name, filter_name, mode):
    model, unit, files = _generated(model_name, filter_name, mode)
    text, scope = _python_functions(files, unit)
    c_text = files[f"{unit.filter}.c"]
    rng = np.random.default_rng(4)
    for name, program in unit.programs.items():
        static_py, static_c = count(program, "python"), count(program, "c")
        counter = OpCounter()
        args = [counter.wrap(v) for v in _inputs(model, program, unit, mode, rng)]
        scope[name](*args)
        assert counter.snapshot() == static_py, (model_name, filter_name, name,
                                                 counter.snapshot().summary(),
                                                 static_py.summary())
        assert count_c_function(c_text, f"{unit.prefix}_{name}") == static_c
        assert static_c.flops == static_py.flops
        assert f"operations per call of {name} (Python): {static_py.summary()}" in text
        assert static_c.summary() in c_text


@pytest.mark.parametrize("model_name,filter_name", CASES)
def test_generated_filter_counts_match_at_run_time_and_in_the_c_text(model_name, filter_name):
    _check(model_name, filter_name, "specialised")


@pytest.mark.parametrize("model_name,filter_name", INPUT_CASES)
def test_input_model_counts_match_at_run_time_and_in_the_c_text(model_name, filter_name):
    _check(model_name, filter_name, "specialised")


def test_input_model_cases_cover_the_kf_the_rts_and_the_ekf_with_inputs_in_f():
    assert [f for _, f in INPUT_CASES] == ["kf", "rts", "ekf"]


@pytest.mark.parametrize("model_name,filter_name", PAPER_CASES)
def test_paper_mode_counts_match_at_run_time_and_in_the_c_text(model_name, filter_name):
    _check(model_name, filter_name, "paper")


def test_every_catalog_model_is_covered():
    assert {m for m, _ in CASES} == set(catalog.names())
    assert {f for _, f in CASES} >= {"kf", "lf", "jklf", "ikf", "sskf", "sslf", "jssklf", "fir",
                                     "pred"}
