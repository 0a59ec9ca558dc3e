"""How user input becomes the model: the user's own symbols, the order of p, symmetry to
rounding, NumPy scalars, finite entries named when they are not, compose's P0 pattern."""

import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import sympy

from derive import LinearModel, NonlinearModel
from derive.build import load_python
from derive.errors import (
    ExpressionError,
    MatrixPropertyError,
    NameError_,
    NotFiniteError,
    SymbolError,
)
from derive.generation import generate
from derive.modelfile import loads_model

dt = sympy.Symbol("dt", positive=True)


def axis(F=None, G=None, H=None, Q=None, R=None, **kw):
    """The constant-velocity axis with the user's positive dt (a symbol without a value
    declared a parameter: ``declare`` names them)."""
    kw.setdefault("parameters", kw.pop("declare", []))
    return LinearModel("ax", ["s", "v"], ["z"],
                       [[1, dt], [0, 1]] if F is None else F,
                       [[1, 0]] if H is None else H,
                       [[1]] if Q is None else Q,
                       [[1]] if R is None else R,
                       G=[[dt / 2], [1]] if G is None else G, **kw)


# -- 1. the user's symbols come back --------------------------------------------------------

def test_user_symbols_are_kept_in_every_matrix():
    model = axis(Q=[["q"]], declare=[dt, "q"])
    assert dt in model.F.free_symbols and dt in model.G.free_symbols
    assert model.F.subs(dt, 2) == sympy.Matrix([[1, 2], [0, 1]])
    assert model.parameters[0] is dt
    num = model.numeric({"dt": 2, "q": 1})  # names map to the user's symbols
    np.testing.assert_array_equal(num.F, [[1, 2], [0, 1]])
    assert model.numeric({dt: 2, "q": 1}).F[0, 1] == 2


def test_string_entries_and_value_keys_map_to_the_users_symbol():
    model = axis(H=[[1, "dt"]], values={"dt": 0.5})
    assert model.H[0, 1] is dt and model.symbol("dt") is dt
    assert model.matrix("H") == sympy.Matrix([[1, sympy.Rational(1, 2)]])
    # a string written before the user's symbol is bound to it too
    model = axis(F=[[1, "dt"], [0, 1]], values={dt: 1})
    assert model.F[0, 1] is dt and not model.parameters


def test_two_symbols_with_one_name_are_refused_naming_both():
    with pytest.raises(SymbolError) as info:
        axis(H=[[1, sympy.Symbol("dt")]])
    text = str(info.value)
    assert "'dt'" in text and "positive=True" in text and "Symbol('dt')" in text
    assert "F[0][1]" in text and "H[0][1]" in text
    with pytest.raises(SymbolError, match="'dt'.*real=True.*values"):
        axis(values={sympy.Symbol("dt", real=True): 1})


def test_nonlinear_jacobians_use_the_users_state_symbols():
    x, y = sympy.symbols("x y", positive=True)
    c = sympy.Symbol("c", nonzero=True)
    f = sympy.Matrix([x + y * c, y])
    h = sympy.Matrix([sympy.sqrt(x**2 + y**2)])
    model = NonlinearModel("nl", ["x", "y"], ["r"], f, h, sympy.eye(2), [[1]],
                           values={"c": 0.1})
    assert model.state_symbols == (x, y)
    assert model.F_jacobian == f.jacobian([x, y])
    assert model.H_jacobian == h.jacobian([x, y])
    fns = model.numeric_functions()
    np.testing.assert_allclose(fns["F"]([3.0, 4.0]), [[1, 0.1], [0, 1]], rtol=0)


def test_jacobians_treat_symbols_without_assumptions_as_real():
    """The entries are real: d|x|/dx is sign(x) for the user's plain Symbol('x') (as the
    guards' select, derive.guards: 1, -1, and 0 at zero), not an expression in re(x) and
    im(x)."""
    x, y = sympy.symbols("x y")
    model = NonlinearModel("nl", ["x", "y"], ["r"], [x, y], [sympy.Abs(x) + y],
                           sympy.eye(2), [[1]])
    assert model.state_symbols == (x, y)
    J = model.H_jacobian
    assert not J.atoms(sympy.re, sympy.im) and J[0, 1] == 1
    assert [J[0, 0].subs(x, v) for v in (2.5, -3, 0)] == [1, -1, 0]


def test_from_continuous_keeps_the_users_symbols():
    w, q = sympy.Symbol("w"), sympy.Symbol("q", nonnegative=True)
    model = LinearModel.from_continuous("c", ["s", "v"], ["z"], [[0, 1], [0, -w]], [[q]],
                                        [[1, 0]], [[1]], dt, G=[[0], [1]],
                                        parameters=["w", "q", "dt"])
    assert model.F.free_symbols == {dt, w}
    assert {s.name for s in model.Q.free_symbols} == {"dt", "w", "q"}
    assert model.Q.free_symbols <= {dt, w, q}
    assert not any(e.has(sympy.re, sympy.im) for e in model.F)


def test_generated_code_binds_the_users_symbols_to_p(tmp_path):
    q = sympy.Symbol("q", positive=True)
    model = axis(Q=[[q]], values={"dt": 1}, declare=[q])
    generate(model, ["kf"], "python", tmp_path)
    mod = load_python(tmp_path / "ax" / "kf.py")
    xs, _ = mod.run(np.ones((3, 1)), np.zeros(2), np.eye(2), np.array([0.01]))
    assert xs.shape == (3, 2)


def test_generated_ekf_with_the_users_symbols_matches_an_ekf_step(tmp_path):
    x, y = sympy.symbols("x y", positive=True)
    c = sympy.Symbol("c")
    model = NonlinearModel("nl", ["x", "y"], ["r"], [x + c * y, y], [sympy.sqrt(x**2 + y**2)],
                           sympy.eye(2) / 100, [[1]], parameters=[c])
    generate(model, ["ekf"], "python", tmp_path)
    ekf = load_python(tmp_path / "nl" / "ekf.py")
    x0, P0, z = np.array([3.0, 4.0]), np.eye(2), np.array([5.1])
    got_x, got_P = ekf.step(list(x0), list(P0.ravel()), list(z), [0.5])
    fns = model.numeric_functions({"c": 0.5})
    F = fns["F"](x0)
    xp, Pp = fns["f"](x0), F @ P0 @ F.T + fns["Q"]
    H = fns["H"](xp, ())
    K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + fns["R"])
    np.testing.assert_allclose(got_x, xp + K @ (z - fns["h"](xp, ())), rtol=1e-12)
    np.testing.assert_allclose(np.reshape(got_P, (2, 2)), (np.eye(2) - K @ H) @ Pp,
                               rtol=1e-10, atol=1e-14)


# -- 2. the order of p --------------------------------------------------------------------

def test_parameters_are_declared_in_the_order_of_p():
    k2, k10, a = sympy.symbols("k2 k10 a", real=True)
    model = LinearModel("o", ["s"], ["z"], [[k10]], [[1]], [[a]], [[k2]], G=[[1]],
                        parameters=["k2", "a", k10])
    assert [p.name for p in model.parameters] == ["k2", "a", "k10"]
    with pytest.raises(SymbolError, match="'k3'.*appears in no matrix"):
        LinearModel("o", ["s"], ["z"], [[k10]], [[1]], [[1]], [[k2]], parameters=["k3"])


@pytest.mark.parametrize("make, message", [
    (lambda: NonlinearModel("cv", ["px", "vx"], ["zp"], ["px + dt*vz", "vx"], ["px"],
                            [[1e-3, 0], [0, 1e-3]], [[0.1]], parameters=["dt"]),
     "model 'cv': symbol 'vz' is not a state, an input or a declared parameter (did you "
     "mean state 'vx'?)"),
    (lambda: LinearModel("axis", ["s", "v"], ["z"], [[1, "dt"], [0, 1]], [[1, 0]], [["q"]],
                         [[0.1]], G=[[0], [1]], values={"q": 0.01}),
     "symbol 'dt' is not a state, an input or a declared parameter; give it a value "
     "(values=) or declare it a runtime parameter (parameters=[..., 'dt'], the order of "
     "p)"),
    (lambda: LinearModel("k", ["s"], ["z"], [["kk"]], [[1]], [[1]], [["k2"]], G=[[1]],
                         parameters=["k2"]),
     "symbol 'kk' is not a state, an input or a declared parameter (did you mean "
     "parameter 'k2'?)"),
    (lambda: LinearModel.from_continuous("c", ["s", "v"], ["z"], [[0, 1], [0, "-w"]],
                                         [["q"]], [[1, 0]], [[0.1]], dt, G=[[0], [1]],
                                         values={"q": 1}, parameters=["dt"]),
     "model 'c': symbol 'w' is not a state, an input or a declared parameter"),
], ids=["misspelt state", "free dt", "close parameter", "continuous"])
def test_an_undeclared_free_symbol_is_refused_with_its_close_match(make, message):
    """A symbol without a value that no ``parameters=`` lists is refused, as the model-file
    route refuses it: a misspelt state never becomes a runtime parameter."""
    with pytest.raises(SymbolError, match=re.escape(message)):
        make()


def test_continuous_and_nonlinear_orders():
    w, q, r = sympy.symbols("w q r", positive=True)
    model = LinearModel.from_continuous("c", ["s", "v"], ["z"], [[0, 1], [0, -w]], [[q]],
                                        [[1, 0]], [[r]], dt, G=[[0], [1]],
                                        parameters=["dt", "r", "w", "q"])
    assert [p.name for p in model.parameters] == ["dt", "r", "w", "q"]
    x = sympy.Symbol("x", real=True)
    model = NonlinearModel("nl", ["x"], ["y"], [w * x], [x + r], [[q]], [["k10"]],
                           parameters=["k10", "w", "r", "q"])
    assert [p.name for p in model.parameters] == ["k10", "w", "r", "q"]


MODEL_FILE = """
[model]
name = "order"
states = ["s"]
measurements = ["z"]
[parameters]
k2 = { description = "first declared" }
r = 1.0
k10 = { description = "second declared" }
[discrete]
F = [["k10"]]
H = [[1]]
Q = [["k2"]]
R = "r"
"""


def test_model_file_parameters_follow_the_table_and_reach_the_header(tmp_path):
    model = loads_model(MODEL_FILE)
    assert [p.name for p in model.parameters] == ["k2", "k10"]  # not F's k10 first
    generate(model, ["kf"], "python", tmp_path)
    text = (tmp_path / "order" / "kf.py").read_text()
    assert "p = [k2, k10]" in text


# -- 3. symmetric to rounding -------------------------------------------------------------

def test_covariances_symmetric_to_rounding_are_accepted_and_symmetrised():
    a = np.array([[2.0, 0.3], [0.3, 1.0]])
    fitted = a.copy()
    fitted[1, 0] = 0.3 * (1 + 1e-15)
    model = LinearModel("s", ["a", "b"], ["y1", "y2"], np.eye(2), np.eye(2), fitted, fitted,
                        P0=fitted)
    for mat in (model.Q, model.R, model.P0):
        assert mat == mat.T
        assert abs(float(mat[0, 1]) - 0.3) < 1e-15
    cv = LinearModel.from_continuous("c", ["a", "b"], ["y"], np.zeros((2, 2)), fitted,
                                     [[1, 0]], [[1]], 1)
    assert cv.continuous["Qc"] == cv.continuous["Qc"].T


def test_asymmetry_beyond_the_tolerance_is_refused_in_decimals():
    with pytest.raises(MatrixPropertyError) as info:
        LinearModel("s", ["a", "b"], ["y"], np.eye(2), [[1, 0]], [[1, 0.1], [0.1001, 1]],
                    [[1]])
    text = str(info.value)
    assert "Q[0][1] = 0.1 but Q[1][0] = 0.1001" in text and "1e-12" in text


# -- 4. NumPy scalars ---------------------------------------------------------------------

@pytest.mark.parametrize("scalar", [np.float64(0.5), np.float32(0.5), np.int64(3),
                                    np.int32(3), np.float16(0.5)])
def test_numpy_scalars_are_numbers_everywhere(scalar):
    exact = sympy.Rational(1, 2) if isinstance(scalar, np.floating) else sympy.Integer(3)
    model = axis(F=[[1, scalar], [0, 1]], H=[[scalar, 0]], values={"dt": scalar},
                 Q=np.array([[scalar]]))
    assert model.F[0, 1] == exact and model.H[0, 0] == exact
    assert model.values["dt"] == exact and model.Q[0, 0] == exact
    assert model.numeric().F[0, 1] == float(scalar)


def test_numpy_float32_is_the_float_it_is():
    model = axis(F=[[1, np.float32(0.1)], [0, 1]], declare=[dt])
    assert float(model.F[0, 1]) == float(np.float32(0.1))


@pytest.mark.parametrize("bad, words", [
    (float("nan"), ["F[0][1]", "nan"]),
    (sympy.nan, ["F[0][1]", "nan"]),
    (np.float64("nan"), ["F[0][1]", "nan"]),
    (np.float32("inf"), ["F[0][1]", "inf"]),
    (np.bool_(True), ["F[0][1]", "boolean"]),
])
def test_bad_numpy_scalars_name_the_entry(bad, words):
    with pytest.raises(SymbolError) as info:
        axis(F=[[1, bad], [0, 1]])
    assert all(w in str(info.value) for w in words)


def test_bad_numpy_value_names_the_value():
    with pytest.raises(SymbolError, match="value of 'dt'.*nan"):
        axis(values={"dt": np.float64("nan")})
    with pytest.raises(SymbolError, match="value of 'dt'.*True"):
        axis(values={"dt": np.bool_(True)})


# -- 5. finite entries at the values, named -----------------------------------------------

def test_entry_that_overflows_at_the_values_is_named():
    with pytest.raises(NotFiniteError) as info:
        axis(F=[[1, dt * dt], [0, 1]], values={"dt": 1e200})
    text = str(info.value)
    assert "F[0][1] = dt**2" in text and "dt = 1e+200" in text and "1e+400" in text


def test_a_huge_number_is_shown_short():
    """1e400 in a model file is an integer of 401 digits: the message shows six digits."""
    with pytest.raises(NotFiniteError) as info:
        axis(F=[[1, sympy.Integer(10) ** 400], [0, 1]])
    text = str(info.value)
    assert "F[0][1] = 1.00000e+400 is not a finite double" in text and len(text) < 200


def test_entry_that_is_not_finite_or_not_real_at_the_values_is_named():
    c = sympy.Symbol("c", real=True)
    with pytest.raises(NotFiniteError, match=r"R\[0\]\[0\] = .*log.*c = 0.*inf"):
        axis(R=[[1 + sympy.log(c) ** 2]], values={"c": 0.0})
    with pytest.raises(NotFiniteError, match=r"R\[0\]\[0\] = .*sqrt.*c = -1.*not a real"):
        axis(R=[[2 + sympy.sqrt(c)]], values={"c": -1})


def test_value_beyond_the_double_range_is_named():
    with pytest.raises(SymbolError, match="value of 'dt'.*1e\\+400.*double"):
        axis(values={"dt": 10**400})


def test_numeric_names_the_entry_at_the_free_parameters():
    model = axis(F=[[1, dt**3], [0, 1]], declare=[dt])
    with pytest.raises(NotFiniteError, match=r"F\[0\]\[1\] = dt\*\*3.*dt = 1e\+200"):
        model.numeric({"dt": 1e200})


def test_huge_powers_do_not_hang():
    """Values that make entries astronomically large are refused quickly (a subprocess
    under a time limit: a hang fails the test instead of stalling the suite)."""
    script = textwrap.dedent("""
        import sympy
        from derive import LinearModel
        from derive.errors import NotFiniteError
        dt = sympy.Symbol("dt", positive=True)
        cases = [(dt**(10**9), 1e200), (sympy.exp(sympy.exp(sympy.exp(dt))), 1000.0),
                 (sympy.sin(sympy.exp(sympy.exp(dt))), 1000.0), ((1 + dt)**(10**9), 1e-15)]
        for entry, value in cases:
            try:
                LinearModel("h", ["s"], ["z"], [[entry]], [[1]], [[1]], [[1]],
                            values={"dt": value})
            except NotFiniteError as error:
                print("refused:", str(error)[:60])
            else:
                raise SystemExit(f"accepted {entry}")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("refused:") == 4


def test_huge_integer_entries_name_the_entry():
    with pytest.raises(ExpressionError, match=r"F\[0\]\[1\].*bits"):
        axis(F=[[1, 10**5000], [0, 1]])


# -- 6. compose and the P0 pattern ---------------------------------------------------------

def two_state_block(P0, pattern):
    """Two states coupled by neither F nor the noises: find_blocks splits them."""
    return LinearModel("b", ["a", "b"], ["ya", "yb"], np.eye(2), np.eye(2), np.eye(2),
                       np.eye(2), P0=P0, P0_pattern=pattern)


def test_compose_keeps_p0_cross_terms_of_a_dense_block():
    dense = two_state_block([[1, 0.5], [0.5, 1]], "dense")
    composed = LinearModel.compose("c", [dense, dense], ["x", "y"])
    assert composed.P0[0, 1] == sympy.Rational(1, 2)
    mask = composed.pattern_mask()
    assert all(mask[i][j] for i in range(4) for j in range(4)
               if composed.P0[i, j] != 0)
    assert composed.P0_pattern == "dense"


def test_compose_picks_the_narrowest_pattern_containing_the_blocks():
    diag = two_state_block(np.eye(2), "diagonal")
    assert LinearModel.compose("c", [diag, diag]).P0_pattern == "diagonal"
    zero = two_state_block(None, "zero")
    assert LinearModel.compose("c", [zero, zero]).P0_pattern == "zero"
    assert LinearModel.compose("c", [zero, diag]).P0_pattern == "diagonal"


def test_p0_outside_its_declared_pattern_is_refused_naming_the_entry():
    with pytest.raises(MatrixPropertyError, match=r"P0\[0\]\[1\] = 0.5.*'diagonal'"):
        two_state_block([[1, 0.5], [0.5, 1]], "diagonal")
    with pytest.raises(MatrixPropertyError, match=r"P0\[0\]\[1\] = 0.5.*'block'"):
        two_state_block([[1, 0.5], [0.5, 1]], "block")
    with pytest.raises(MatrixPropertyError, match=r"P0\[0\]\[0\] = 1.*'zero'"):
        two_state_block(np.eye(2), "zero")


# -- 7. names -----------------------------------------------------------------------------

@pytest.mark.parametrize("which", ["states", "measurements"])
def test_none_for_names_is_a_model_error(which):
    kwargs = {"states": ["s", "v"], "measurements": ["z"], which: None}
    with pytest.raises(NameError_, match=f"{which} must be a list of names"):
        LinearModel("n", kwargs["states"], kwargs["measurements"], np.eye(2), [[1, 0]],
                    np.eye(2), [[1]])


@pytest.mark.parametrize("name", ["a b", "while", "_x", "double", "pi"])
def test_free_symbols_must_be_identifiers(name):
    with pytest.raises(SymbolError, match=repr(name)):
        axis(F=[[1, sympy.Symbol(name)], [0, 1]])
