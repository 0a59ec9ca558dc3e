"""Model objects: linear discrete, linear continuous (discretised exactly) and nonlinear.

Entries stay symbolic. Symbols with a value in ``values`` are constants of the
model; the others are free runtime parameters, passed to generated code as
``p`` in the order of :attr:`parameters` (sorted by name).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import sympy

from .errors import MatrixPropertyError, ModelError, ShapeError, SymbolError
from .symbols import (
    as_matrix,
    check_identifier,
    check_names,
    check_shape,
    normalize_values,
    symbol,
)

P0_PATTERNS = ("dense", "zero", "diagonal", "block")


@dataclass(frozen=True)
class NumericLinear:
    """A linear model at numbers: what the NumPy reference filters take."""

    F: np.ndarray
    G: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    x0: np.ndarray
    P0: np.ndarray

    @property
    def GQGt(self) -> np.ndarray:
        return self.G @ self.Q @ self.G.T


class _Model:
    """What linear and nonlinear models share: names, values, free parameters."""

    kind = "model"

    def _init_names(self, name, states, measurements, description, source) -> None:
        self.name = check_identifier(name, "model name")
        self.states = check_names(states, "states")
        self.measurements = check_names(measurements, "measurements")
        clash = set(self.states) & set(self.measurements)
        if clash:
            raise SymbolError(f"name {sorted(clash)[0]!r} is both a state and a measurement")
        self.description = str(description)
        self.source = str(source)

    def _init_values(self, values, used: set[sympy.Symbol], reserved: set[str]) -> None:
        self.values = normalize_values(values)
        used_names = {s.name for s in used}
        for nm in self.values:
            if nm in reserved:
                raise SymbolError(f"value given for {nm!r}, which is a state or input, "
                                  "not a parameter")
            if nm not in used_names:
                raise SymbolError(f"value given for unknown symbol {nm!r}: it appears in no "
                                  f"matrix of model {self.name!r}")
        for s in used:
            if s.name in self.measurements:
                raise SymbolError(f"symbol {s.name!r} is a measurement name; measurements "
                                  "cannot appear in model matrices")
        for s in used:
            try:
                check_identifier(s.name, "symbol")
            except ModelError as exc:
                raise SymbolError(str(exc)) from None
        self.symbols = tuple(sorted(used, key=lambda s: s.name))
        self.parameters = tuple(s for s in self.symbols if s.name not in self.values)
        self._subs = {symbol(k): v for k, v in self.values.items()}

    @property
    def n(self) -> int:
        return len(self.states)

    @property
    def m(self) -> int:
        return len(self.measurements)

    def subs(self, expr):
        """``expr`` with every valued symbol replaced by its exact value."""
        return expr.xreplace(self._subs) if self._subs else expr

    def parameter_values(self, params=None) -> dict[sympy.Symbol, sympy.Expr]:
        """Values for the free parameters from ``params`` (name -> number); all required."""
        given = normalize_values(params)
        for nm in given:
            if nm not in {p.name for p in self.parameters}:
                raise SymbolError(f"{nm!r} is not a free parameter of model {self.name!r} "
                                  f"(free: {[p.name for p in self.parameters]})")
        missing = [p.name for p in self.parameters if p.name not in given]
        if missing:
            raise SymbolError(f"model {self.name!r} needs values for free parameters {missing}")
        return {symbol(k): v for k, v in given.items()}

    def _initial(self, x0, P0, P0_pattern) -> None:
        n = self.n
        self.x0 = (sympy.ImmutableMatrix.zeros(n, 1) if x0 is None
                   else as_matrix(x0, "x0", vector=True))
        check_shape(self.x0, "x0", (n, 1), "one entry per state")
        self.P0 = sympy.ImmutableMatrix.zeros(n, n) if P0 is None else as_matrix(P0, "P0")
        check_shape(self.P0, "P0", (n, n), "states x states")
        for mat, nm in ((self.x0, "x0"), (self.P0, "P0")):
            if mat.free_symbols:
                raise SymbolError(f"{nm} must be numeric, has symbols "
                                  f"{sorted(s.name for s in mat.free_symbols)}")
        _check_symmetric(self.P0, "P0")
        if P0_pattern is None:
            P0_pattern = "dense"
        if P0_pattern not in P0_PATTERNS:
            raise SymbolError(f"P0_pattern {P0_pattern!r} is not one of {P0_PATTERNS}")
        self.P0_pattern = P0_pattern

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.name!r}, n={self.n}, m={self.m}, "
                f"parameters={[p.name for p in self.parameters]})")


def _check_symmetric(mat: sympy.MatrixBase, name: str) -> None:
    diff = (mat - mat.T).applyfunc(sympy.simplify)
    if any(e != 0 for e in diff):
        i, j = next((i, j) for i in range(mat.rows) for j in range(mat.cols) if diff[i, j] != 0)
        raise MatrixPropertyError(
            f"matrix {name} must be symmetric: {name}[{i}][{j}] = {mat[i, j]} but "
            f"{name}[{j}][{i}] = {mat[j, i]}"
        )


def _check_definite(mat: sympy.MatrixBase, name: str, strict: bool) -> None:
    """Check a numeric symmetric matrix is positive (semi)definite; skip if symbolic."""
    if mat.free_symbols:
        return
    a = np.array(mat.tolist(), dtype=float)
    eig = np.linalg.eigvalsh(a)
    scale = max(1.0, float(np.max(np.abs(eig)))) if eig.size else 1.0
    tol = 1e-12 * scale
    low = float(eig.min())
    if strict and low <= tol:
        raise MatrixPropertyError(
            f"matrix {name} must be positive definite at the given values; its smallest "
            f"eigenvalue is {low:.3g}")
    if not strict and low < -tol:
        raise MatrixPropertyError(
            f"matrix {name} must be positive semidefinite at the given values; its smallest "
            f"eigenvalue is {low:.3g}")


class LinearModel(_Model):
    """A linear time-invariant discrete model (SPEC §1).

    ``x(k+1) = F x(k) + G w(k)``, ``z(k) = H x(k) + v(k)``, ``w ~ N(0, Q)``, ``v ~ N(0, R)``.
    """

    kind = "linear"

    def __init__(self, name, states, measurements, F, H, Q, R, G=None, values=None,
                 x0=None, P0=None, P0_pattern=None, description="", source=""):
        self._init_names(name, states, measurements, description, source)
        n, m = self.n, self.m
        self.F = as_matrix(F, "F")
        check_shape(self.F, "F", (n, n), "states x states")
        self.H = as_matrix(H, "H")
        check_shape(self.H, "H", (m, n), "measurements x states")
        self.G = sympy.ImmutableMatrix.eye(n) if G is None else as_matrix(G, "G", vector=True)
        if self.G.rows != n:
            raise ShapeError(f"matrix G must have {n} rows (one per state), got "
                             f"{self.G.rows}x{self.G.cols}")
        q = self.G.cols
        self.Q = as_matrix(Q, "Q")
        check_shape(self.Q, "Q", (q, q), "noise inputs x noise inputs, one per column of G")
        self.R = as_matrix(R, "R")
        check_shape(self.R, "R", (m, m), "measurements x measurements")
        used = set()
        for mat in (self.F, self.G, self.H, self.Q, self.R):
            used |= mat.free_symbols
        self._init_values(values, used, set(self.states))
        for s in used:
            if s.name in self.states:
                raise SymbolError(f"symbol {s.name!r} is a state name; a linear model's "
                                  "matrices cannot depend on the state")
        _check_symmetric(self.Q, "Q")
        _check_symmetric(self.R, "R")
        _check_definite(self.subs(self.Q), "Q", strict=False)
        _check_definite(self.subs(self.R), "R", strict=True)
        self._initial(x0, P0, P0_pattern)

    @property
    def noise_dim(self) -> int:
        return self.G.cols

    def matrix(self, which: str) -> sympy.ImmutableMatrix:
        """``F, G, H, Q, R`` or ``GQGt`` with the given values substituted (exact)."""
        if which == "GQGt":
            return sympy.ImmutableMatrix(
                (self.subs(self.G) * self.subs(self.Q) * self.subs(self.G).T)
                .applyfunc(sympy.expand))
        if which not in ("F", "G", "H", "Q", "R"):
            raise KeyError(which)
        return self.subs(getattr(self, which))

    def numeric(self, params=None) -> NumericLinear:
        """The model at numbers; free parameters must be given in ``params``."""
        extra = self.parameter_values(params)

        def arr(mat):
            return np.array(mat.xreplace(extra).evalf(17).tolist(), dtype=float)

        m = {k: arr(self.matrix(k)) for k in ("F", "G", "H", "Q", "R")}
        return NumericLinear(x0=np.array(self.x0.tolist(), dtype=float).ravel(),
                             P0=np.array(self.P0.tolist(), dtype=float), **m)

    @classmethod
    def from_continuous(cls, name, states, measurements, Phi, Qc, H, R, dt, G=None,
                        values=None, x0=None, P0=None, P0_pattern=None, description="",
                        source=""):
        """Discretise ``dx/dt = Phi x + G w`` (spectral density Qc) exactly over ``dt``."""
        from .discretize import discretize
        from .symbols import normalize

        n = len(check_names(states, "states"))
        Phi_m = as_matrix(Phi, "Phi")
        check_shape(Phi_m, "Phi", (n, n), "states x states")
        G_m = sympy.ImmutableMatrix.eye(n) if G is None else as_matrix(G, "G", vector=True)
        if G_m.rows != n:
            raise ShapeError(f"matrix G must have {n} rows (one per state), got "
                             f"{G_m.rows}x{G_m.cols}")
        Qc_m = as_matrix(Qc, "Qc")
        check_shape(Qc_m, "Qc", (G_m.cols, G_m.cols), "noise inputs x noise inputs")
        _check_symmetric(Qc_m, "Qc")
        dt_e = normalize(dt, "dt")
        F, Qd, method = discretize(Phi_m, G_m, Qc_m, dt_e, normalize_values(values))
        if method == "numeric-expm":  # symbols of Phi and dt are now numbers in F and Qd
            kept = {s.name for s in F.free_symbols | Qd.free_symbols
                    | as_matrix(H, "H").free_symbols | as_matrix(R, "R").free_symbols}
            values = {k: v for k, v in normalize_values(values).items() if k in kept}
        model = cls(name, states, measurements, F, H, Qd, R, G=None, values=values, x0=x0,
                    P0=P0, P0_pattern=P0_pattern, description=description, source=source)
        model.continuous = {"Phi": Phi_m, "G": G_m, "Qc": Qc_m, "dt": dt_e, "method": method}
        return model

    @classmethod
    def compose(cls, name, models, suffixes=None, description="", source=""):
        """Block-diagonal composition (model A = three model-B axes)."""
        from .structure import compose

        return compose(cls, name, models, suffixes, description=description, source=source)

    def blocks(self):
        """Independent blocks of the model (see :func:`derive.structure.find_blocks`)."""
        from .structure import find_blocks

        return find_blocks(self)


class NonlinearModel(_Model):
    """``x(k+1) = f(x(k)) + w(k)``, ``z(k) = h(x(k), u(k)) + v(k)`` (SPEC §6).

    ``inputs`` are per-step input symbols (satellite coordinates): they change every
    step and are passed to the generated filter beside z.
    """

    kind = "nonlinear"

    def __init__(self, name, states, measurements, f, h, Q, R, values=None, inputs=None,
                 x0=None, P0=None, P0_pattern=None, description="", source=""):
        self._init_names(name, states, measurements, description, source)
        n, m = self.n, self.m
        self.inputs = tuple(symbol(s) for s in check_names(inputs, "inputs")) if inputs else ()
        reserved = set(self.states) | {s.name for s in self.inputs}
        if len(reserved) != n + len(self.inputs):
            raise SymbolError("an input has the same name as a state: "
                              f"{sorted(set(self.states) & {s.name for s in self.inputs})}")
        self.f = as_matrix(f, "f", vector=True)
        check_shape(self.f, "f", (n, 1), "one expression per state")
        self.h = as_matrix(h, "h", vector=True)
        check_shape(self.h, "h", (m, 1), "one expression per measurement")
        self.Q = as_matrix(Q, "Q")
        check_shape(self.Q, "Q", (n, n), "states x states")
        self.R = as_matrix(R, "R")
        check_shape(self.R, "R", (m, m), "measurements x measurements")
        self.state_symbols = tuple(symbol(s) for s in self.states)
        used = set()
        for mat in (self.f, self.h, self.Q, self.R):
            used |= mat.free_symbols
        for mat, nm in ((self.Q, "Q"), (self.R, "R")):
            bad = {s.name for s in mat.free_symbols} & reserved
            if bad:
                raise SymbolError(f"matrix {nm} depends on state or input {sorted(bad)[0]!r}")
        bad_f = {s.name for s in self.f.free_symbols} & {s.name for s in self.inputs}
        if bad_f:
            raise SymbolError(f"f depends on per-step input {sorted(bad_f)[0]!r}; inputs may "
                              "only appear in h")
        params = {s for s in used if s.name not in reserved}
        self._init_values(values, params, reserved)
        _check_symmetric(self.Q, "Q")
        _check_symmetric(self.R, "R")
        _check_definite(self.subs(self.Q), "Q", strict=False)
        _check_definite(self.subs(self.R), "R", strict=True)
        self._initial(x0, P0, P0_pattern)
        X = sympy.Matrix(self.state_symbols)
        self.F_jacobian = sympy.ImmutableMatrix(self.f.jacobian(X))
        self.H_jacobian = sympy.ImmutableMatrix(self.h.jacobian(X))

    def numeric_functions(self, params=None) -> dict[str, Callable | np.ndarray]:
        """NumPy callables ``f(x)``, ``F(x)``, ``h(x, u)``, ``H(x, u)`` and arrays Q, R.

        Vectors come back flat (shape (n,) or (m,)), Jacobians as 2-D arrays.
        """
        extra = self.parameter_values(params)
        X = sympy.Matrix(self.state_symbols)
        U = sympy.Matrix(self.inputs) if self.inputs else sympy.Matrix.zeros(0, 1)

        def fn(mat, with_u):
            e = self.subs(mat).xreplace(extra)
            args = [list(X), list(U)] if with_u else [list(X)]
            lam = sympy.lambdify(args, e, modules="numpy", cse=True)
            shape = (mat.rows,) if mat.cols == 1 else mat.shape

            def call(x, u=()):
                vals = [list(np.asarray(x, float).ravel())]
                if with_u:
                    vals.append(list(np.asarray(u, float).ravel()))
                return np.asarray(lam(*vals), dtype=float).reshape(shape)
            return call

        def num(mat):
            return np.array(self.subs(mat).xreplace(extra).evalf(17).tolist(), dtype=float)

        return {"f": fn(self.f, False), "F": fn(self.F_jacobian, False),
                "h": fn(self.h, True), "H": fn(self.H_jacobian, True),
                "Q": num(self.Q), "R": num(self.R)}
