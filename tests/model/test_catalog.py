"""The catalog (SPEC §2): every model loads with its dimensions and the matrices the papers
print; the continuous models' Qd equals SPEC §1 exactly."""

import pytest
import sympy

from derive import catalog
from derive.errors import ModelError
from derive.model import LinearModel, NonlinearModel

S = {n: sympy.Symbol(n, real=True) for n in ("dt", "sq2", "sr2", "x", "y", "z", "b", "q",
                                             "sigma2")}
dt, sq2, sr2 = S["dt"], S["sq2"], S["sr2"]

# SPEC §2: name -> (class, n, m)
TABLE = {
    "mpt3d_a": (LinearModel, 6, 3),
    "mpt3d_b": (LinearModel, 2, 1),
    "gsm2d_a": (LinearModel, 4, 2),
    "gsm2d_b": (LinearModel, 2, 1),
    "cv": (LinearModel, 2, 1),
    "ca": (LinearModel, 3, 1),
    "gps_static": (LinearModel, 3, 3),
    "gnss_pseudorange": (NonlinearModel, 4, 4),
    "ins_eskf": (NonlinearModel, 16, 7),
    "ins_fc24_eskf": (NonlinearModel, 24, 11),
    "ins_gnss": (NonlinearModel, 16, 7),
    "ctrv_radar": (NonlinearModel, 5, 2),
    "ins_fc24": (NonlinearModel, 24, 11),
}


def test_names_are_the_spec_catalog_sorted():
    assert catalog.names() == sorted(TABLE)


@pytest.mark.parametrize("name", sorted(TABLE))
def test_every_model_loads_with_its_dimensions_and_a_source(name):
    cls, n, m = TABLE[name]
    model = catalog.load(name)
    assert type(model) is cls
    assert (model.name, model.n, model.m) == (name, n, m)
    assert "§" in model.source and model.description
    assert catalog.path(name).is_file()
    assert catalog.path(name).read_text(encoding="utf-8") == catalog.read_text(name)


def test_unknown_name_lists_the_catalog_and_suggests():
    with pytest.raises(ModelError) as info:
        catalog.load("mpt3d_c")
    message = str(info.value)
    assert "unknown catalog model 'mpt3d_c'" in message
    assert "did you mean 'mpt3d_b'?" in message
    assert "available: ca, ctrv_radar, cv, gnss_pseudorange" in message
    with pytest.raises(ModelError, match="unknown catalog model"):
        catalog.path("../pyproject")


AXIS = {
    "F": sympy.Matrix([[1, dt], [0, 1]]),
    "G": sympy.Matrix([[dt / 2], [1]]),
    "H": sympy.Matrix([[1, dt]]),
    "Q": sympy.Matrix([[sq2]]),
    "R": sympy.Matrix([[sr2]]),
}
EXAMPLE_VALUES = {"dt": 1, "sq2": sympy.Rational(1, 100), "sr2": sympy.Rational(1, 10)}


@pytest.mark.parametrize("name", ["mpt3d_b", "gsm2d_b"])
def test_axis_models_are_the_printed_axis(name):
    model = catalog.load(name)
    for key, expected in AXIS.items():
        assert getattr(model, key) == expected, key
    assert model.values == EXAMPLE_VALUES
    assert model.states == ("s", "v") and model.measurements == ("z",)
    assert model.x0 == sympy.zeros(2, 1) and model.P0 == sympy.zeros(2, 2)
    assert model.P0_pattern == "zero"


@pytest.mark.parametrize("name, axes", [("mpt3d_a", "xyz"), ("gsm2d_a", "xy")])
def test_model_a_is_model_b_on_a_block_diagonal(name, axes):
    model = catalog.load(name)
    assert model.states == tuple(f"{s}{a}" for a in axes for s in "sv")
    assert model.measurements == tuple(f"z{a}" for a in axes)
    for key, block in AXIS.items():
        assert getattr(model, key) == sympy.diag(*[block] * len(axes)), key
    assert model.values == EXAMPLE_VALUES
    assert [block.model.n for block in model.blocks()] == [2] * len(axes)


def test_cv_discretisation_equals_spec():
    model = catalog.load("cv")
    assert model.F == sympy.Matrix([[1, dt], [0, 1]])
    spec_qd = sq2 * sympy.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    assert (model.Q - spec_qd).applyfunc(sympy.simplify) == sympy.zeros(2, 2)
    assert model.H == sympy.Matrix([[1, 0]]) and model.R == sympy.Matrix([[sr2]])
    assert model.G == sympy.eye(2)
    assert model.values == EXAMPLE_VALUES
    assert model.matrix("Q") == sympy.Matrix([[sympy.Rational(1, 300), sympy.Rational(1, 200)],
                                              [sympy.Rational(1, 200), sympy.Rational(1, 100)]])


def test_ca_discretisation_equals_spec():
    model = catalog.load("ca")
    assert model.F == sympy.Matrix([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]])
    spec_qd = sq2 * sympy.Matrix([
        [dt**5 / 20, dt**4 / 8, dt**3 / 6],
        [dt**4 / 8, dt**3 / 3, dt**2 / 2],
        [dt**3 / 6, dt**2 / 2, dt],
    ])
    assert (model.Q - spec_qd).applyfunc(sympy.simplify) == sympy.zeros(3, 3)
    assert model.H == sympy.Matrix([[1, 0, 0]]) and model.R == sympy.Matrix([[sr2]])
    assert model.values == EXAMPLE_VALUES


def test_gps_static_is_the_mdkf_random_walk():
    model = catalog.load("gps_static")
    names = ("upsilon", "tau", "zeta", "sx2", "sy2", "sz2")
    upsilon, tau, zeta, sx2, sy2, sz2 = (sympy.Symbol(n, real=True) for n in names)
    assert model.F == sympy.eye(3) and model.H == sympy.eye(3) and model.G == sympy.eye(3)
    assert model.Q == sympy.diag(upsilon, tau, zeta)
    assert model.R == sympy.diag(sx2, sy2, sz2)
    assert model.values == {**dict.fromkeys(names[:3], sympy.Rational(1, 100)),
                            **dict.fromkeys(names[3:], sympy.Rational(1, 10))}
    assert model.P0 == model.matrix("R") and model.P0_pattern == "diagonal"
    assert [block.model.n for block in model.blocks()] == [1, 1, 1]


def test_gnss_pseudorange_is_the_spec_model():
    model = catalog.load("gnss_pseudorange")
    x, y, z, b = (S[n] for n in "xyzb")
    inputs = [sympy.Symbol(f"{c}s{i}", real=True) for i in range(1, 5) for c in "xyz"]
    assert model.inputs == tuple(inputs)
    assert model.f == sympy.Matrix([x, y, z, b])
    for i in range(4):
        xs, ys, zs = inputs[3 * i: 3 * i + 3]
        assert model.h[i] == sympy.sqrt((xs - x) ** 2 + (ys - y) ** 2 + (zs - z) ** 2) + b
    assert model.subs(model.Q) == sympy.eye(4) / 100
    assert model.subs(model.R) == sympy.eye(4) * 100
    assert model.parameters == ()
    assert list(model.H_jacobian[:, 3]) == [1, 1, 1, 1]
