"""Exact discretisation: SPEC §1's CV and CA matrices, derived, compared symbolically."""

import sympy
from conftest import dt, sq2, sr2

from derive import LinearModel
from derive.discretize import discretize


def _zero(a, b):
    return all(sympy.simplify(e) == 0 for e in (sympy.Matrix(a) - sympy.Matrix(b)))


def test_constant_velocity():
    F, Qd, _ = discretize(sympy.Matrix([[0, 1], [0, 0]]), sympy.Matrix([0, 1]),
                       sympy.Matrix([[sq2]]), dt)
    assert _zero(F, [[1, dt], [0, 1]])
    assert _zero(Qd, sq2 * sympy.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))


def test_constant_acceleration():
    F, Qd, _ = discretize(sympy.Matrix([[0, 1, 0], [0, 0, 1], [0, 0, 0]]), sympy.Matrix([0, 0, 1]),
                       sympy.Matrix([[sq2]]), dt)
    assert _zero(F, [[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]])
    expected = sq2 * sympy.Matrix([[dt**5 / 20, dt**4 / 8, dt**3 / 6],
                                   [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                                   [dt**3 / 6, dt**2 / 2, dt]])
    assert _zero(Qd, expected)


def test_van_loan_equals_the_integral_for_an_oscillator():
    """A non-nilpotent Phi: compare with the defining integral, computed independently."""
    w = sympy.Symbol("w", real=True)
    s = sympy.Symbol("s", real=True)
    Phi = sympy.Matrix([[0, 1], [-w**2, 0]])
    G = sympy.Matrix([0, 1])
    F, Qd, _ = discretize(Phi, G, sympy.Matrix([[sq2]]), dt)
    E = sympy.Matrix([[sympy.cos(w * s), sympy.sin(w * s) / w],
                      [-w * sympy.sin(w * s), sympy.cos(w * s)]])
    integral = (E * G * sq2 * G.T * E.T).applyfunc(lambda e: sympy.integrate(e, (s, 0, dt)))
    vals = {w: sympy.Rational(7, 10), dt: sympy.Rational(3, 10), sq2: 2}
    assert _zero(F.subs(vals), E.subs(s, dt).subs(vals))
    for a, b in zip(Qd.subs(vals), integral.subs(vals)):
        assert abs(sympy.N(a - b, 30)) < 1e-25


def test_from_continuous_builds_model():
    m = LinearModel.from_continuous("cv", ["s", "v"], ["z"], [[0, 1], [0, 0]], [[sq2]],
                                    [[1, 0]], [[sr2]], dt, G=[0, 1],
                                    values={"dt": 1, "sq2": 0.01, "sr2": 0.1})
    assert m.G == sympy.eye(2)
    assert _zero(m.Q, sq2 * sympy.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    assert m.matrix("Q")[0, 0] == sympy.Rational(1, 300)
