"""derive's sympy Jacobians (derive.filters.nonlinear.linearise) against CasADi's automatic
differentiation of the same expressions (derive.apps.casadi_bridge)."""

import numpy as np
import pytest
import sympy

pytest.importorskip("casadi")

from derive import NonlinearModel, catalog  # noqa: E402
from derive.apps.casadi_bridge import (  # noqa: E402
    CasadiTranslationError,
    casadi_function,
    check_jacobians,
    to_casadi,
)
from derive.filters import nonlinear as nonlinear_module  # noqa: E402

RTOL = 1e-12
NONLINEAR = [name for name in catalog.names() if catalog.load(name).kind == "nonlinear"]


def gnss_sampler(rng, symbols):
    """Receiver near the Earth's surface, satellites at GPS distances, bias in metres."""
    out = []
    for s in symbols:
        if s.name[:2] in ("xs", "ys", "zs"):
            out.append(rng.uniform(-2.66e7, 2.66e7))
        elif s.name in ("x", "y", "z"):
            out.append(rng.uniform(-6.4e6, 6.4e6))
        else:
            out.append(rng.normal(0.0, 1e3))
    return np.array(out)


def test_catalog_has_a_nonlinear_model():
    assert "gnss_pseudorange" in NONLINEAR


@pytest.mark.parametrize("name", NONLINEAR)
def test_sympy_jacobians_agree_with_casadi(name):
    model = catalog.load(name)
    for sampler_kw in ({}, {"sampler": gnss_sampler} if name.startswith("gnss") else {}):
        check = check_jacobians(model, points=100, seed=3, **sampler_kw)
        assert check.points == 100
        assert check.worst <= RTOL, check


RANGE_BEARING = NonlinearModel(
    "unicycle", ["px", "py", "th", "v"], ["r", "phi"],
    f=["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w", "v*exp(-dt/tau)"],
    h=["sqrt((ax - px)**2 + (ay - py)**2)", "atan2(ay - py, ax - px) - th"],
    Q=np.diag([0.01, 0.01, 0.001, 0.1]).tolist(), R=[["sr", 0], [0, 0.001]],
    inputs=["ax", "ay"], values={"dt": 0.1, "tau": 5, "w": 0.2}, parameters=["sr"])


def test_trigonometric_model_agrees_with_casadi():
    check = check_jacobians(RANGE_BEARING, points=100, seed=1)
    assert check.worst <= RTOL, check
    # the check is not vacuous: both sides are nonzero functions of the state
    fn = casadi_function("h", list(RANGE_BEARING.subs(RANGE_BEARING.h)),
                         RANGE_BEARING.state_symbols, list(RANGE_BEARING.inputs) + [
                             sympy.Symbol("sr", real=True)])
    _, J = fn([1.0, 2.0, 0.3, 4.0], [5.0, -1.0, 0.1])
    assert np.count_nonzero(np.asarray(J.full())) >= 5


def test_a_wrong_jacobian_is_caught(monkeypatch):
    real = nonlinear_module.linearise

    def off_by_a_little(values, wrt, with_jacobian=True):
        lin = real(values, wrt, with_jacobian)
        jac = sympy.ImmutableMatrix(lin.jacobian.rows, lin.jacobian.cols,
                                    lambda i, j: lin.jacobian[i, j] * (1 + sympy.Rational(1, 10**9)
                                                                       if (i, j) == (0, 0) else 1))
        return nonlinear_module.Linearisation(lin.shared, lin.values, jac)

    monkeypatch.setattr(nonlinear_module, "linearise", off_by_a_little)
    check = check_jacobians(catalog.load("gnss_pseudorange"), points=5, seed=0)
    assert 1e-10 < check.h_jacobian < 1e-8


def test_translation_of_numbers_powers_and_errors():
    import casadi

    x, y = sympy.symbols("x y", real=True)
    X, Y = casadi.SX.sym("X"), casadi.SX.sym("Y")
    expr = sympy.pi * x ** 3 / y + x ** sympy.Rational(3, 2) - 1 / sympy.sqrt(y) + sympy.Abs(y)
    fn = casadi.Function("e", [X, Y], [to_casadi(expr, {x: X, y: Y})])
    value = float(fn(2.0, 3.0))
    expected = float(expr.subs({x: 2.0, y: 3.0}))
    assert value == pytest.approx(expected, rel=1e-15)
    with pytest.raises(CasadiTranslationError, match="gamma"):
        to_casadi(sympy.gamma(x), {x: X})
    with pytest.raises(CasadiTranslationError, match="'y'"):
        to_casadi(x + y, {x: X})
