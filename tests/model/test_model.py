"""Model construction and validation: every error names its culprit."""

import numpy as np
import pytest
import sympy
from conftest import axis_model, dt, sq2, sr2

from derive import LinearModel, ModelError, NonlinearModel
from derive.errors import MatrixPropertyError, NameError_, ShapeError, SymbolError


def test_values_and_free_parameters():
    m = axis_model(values={"dt": 1, "sq2": 0.01})
    assert [p.name for p in m.parameters] == ["sr2"]
    assert m.matrix("F") == sympy.Matrix([[1, 1], [0, 1]])
    assert m.matrix("GQGt") == sympy.Matrix([[sympy.Rational(1, 400), sympy.Rational(1, 200)],
                                             [sympy.Rational(1, 200), sympy.Rational(1, 100)]])
    num = m.numeric({"sr2": 0.5})
    np.testing.assert_array_equal(num.R, [[0.5]])
    with pytest.raises(SymbolError, match="sr2"):
        m.numeric()
    with pytest.raises(SymbolError, match="'nope'"):
        m.numeric({"sr2": 1.0, "nope": 2.0})


def test_two_symbols_with_one_name_refused():
    """Two different symbols with one name are ambiguous: refused, naming both."""
    d = sympy.Symbol("dt", positive=True)
    with pytest.raises(SymbolError, match=r"'dt'.*positive=True.*F\[0\]\[1\].*real=True"):
        LinearModel("u", ["s", "v"], ["z"], [[1, d], [0, 1]], [[1, dt]], [[1]], [[1]],
                    G=[[0], [1]])


@pytest.mark.parametrize(
    "kwargs, cls, words",
    [
        (dict(F=[[1, 0, 0], [0, 1, 0]]), ShapeError, ["F", "2x2", "2x3"]),
        (dict(H=[[1, 0, 0]]), ShapeError, ["H", "1x2", "1x3"]),
        (dict(Q=[[1, 0], [0, 1]]), ShapeError, ["Q", "1x1", "2x2"]),
        (dict(R=[[1, 0], [0, 1]]), ShapeError, ["R", "1x1", "2x2"]),
        (dict(G=[[1], [0], [0]]), ShapeError, ["G", "2 rows"]),
        (dict(F=[[1, 2], [3]]), ShapeError, ["F", "ragged"]),
        (dict(R=[[-sr2]]), MatrixPropertyError, ["R", "positive definite"]),
        (dict(R=[[0 * sr2 + 0]], values={"dt": 1, "sq2": 0.01}), MatrixPropertyError,
         ["R", "positive definite"]),
        (dict(Q=[[-sq2]]), MatrixPropertyError, ["Q", "semidefinite"]),
        (dict(values={"dt": 1, "bogus": 2}), SymbolError, ["bogus", "unknown"]),
        (dict(values={"dt": "x"}), SymbolError, ["dt", "number"]),
        (dict(values={"dt": float("nan")}), SymbolError, ["nan"]),
    ],
)
def test_bad_linear_models(kwargs, cls, words):
    base = dict(F=[[1, dt], [0, 1]], H=[[1, dt]], Q=[[sq2]], R=[[sr2]], G=[[dt / 2], [1]],
                values={"dt": 1, "sq2": 0.01, "sr2": 0.1})
    base.update(kwargs)
    with pytest.raises(cls) as info:
        LinearModel("bad", ["s", "v"], ["z"], base.pop("F"), base.pop("H"), base.pop("Q"),
                    base.pop("R"), **base)
    assert isinstance(info.value, ModelError)
    for w in words:
        assert w in str(info.value)


def test_nonsymmetric_noise_named():
    with pytest.raises(MatrixPropertyError, match=r"R must be symmetric: R\[0\]\[1\]"):
        LinearModel("bad", ["a", "b"], ["y1", "y2"], [[1, 0], [0, 1]], [[1, 0], [0, 1]],
                    [[1, 0], [0, 1]], [[1, 0.5], [0.2, 1]])
    with pytest.raises(MatrixPropertyError, match="Q must be symmetric"):
        LinearModel("bad", ["a", "b"], ["y"], [[1, 0], [0, 1]], [[1, 0]],
                    [[1, sq2], [0, 1]], [[1]])


@pytest.mark.parametrize(
    "name, states, meas, words",
    [
        ("1bad", ["s", "v"], ["z"], ["model name", "1bad"]),
        ("../x", ["s", "v"], ["z"], ["model name", "../x"]),
        ("while", ["s", "v"], ["z"], ["reserved", "while"]),
        ("ok", ["s", "s"], ["z"], ["twice", "'s'"]),
        ("ok", ["s", "v w"], ["z"], ["state name", "v w"]),
        ("ok", ["s", "double"], ["z"], ["reserved", "double"]),
        ("ok", ["s", "v"], ["s"], ["both a state and a measurement"]),
        ("ok", ["s", "_v"], ["z"], ["underscore"]),
        ("ok", [], ["z"], ["states must not be empty"]),
    ],
)
def test_bad_names(name, states, meas, words):
    with pytest.raises(NameError_ if "both" not in words[0] else SymbolError) as info:
        LinearModel(name, states, meas, sympy.eye(max(len(states), 1))[:len(states), :len(states)]
                    if states else [[1]], [[1] * max(len(states), 1)], [[1]], [[1]])
    for w in words:
        assert w in str(info.value)


def test_state_symbol_in_linear_matrix_rejected():
    s = sympy.Symbol("s")
    with pytest.raises(SymbolError, match="'s' is a state"):
        LinearModel("bad", ["s", "v"], ["z"], [[1, s], [0, 1]], [[1, 0]], [[1]], [[1]],
                    G=[[0], [1]])


def test_nonlinear_jacobians_and_numeric():
    x, y, b, xs, ys = sympy.symbols("x y b xs ys", real=True)
    r = sympy.sqrt((xs - x) ** 2 + (ys - y) ** 2)
    m = NonlinearModel("pr", ["x", "y", "b"], ["rho"], [x, y, b], [r + b],
                       sympy.eye(3) / 100, [["sig2"]], values={"sig2": 100.0},
                       inputs=["xs", "ys"])
    assert m.F_jacobian == sympy.eye(3)
    assert sympy.simplify(m.H_jacobian[0, 0] - (x - xs) / r) == 0
    fns = m.numeric_functions()
    X, U = np.array([1.0, 2.0, 3.0]), np.array([4.0, 6.0])
    np.testing.assert_allclose(fns["h"](X, U), [5.0 + 3.0], rtol=1e-15)
    np.testing.assert_allclose(fns["H"](X, U), [[-0.6, -0.8, 1.0]], rtol=1e-15)
    np.testing.assert_allclose(fns["f"](X), X, rtol=0)


def test_nonlinear_inputs_in_f_take_u_in_f_F_and_Fu():
    x, u = sympy.symbols("x u", real=True)
    m = NonlinearModel("drive", ["x"], ["y"], [x + u * x], [x], [[1]], [[1]], inputs=["u"],
                       Qu=[[2]])
    assert m.f_inputs == (u,)
    fns = m.numeric_functions()
    assert fns["f"]([3.0], [0.5]).tolist() == [4.5]
    assert fns["F"]([3.0], [0.5]).tolist() == [1.5]  # one column: flat, like a vector
    assert fns["Fu"]([3.0], [0.5]).tolist() == [3.0]
    assert fns["Qu"].tolist() == [[2.0]]


def test_negative_and_signed_zero_floats_are_exact():
    m = LinearModel("neg", ["a"], ["y"], [[-0.5]], [[-0.0 + 1.0]], [[0.25]], [[2.5]])
    assert m.F[0, 0] == sympy.Rational(-1, 2)
    m2 = LinearModel("negz", ["a", "b"], ["y"], [[1, -0.0], [0, 1]], [[1, 0]], np.eye(2),
                     [[1]])
    assert m2.F[0, 1] == 0
