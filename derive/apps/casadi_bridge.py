"""sympy expressions as CasADi SX, to cross-check derive's Jacobians by automatic
differentiation.

:func:`to_casadi` translates one expression (numbers, symbols, + * ** and the functions of
:data:`FUNCTIONS`); :func:`check_jacobians` compares the Jacobians derive generates code
from (:func:`derive.filters.nonlinear.linearise`: simplified, sharing work with f and h) with
CasADi's ``jacobian`` of the model's own f and h at random points.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import sympy
from sympy import default_sort_key

from derive.errors import ModelError
from derive.filters import nonlinear
from derive.guards import SELECTS, IfGreater, numpy_selects


class CasadiTranslationError(ModelError):
    """An expression with a node CasADi has no counterpart for, or an unbound symbol."""


INSTALL_HINT = "pip install 'derive-filters[casadi]'"


def unavailable() -> str | None:
    """Why CasADi cannot be used in this environment, or None when it can."""
    try:
        import casadi  # noqa: F401  (an optional dependency: the casadi extra)
    except ImportError:
        return f"casadi is not installed ({INSTALL_HINT})"
    return None


def _casadi():
    try:
        import casadi  # an optional dependency: the casadi extra
    except ImportError as exc:
        raise ModelError(f"the CasADi cross-check needs the package casadi "
                         f"({INSTALL_HINT})") from exc
    return casadi


FUNCTIONS: dict[type, str] = {
    sympy.sin: "sin", sympy.cos: "cos", sympy.tan: "tan", sympy.exp: "exp",
    sympy.log: "log", sympy.atan: "atan", sympy.asin: "asin", sympy.acos: "acos",
    sympy.sinh: "sinh", sympy.cosh: "cosh", sympy.tanh: "tanh", sympy.Abs: "fabs",
}
"""sympy function -> casadi function of the same meaning (atan2 is handled apart)."""


def to_casadi(expr: sympy.Expr, symbols: Mapping[sympy.Symbol, object]):
    """CasADi SX of ``expr``; ``symbols`` maps every free symbol to an SX (or a number)."""
    ca = _casadi()
    memo: dict[sympy.Basic, object] = {}

    def go(e: sympy.Basic):
        if e in memo:
            return memo[e]
        if e.is_Symbol:
            if e not in symbols:
                raise CasadiTranslationError(
                    f"symbol {e.name!r} has no CasADi counterpart (bound: "
                    f"{sorted(s.name for s in symbols)})")
            out = symbols[e]
        elif e.is_number:
            value = complex(e.evalf(30))
            if value.imag != 0:
                raise CasadiTranslationError(f"constant {e} is not real")
            out = ca.SX(value.real)
        elif e.is_Add:
            out = go(e.args[0])
            for a in e.args[1:]:
                out = out + go(a)
        elif e.is_Mul:
            out = go(e.args[0])
            for a in e.args[1:]:
                out = out * go(a)
        elif e.is_Pow:
            base, exp = go(e.base), e.exp
            if exp == sympy.Rational(1, 2):
                out = ca.sqrt(base)
            elif exp == sympy.Rational(-1, 2):
                out = 1 / ca.sqrt(base)
            elif exp.is_Integer:
                out = ca.constpow(base, int(exp))
            else:
                out = base ** go(exp)
        elif isinstance(e, sympy.atan2):
            out = ca.atan2(go(e.args[0]), go(e.args[1]))
        elif isinstance(e, SELECTS):  # both branches computed, as generated code does
            left, right, a, b = (go(arg) for arg in e.args)
            out = ca.if_else(left > right if isinstance(e, IfGreater) else left >= right,
                             a, b)
        elif type(e) in FUNCTIONS:
            out = getattr(ca, FUNCTIONS[type(e)])(go(e.args[0]))
        else:
            raise CasadiTranslationError(f"no CasADi translation for {type(e).__name__} "
                                         f"in {e}")
        memo[e] = out
        return out

    return go(sympy.sympify(expr))


def casadi_function(name: str, outputs: Sequence[sympy.Expr], wrt: Sequence[sympy.Symbol],
                    others: Sequence[sympy.Symbol]):
    """A casadi.Function ``(wrt, others) -> (values, d values / d wrt)`` by CasADi's AD."""
    ca = _casadi()
    X = ca.SX.sym("X", len(wrt))
    U = ca.SX.sym("U", len(others))
    bound = {s: X[i] for i, s in enumerate(wrt)}
    bound.update({s: U[i] for i, s in enumerate(others)})
    values = ca.vertcat(*[to_casadi(e, bound) for e in outputs])
    return ca.Function(name, [X, U], [values, ca.jacobian(values, X)])


@dataclass(frozen=True)
class JacobianCheck:
    """Largest normwise relative difference, over the points, of (values, Jacobian) of
    f and of h between derive's linearisation and CasADi's AD."""

    model: str
    points: int
    f_values: float
    f_jacobian: float
    h_values: float
    h_jacobian: float

    @property
    def worst(self) -> float:
        return max(self.f_values, self.f_jacobian, self.h_values, self.h_jacobian)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    scale = max(float(np.max(np.abs(b))) if b.size else 0.0, np.finfo(float).tiny)
    return float(np.max(np.abs(a - b))) / scale if b.size else 0.0


Sampler = Callable[[np.random.Generator, Sequence[sympy.Symbol]], np.ndarray]


def normal_sampler(rng: np.random.Generator, symbols: Sequence[sympy.Symbol]) -> np.ndarray:
    """Every symbol ~ N(0, 10²): the default random point."""
    return rng.normal(0.0, 10.0, len(symbols))


def check_jacobians(model, points: int = 100, seed: int = 0,
                    sampler: Sampler = normal_sampler) -> JacobianCheck:
    """Compare derive's (f, F) and (h, H) with CasADi's at ``points`` random points.

    A point where either side is not finite (outside the domain of a log or sqrt) is
    drawn again; after 100 * points draws without enough finite points, ModelError.
    """
    states = list(model.state_symbols)
    others = list(model.inputs) + sorted(model.parameters, key=default_sort_key)
    every = states + others
    results = {}
    for label, exprs in (("f", model.subs(model.f)), ("h", model.subs(model.h))):
        values, jac = nonlinear.linearise(exprs, states).expanded()
        ours = sympy.lambdify([every], [values, jac], modules=[numpy_selects(), "numpy"])
        theirs = casadi_function(label, list(exprs), states, others)
        rng = np.random.default_rng(seed)
        worst_v = worst_j = 0.0
        used = tries = 0
        while used < points:
            tries += 1
            if tries > 100 * points:
                raise ModelError(f"model {model.name!r}: fewer than {points} of "
                                 f"{100 * points} random points are in the domain of {label}")
            point = np.asarray(sampler(rng, every), dtype=float)
            with np.errstate(all="ignore"):
                v, J = (np.asarray(a, dtype=float) for a in ours(point))
            cv, cJ = (np.asarray(a.full(), dtype=float)
                      for a in theirs(point[: len(states)], point[len(states):]))
            if not (np.all(np.isfinite(v)) and np.all(np.isfinite(J))
                    and np.all(np.isfinite(cv)) and np.all(np.isfinite(cJ))):
                continue
            used += 1
            worst_v = max(worst_v, _relative(v.reshape(cv.shape), cv))
            worst_j = max(worst_j, _relative(J.reshape(cJ.shape), cJ))
        results[label] = (worst_v, worst_j)
    return JacobianCheck(model.name, points, *results["f"], *results["h"])
