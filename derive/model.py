"""Model objects: linear discrete, linear continuous (discretised exactly) and nonlinear.

Entries stay symbolic, with the symbols the user gave (assumptions included). Symbols
with a value in ``values`` are constants of the model; the others are free runtime
parameters, passed to generated code as ``p`` in the order of :attr:`parameters`: the
names of the ``parameters`` argument first, in that order, then the other free symbols
in order of first appearance, scanning the matrices in argument order (linear: F, G, H,
Q, R, B, D; continuous: Phi, G, Qc, H, R, dt; nonlinear: f, h, Q, R), each row by row
(within one entry, ``k2`` before ``k10``). With ``sensors``, each sensor's matrices (linear:
H, R, D; nonlinear: h, R) in declaration order take the place of the stacked H (h).
"""

from __future__ import annotations

import copy
import functools
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import sympy

from . import structure
from .discretize import discretize
from .domains import check_value
from .errors import MatrixPropertyError, ModelError, ShapeError, SymbolError
from .finite import check_entries
from .forms import ROW_FORMS, UPDATE_FORMS
from .guards import numpy_selects, selects
from .manifolds import QUATERNION, TangentLayout, parse_manifolds
from .symbols import (
    SymbolTable,
    as_matrix,
    check_identifier,
    check_names,
    check_shape,
    decimal,
    jacobian,
    normalize,
    normalize_values,
    real_stand_ins,
    symbol,
)

P0_PATTERNS = ("dense", "zero", "diagonal", "block")

Entry = str | int | float | sympy.Expr
"""One matrix entry: a number, a SymPy expression, or an expression as text (``"dt**2/2"``)."""
Matrix = sympy.MatrixBase | np.ndarray | Sequence[Sequence[Entry]]
"""A matrix: rows of entries, a NumPy array or a SymPy matrix."""
Vector = sympy.MatrixBase | np.ndarray | Sequence[Entry]
"""A vector (x0, f, h; a column G): a list of entries, a NumPy array or a SymPy matrix."""
Values = Mapping[str | sympy.Symbol, Entry]
"""Symbol (or its name) -> value: the symbols that are constants of the model."""
Names = Sequence[str | sympy.Symbol]
"""Names in order (the runtime parameters ``p``)."""

SYMMETRY_TOLERANCE = 1e-12
"""Q, R, P0 (and Qc) are accepted as symmetric when, for every pair of numeric entries,
``|M[i][j] - M[j][i]| <= 1e-12 * max(|M[i][j]|, |M[j][i]|, sqrt(|M[i][i] M[j][j]|))``;
they are then symmetrised (both entries become the mean). Symbolic entries must be
exactly symmetric."""


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
    B: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    D: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def GQGt(self) -> np.ndarray:
        return self.G @ self.Q @ self.G.T


R_ARGUMENT = "argument"
"""A sensor's R given per call (``Sensor(..., R="argument")``, ``R = "argument"`` in a
model file): its update takes R (m_s x m_s, symmetric positive definite) beside z."""


@dataclass(frozen=True)
class Sensor:
    """A named measurement group of a model (``sensors=[Sensor(...), ...]``): its own
    measurements, h (NonlinearModel: expressions in states, its inputs and parameters) or
    H (LinearModel; with D over its inputs: ``z = H x + D u + v``), R (constant, symbolic
    in parameters, or :data:`R_ARGUMENT`: given per call, an input of its update and a
    per-step array of run) and inputs (names among the model's ``inputs``; default: a
    nonlinear sensor's, those its h uses; a linear sensor's, all of them when D is given,
    else none). ``update``: how its update fuses its measurements, ``"batch"`` (one LDL^T
    solve of S) or ``"sequential"`` (one scalar update per measurement; R must be constant
    and diagonal); the filter option ``update`` overrides it for every sensor.

    A model with sensors has one ``update_<name>`` per sensor beside ``predict``; its
    ``measurements``, ``h``/``H``, ``R`` and ``D`` are the sensors' stacked (R block
    diagonal), in declaration order.
    """

    name: str
    measurements: Sequence[str]
    h: Vector | None = None
    H: Matrix | None = None
    R: Matrix | None = None
    inputs: Sequence[str] | None = None
    D: Matrix | None = None
    update: str = "batch"


@dataclass(frozen=True)
class SensorGroup:
    """A model's sensor, resolved: name, measurements, the rows it holds in the stacked
    measurement vector, its inputs (symbols, a subset of the model's, in model order) and
    its matrices with the model's symbols: ``h`` (nonlinear) or ``H`` and ``D`` (linear, D
    over this sensor's inputs), ``R``."""

    name: str
    measurements: tuple[str, ...]
    rows: tuple[int, int]
    inputs: tuple[sympy.Symbol, ...]
    R: sympy.ImmutableMatrix
    h: sympy.ImmutableMatrix | None = None
    H: sympy.ImmutableMatrix | None = None
    D: sympy.ImmutableMatrix | None = None
    R_argument: bool = False
    update: str = "batch"

    @property
    def m(self) -> int:
        return len(self.measurements)


SENSOR_UPDATES = UPDATE_FORMS
"""How a sensor's update may fuse its measurements (``Sensor.update``): the choices of the
filter option ``update``, which overrides it."""


def sequential_problem(name: str, R: sympy.MatrixBase, R_argument: bool) -> str | None:
    """Why sensor ``name`` (its R, valued symbols substituted; ``R_argument``: R given per
    call) cannot be updated one scalar measurement at a time, or None when it can: the
    scalar updates equal the batch update only for uncorrelated measurement noises, so R
    must be diagonal, or constant (then decorrelated by its LDL^T factors when the code is
    generated: derive.filters.sensors.sequential_update)."""
    if R_argument:
        return (f"sensor {name!r}: the sequential update needs R diagonal or constant, but "
                "its R is given per call")
    if R.free_symbols:
        for i in range(R.rows):
            for j in range(i + 1, R.cols):
                if R[i, j] != 0:
                    return (f"sensor {name!r}: the sequential update needs R diagonal or "
                            f"constant (to decorrelate it when the code is generated), but "
                            f"R[{i}, {j}] = {R[i, j]} is not zero and R depends on "
                            f"{', '.join(sorted(s.name for s in R.free_symbols))}")
    return None


def _sensor_update(sensor: Sensor, R: sympy.MatrixBase) -> str:
    """``sensor.update``, checked: one of SENSOR_UPDATES; sequential only where it holds."""
    if sensor.update not in SENSOR_UPDATES:
        raise ModelError(f"sensor {sensor.name!r}: update must be one of "
                         f"{', '.join(SENSOR_UPDATES)}, got {sensor.update!r}")
    if sensor.update == "sequential":
        problem = sequential_problem(sensor.name, R, _R_given_per_call(sensor))
        if problem:
            raise ModelError(problem)
    return sensor.update


def _sensor_list(sensors, kind: str, given: Mapping[str, object]) -> tuple[Sensor, ...]:
    """The sensors as a tuple of :class:`Sensor`, refused when the stacked measurement
    arguments (``given``: measurements, h/H, R, D) are given too, or a sensor has the
    wrong matrix for ``kind`` (h for nonlinear, H and D for linear)."""
    if isinstance(sensors, (str, Sensor)) or not isinstance(sensors, Sequence):
        raise ModelError("sensors must be a list of derive.Sensor, got "
                         f"{type(sensors).__name__}")
    if not sensors:
        raise ModelError("sensors must not be empty (leave it out for a model with one "
                         "measurement group)")
    both = [key for key, value in given.items() if value is not None]
    if both:
        raise ModelError(f"give either sensors or {', '.join(both)}, not both: a model with "
                         "sensors takes its measurements, "
                         + ("h" if kind == "nonlinear" else "H, D") + " and R from them")
    names: dict[str, str] = {}  # upper case -> as declared
    for sensor in sensors:
        if not isinstance(sensor, Sensor):
            raise ModelError(f"sensors must hold derive.Sensor objects, got "
                             f"{type(sensor).__name__} {sensor!r}")
        name = check_identifier(sensor.name, "sensor name")
        if name in names.values():
            raise SymbolError(f"sensor {name!r} is declared twice")
        if name.upper() in names:
            # generated C names each sensor in upper case too (PREFIX_M_GPS, the status
            # enum's PREFIX_STATUS_UPDATE_GPS_...): two such names would be one
            raise SymbolError(f"sensor names {names[name.upper()]!r} and {name!r} differ "
                              f"only in case; generated C names sensors in upper case "
                              f"({name.upper()}), so they would be one name")
        names[name.upper()] = name
        wanted, wrong = (("h",), ("H", "D")) if kind == "nonlinear" else (("H",), ("h",))
        for key in wrong:
            if getattr(sensor, key) is not None:
                raise ModelError(f"sensor {name!r}: {key} is for a "
                                 f"{'linear' if kind == 'nonlinear' else 'nonlinear'} model; "
                                 f"a {kind} model's sensor gives {wanted[0]}")
        for key in wanted + ("R",):
            if getattr(sensor, key) is None:
                raise ModelError(f"sensor {name!r}: missing {key}")
    return tuple(sensors)


def _R_given_per_call(sensor: Sensor) -> bool:
    return isinstance(sensor.R, str) and sensor.R == R_ARGUMENT


def _sensor_R(sensor: Sensor, table: SymbolTable) -> sympy.ImmutableMatrix:
    """A sensor's R, checked under its name (shape, symmetry); for :data:`R_ARGUMENT` the
    identity, which stands in the stacked R (the update takes the real R per call)."""
    label = f"R of sensor {sensor.name!r}"
    m_s = len(sensor.measurements)
    if _R_given_per_call(sensor):
        return sympy.ImmutableMatrix.eye(m_s)
    R_s = as_matrix(sensor.R, label, table)
    check_shape(R_s, label, (m_s, m_s), "its measurements x measurements")
    return _symmetric(R_s, label)


def _sensor_inputs(sensor: Sensor, model_inputs: Sequence[str], default: Sequence[str]
                   ) -> tuple[str, ...]:
    """A sensor's input names: its own list (each one of the model's), else ``default``;
    returned in the model's order."""
    if sensor.inputs is None:
        names = tuple(default)
    else:
        names = check_names(sensor.inputs, f"inputs of sensor {sensor.name!r}") \
            if sensor.inputs else ()
    for u in names:
        if u not in model_inputs:
            raise SymbolError(f"sensor {sensor.name!r}: input {u!r} is not one of the model's "
                              f"inputs {list(model_inputs)}")
    return tuple(u for u in model_inputs if u in names)


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

    def _init_values(self, values, table: SymbolTable, used: set[sympy.Symbol],
                     reserved: set[str], order) -> None:
        """Values, the model's symbols and the free parameters in the order of ``p``."""
        given = normalize_values(values, table)
        self.values = dict(sorted(given.items()))
        self._by_name = dict(table.by_name)
        used_names = {s.name for s in used}
        for nm in self.values:
            if nm in reserved:
                raise SymbolError(f"value given for {nm!r}, which is a state or input, "
                                  "not a parameter")
            if nm not in used_names:
                raise SymbolError(f"value given for unknown symbol {nm!r}: it appears in no "
                                  f"matrix of model {self.name!r}")
            check_value(table.by_name[nm], self.values[nm], f"model {self.name!r} values")
        for s in used:
            if s.name in self.measurements:
                raise SymbolError(f"symbol {s.name!r} is a measurement name; measurements "
                                  "cannot appear in model matrices")
        for s in used:
            try:
                check_identifier(s.name, "symbol")
            except ModelError as exc:
                raise SymbolError(str(exc)) from None
        first = [s for s in table.by_name.values() if s in used]
        self.symbols = tuple(first)
        self.parameters = tuple(self._ordered(
            [s for s in first if s.name not in self.values], order, used_names))
        self._subs = {self._by_name[k]: v for k, v in self.values.items()}

    def _init_examples(self, examples) -> None:
        """``examples``: name -> a typical value of a free parameter (a time step, say), used
        where derive needs numbers and the model gives none (derive verify's simulation);
        the parameter stays free in generated code."""
        self.examples: dict[str, float] = {}
        if examples is None:
            return
        if not isinstance(examples, Mapping):
            raise SymbolError(f"examples must map free parameter names to numbers, got "
                              f"{type(examples).__name__} {examples!r}")
        free = [p.name for p in self.parameters]
        for nm, value in examples.items():
            if nm not in free:
                raise SymbolError(f"example given for {nm!r}, which is not a free parameter "
                                  f"of model {self.name!r} (free: {free})")
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = float("nan")
            if isinstance(value, (bool, str)) or not np.isfinite(number):
                raise SymbolError(f"example of {nm!r} must be a finite number, got {value!r}")
            check_value(self._by_name[nm], number, f"model {self.name!r} examples")
            self.examples[nm] = number

    def _ordered(self, free: list[sympy.Symbol], order, used_names: set[str]):
        """``free`` with the names listed in ``order`` first, in that order."""
        if order is None:
            return free
        if isinstance(order, str) or not isinstance(order, Sequence):
            raise SymbolError("parameters must be a list of names (the order of p), got "
                              f"{type(order).__name__} {order!r}")
        listed: list[str] = []
        for item in order:
            nm = item.name if isinstance(item, sympy.Symbol) else item
            check_identifier(nm, "parameter name")
            if nm not in used_names:
                raise SymbolError(f"parameters lists {nm!r}, which appears in no matrix of "
                                  f"model {self.name!r}")
            if isinstance(item, sympy.Symbol) and item != self._by_name[nm]:
                raise SymbolError(f"parameters lists a different symbol named {nm!r} than the "
                                  "model's matrices use")
            if nm in listed:
                raise SymbolError(f"parameters lists {nm!r} twice")
            listed.append(nm)
        by_name = {s.name: s for s in free}
        head = [by_name[nm] for nm in listed if nm in by_name]
        return head + [s for s in free if s.name not in listed]

    def _check_finite(self, matrices: Mapping[str, sympy.MatrixBase], extra=None) -> None:
        """Every entry whose symbols have values is a finite double there."""
        check_entries(matrices, {**self._subs, **(extra or {})})

    @property
    def n(self) -> int:
        return len(self.states)

    #: The tangent coordinates' names (a model without manifold states: its states).
    @property
    def tangent(self) -> tuple[str, ...]:
        layout = getattr(self, "layout", None)
        return self.states if layout is None else layout.tangent

    @property
    def n_tangent(self) -> int:
        """The covariance's dimension: n, or fewer with quaternion states."""
        return len(self.tangent)

    @property
    def m(self) -> int:
        return len(self.measurements)

    def symbol(self, name: str) -> sympy.Symbol:
        """The model's symbol named ``name`` (the user's own, assumptions included)."""
        return self._by_name.get(name) or symbol(name)

    def subs(self, expr):
        """``expr`` with every valued symbol replaced by its exact value."""
        return expr.xreplace(self._subs) if self._subs else expr

    def at_values(self, params) -> _Model:
        """This model with free parameters given values (name -> number): a copy in which
        they are constants, as if ``values`` had held them (derive verify runs a model at
        its parameters' examples so). The other free parameters stay free, in order."""
        extra = self.parameter_values(params, partial=True)
        valued = copy.copy(self)
        valued.values = dict(sorted({**self.values,
                                     **{s.name: v for s, v in extra.items()}}.items()))
        valued.parameters = tuple(s for s in self.parameters if s not in extra)
        valued.examples = {k: v for k, v in self.examples.items()
                           if k not in {s.name for s in extra}}
        valued._subs = {**self._subs, **extra}
        return valued

    def parameter_values(self, params=None, partial: bool = False
                         ) -> dict[sympy.Symbol, sympy.Expr]:
        """Values for the free parameters from ``params`` (name -> number); all required
        unless ``partial``."""
        table = SymbolTable.known(self._by_name.values(), f"model {self.name!r}")
        given = normalize_values(params, table, "params")
        for nm in given:
            if nm not in {p.name for p in self.parameters}:
                raise SymbolError(f"{nm!r} is not a free parameter of model {self.name!r} "
                                  f"(free: {[p.name for p in self.parameters]})")
        missing = [p.name for p in self.parameters if p.name not in given]
        if missing and not partial:
            raise SymbolError(f"model {self.name!r} needs values for free parameters {missing}")
        for k, v in given.items():  # a declared domain refuses a value as generated code does
            check_value(self._by_name[k], v, f"model {self.name!r}")
        return {self._by_name[k]: v for k, v in given.items()}

    def _initial(self, x0, P0, P0_pattern) -> None:
        n, nt = self.n, self.n_tangent
        table = SymbolTable()
        self.x0 = (sympy.ImmutableMatrix.zeros(n, 1) if x0 is None
                   else as_matrix(x0, "x0", table, vector=True))
        check_shape(self.x0, "x0", (n, 1), "one entry per state")
        self.P0 = (sympy.ImmutableMatrix.zeros(nt, nt) if P0 is None
                   else as_matrix(P0, "P0", table))
        check_shape(self.P0, "P0", (nt, nt), "states x states" if nt == n else
                    "tangent x tangent coordinates " + ", ".join(self.tangent))
        for mat, nm in ((self.x0, "x0"), (self.P0, "P0")):
            if mat.free_symbols:
                raise SymbolError(f"{nm} must be numeric, has symbols "
                                  f"{sorted(s.name for s in mat.free_symbols)}")
        check_entries({"x0": self.x0, "P0": self.P0}, {})
        self.P0 = _symmetric(self.P0, "P0")
        _check_definite(self.P0, "P0", strict=False)   # a covariance: no filter runs from -I
        if P0_pattern is None:
            P0_pattern = "dense"
        if P0_pattern not in P0_PATTERNS:
            raise SymbolError(f"P0_pattern {P0_pattern!r} is not one of {P0_PATTERNS}")
        self.P0_pattern = P0_pattern
        self._check_P0_pattern()

    def _check_P0_pattern(self) -> None:
        """Refuse a P0 with a nonzero entry outside its declared pattern."""
        if self.P0_pattern == "dense" or not any(self.P0):
            return
        nt = self.n_tangent
        if self.P0_pattern != "block" or any(
                self.P0[i, j] != 0 for i in range(nt) for j in range(nt) if i != j):
            mask = self.pattern_mask()
            for i in range(nt):
                for j in range(nt):
                    if self.P0[i, j] != 0 and not mask[i][j]:
                        raise MatrixPropertyError(
                            f"P0[{i}][{j}] = {decimal(self.P0[i, j])} is outside the declared "
                            f"P0_pattern {self.P0_pattern!r}")

    def pattern_mask(self, name: str | None = None) -> tuple[tuple[bool, ...], ...]:
        """The entries a P0 pattern (``name``, default the model's) allows, as booleans."""
        n = self.n_tangent
        name = name or self.P0_pattern
        if name == "dense":
            return tuple(tuple(True for _ in range(n)) for _ in range(n))
        if name == "zero":
            return tuple(tuple(False for _ in range(n)) for _ in range(n))
        if name == "diagonal":
            return tuple(tuple(i == j for j in range(n)) for i in range(n))
        if name == "block":
            owner = {}
            for b, blk in enumerate(self.blocks()):
                for s in blk.states:
                    owner[s] = b
            return tuple(tuple(owner[i] == owner[j] for j in range(n)) for i in range(n))
        raise ModelError(f"P0 pattern {name!r} is not one of {', '.join(P0_PATTERNS)}")

    def blocks(self):
        """Independent blocks (see :func:`derive.structure.find_blocks`); one for a
        nonlinear model."""
        return [_WholeModel(tuple(range(self.n)), self)]

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.name!r}, n={self.n}, m={self.m}, "
                f"parameters={[p.name for p in self.parameters]})")


@dataclass(frozen=True)
class _WholeModel:
    """The one block of a model that is not split (its ``states`` are all of them)."""

    states: tuple[int, ...]
    model: object


def _symmetric(mat: sympy.MatrixBase, name: str) -> sympy.ImmutableMatrix:
    """``mat`` symmetrised if it is symmetric to SYMMETRY_TOLERANCE; else refused, naming
    the first asymmetric pair (numbers as decimals)."""
    out = sympy.Matrix(mat)
    for i in range(mat.rows):
        for j in range(i + 1, mat.cols):
            a, b = mat[i, j], mat[j, i]
            if a == b:
                continue
            if a.is_Rational and b.is_Rational:
                scale = max(abs(a), abs(b))
                di, dj = mat[i, i], mat[j, j]
                if di.is_Rational and dj.is_Rational:
                    scale = max(scale, sympy.sqrt(abs(di * dj)))
                if abs(a - b) <= sympy.Rational(SYMMETRY_TOLERANCE) * scale:
                    out[i, j] = out[j, i] = (a + b) / 2
                    continue
            elif sympy.simplify(a - b) == 0:
                continue
            raise MatrixPropertyError(
                f"matrix {name} must be symmetric: {name}[{i}][{j}] = {decimal(a)} but "
                f"{name}[{j}][{i}] = {decimal(b)} (more than the relative tolerance "
                f"{SYMMETRY_TOLERANCE:g} apart)")
    return sympy.ImmutableMatrix(out)


DEFINITE_TOLERANCE = 1e-12
"""Eigenvalues of Q, Qu, R within this fraction of the matrix's largest |eigenvalue| of 0
count as 0 (rounding of a fitted covariance): refused for a definite R, accepted for a
semidefinite Q."""


def _check_definite(mat: sympy.MatrixBase, name: str, strict: bool) -> None:
    """Check a numeric symmetric matrix is positive (semi)definite; skip if symbolic."""
    if mat.free_symbols:
        return
    a = np.array(mat.tolist(), dtype=float)
    eig = np.linalg.eigvalsh(a)
    # relative to the matrix's own scale (its largest |eigenvalue|): a model in small
    # units (R = 1e-160 I) is as definite as one in large units, and an indefinite Q of
    # small entries is as indefinite
    scale = float(np.max(np.abs(eig))) if eig.size else 0.0
    tol = DEFINITE_TOLERANCE * scale
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
    """A linear time-invariant discrete model (the linear model of MPT3D and SSPRED).

    ``x(k+1) = F x(k) + G w(k)``, ``z(k) = H x(k) + v(k)``, ``w ~ N(0, Q)``, ``v ~ N(0, R)``.

    With ``inputs`` (names of the per-step known inputs u, n_u of them) and the input
    matrices ``B`` (n x n_u) and ``D`` (m x n_u), each zero when not given:
    ``x(k+1) = F x(k) + B u(k) + G w(k)``, ``z(k+1) = H x(k+1) + D u(k) + v(k+1)``: the
    input row u(k) that drives the transition into step k+1 also offsets z(k+1), so one
    row of inputs goes with one row of measurements (a known state offset is an input
    with a B column; an observation offset an input with a D column).
    """

    kind = "linear"

    def __init__(self, name: str, states: Sequence[str],
                 measurements: Sequence[str] | None = None, F: Matrix | None = None,
                 H: Matrix | None = None, Q: Matrix | None = None, R: Matrix | None = None,
                 G: Matrix | Vector | None = None,
                 values: Values | None = None, x0: Vector | None = None,
                 P0: Matrix | None = None, P0_pattern: str | None = None,
                 description: str = "", source: str = "",
                 parameters: Names | None = None, B: Matrix | None = None,
                 D: Matrix | None = None, inputs: Sequence[str] | None = None,
                 sensors: Sequence[Sensor] | None = None,
                 examples: Values | None = None) -> None:
        sensor_list = (_sensor_list(sensors, "linear", {"measurements": measurements, "H": H,
                                                        "R": R, "D": D})
                       if sensors is not None else ())
        if sensor_list:
            measurements = [z for sensor in sensor_list for z in sensor.measurements]
        for key, value in (("F", F), ("H", H), ("Q", Q), ("R", R)):
            if value is None and not (sensor_list and key in ("H", "R")):
                raise ModelError(f"LinearModel {name!r}: missing {key}")
        self._init_names(name, states, measurements, description, source)
        n, m = self.n, self.m
        table = SymbolTable()
        self.F = as_matrix(F, "F", table)
        check_shape(self.F, "F", (n, n), "states x states")
        self.G = (sympy.ImmutableMatrix.eye(n) if G is None
                  else as_matrix(G, "G", table, vector=True))
        if self.G.rows != n:
            raise ShapeError(f"matrix G must have {n} rows (one per state), got "
                             f"{self.G.rows}x{self.G.cols}")
        if sensor_list:
            H, R, D = self._stack_sensors(sensor_list, inputs, table)
        self.H = as_matrix(H, "H", table)
        check_shape(self.H, "H", (m, n), "measurements x states")
        q = self.G.cols
        self.Q = as_matrix(Q, "Q", table)
        check_shape(self.Q, "Q", (q, q), "noise inputs x noise inputs, one per column of G")
        self.R = as_matrix(R, "R", table)
        check_shape(self.R, "R", (m, m), "measurements x measurements")
        self._init_inputs(inputs, B, D, table)
        self.F, self.G, self.H, self.Q, self.R, self.B, self.D = (
            table.finish(mat) for mat in (self.F, self.G, self.H, self.Q, self.R, self.B,
                                          self.D))
        used = set()
        for mat in (self.F, self.G, self.H, self.Q, self.R, self.B, self.D):
            used |= mat.free_symbols
        input_names = {u.name for u in self.inputs}
        for s in used:
            if s.name in input_names:
                raise SymbolError(f"symbol {s.name!r} is a per-step input; inputs enter only "
                                  "through B u and D u, not inside a matrix")
        self._init_values(values, table, used, set(self.states) | input_names, parameters)
        self._init_examples(examples)
        for s in used:
            if s.name in self.states:
                raise SymbolError(f"symbol {s.name!r} is a state name; a linear model's "
                                  "matrices cannot depend on the state")
        self._check_finite({"F": self.F, "G": self.G, "H": self.H, "Q": self.Q, "R": self.R,
                            "B": self.B, "D": self.D})
        self.Q = _symmetric(self.Q, "Q")
        self.R = _symmetric(self.R, "R")
        _check_definite(self.subs(self.Q), "Q", strict=False)
        self._initial(x0, P0, P0_pattern)
        self.sensors = self._sensor_groups(sensor_list)
        if not sensor_list:  # else each sensor's R is checked under its name
            _check_definite(self.subs(self.R), "R", strict=True)

    def _stack_sensors(self, sensor_list, inputs, table: SymbolTable):
        """The sensors' H (stacked), R (block diagonal) and D (stacked, over the model's
        inputs; None when no sensor gives one), each checked under the sensor's name."""
        n = self.n
        names = check_names(inputs, "inputs") if inputs else ()
        Hs, Rs, Ds = [], [], []
        self._sensor_input_names = {}
        for sensor in sensor_list:
            label = f"sensor {sensor.name!r}"
            m_s = len(sensor.measurements)
            H_s = as_matrix(sensor.H, f"H of {label}", table)
            check_shape(H_s, f"H of {label}", (m_s, n), "its measurements x states")
            Rs.append(_sensor_R(sensor, table))
            Hs.append(H_s)
            own = _sensor_inputs(sensor, names, names if sensor.D is not None else ())
            self._sensor_input_names[sensor.name] = own
            D_full = sympy.zeros(m_s, len(names))
            if sensor.D is not None:
                if not own:
                    raise ShapeError(f"D of {label} is given but the sensor has no inputs")
                D_s = as_matrix(sensor.D, f"D of {label}", table, vector=True)
                check_shape(D_s, f"D of {label}", (m_s, len(own)),
                            "its measurements x its inputs")
                for j, u in enumerate(own):
                    D_full[:, names.index(u)] = D_s[:, j]
            Ds.append(D_full)
        D = (sympy.ImmutableMatrix(sympy.Matrix.vstack(*Ds))
             if any(s.D is not None for s in sensor_list) else None)
        return (sympy.ImmutableMatrix(sympy.Matrix.vstack(*Hs)),
                sympy.ImmutableMatrix(sympy.diag(*Rs)), D)

    def _sensor_groups(self, sensor_list) -> tuple[SensorGroup, ...]:
        """The resolved sensors: row blocks of the stacked H, R and D."""
        groups, row = [], 0
        for sensor in sensor_list:
            label = f"R of sensor {sensor.name!r}"
            m_s = len(sensor.measurements)
            rows = slice(row, row + m_s)
            own = self._sensor_input_names[sensor.name]
            columns = [i for i, u in enumerate(self.inputs) if u.name in own]
            R_s = self.R[rows, rows]
            if not _R_given_per_call(sensor):
                _check_definite(self.subs(R_s), label, strict=True)
            groups.append(SensorGroup(
                sensor.name, tuple(sensor.measurements), (row, row + m_s),
                tuple(self.inputs[i] for i in columns), sympy.ImmutableMatrix(R_s),
                H=sympy.ImmutableMatrix(self.H[rows, :]), R_argument=_R_given_per_call(sensor),
                update=_sensor_update(sensor, self.subs(R_s)),
                D=sympy.ImmutableMatrix(self.D.extract(list(range(row, row + m_s)), columns)
                                        if columns else sympy.zeros(m_s, 0))))
            row += m_s
        return tuple(groups)

    def _init_inputs(self, inputs, B, D, table: SymbolTable) -> None:
        """``self.inputs`` (symbols), ``B`` (n x n_u) and ``D`` (m x n_u), zero when not
        given; B or D without inputs, or of the wrong shape, is refused naming it."""
        names = check_names(inputs, "inputs") if inputs else ()
        clash = set(names) & (set(self.states) | set(self.measurements))
        if clash:
            raise SymbolError(f"input {sorted(clash)[0]!r} has the name of a state or "
                              "measurement")
        self.inputs = tuple(symbol(u) for u in names)
        n_u = len(names)
        for given, nm, rows, what in ((B, "B", self.n, "states"),
                                      (D, "D", self.m, "measurements")):
            if given is None:
                setattr(self, nm, sympy.ImmutableMatrix.zeros(rows, n_u))
                continue
            if not n_u:
                raise ShapeError(f"matrix {nm} is given but the model declares no inputs "
                                 "(inputs = [names of u])")
            mat = as_matrix(given, nm, table, vector=True)
            check_shape(mat, nm, (rows, n_u), f"{what} x inputs")
            setattr(self, nm, mat)

    @property
    def noise_dim(self) -> int:
        return self.G.cols

    @property
    def n_inputs(self) -> int:
        """n_u, the number of per-step inputs (0 without inputs)."""
        return len(self.inputs)

    def matrix(self, which: str) -> sympy.ImmutableMatrix:
        """``F, G, H, Q, R, B, D`` or ``GQGt`` with the given values substituted (exact)."""
        if which == "GQGt":
            return sympy.ImmutableMatrix(
                (self.subs(self.G) * self.subs(self.Q) * self.subs(self.G).T)
                .applyfunc(sympy.expand))
        if which not in ("F", "G", "H", "Q", "R", "B", "D"):
            raise KeyError(which)
        return self.subs(getattr(self, which))

    def numeric(self, params: Values | None = None) -> NumericLinear:
        """The model at numbers; free parameters must be given in ``params``."""
        extra = self.parameter_values(params)
        names = ("F", "G", "H", "Q", "R", "B", "D")
        self._check_finite({k: getattr(self, k) for k in names}, extra)

        def arr(mat):
            return np.array(mat.xreplace(extra).evalf(17).tolist(),
                            dtype=float).reshape(mat.shape)

        m = {k: arr(self.matrix(k)) for k in names}
        return NumericLinear(x0=np.array(self.x0.tolist(), dtype=float).ravel(),
                             P0=np.array(self.P0.tolist(), dtype=float), **m)

    @classmethod
    def from_continuous(cls, name: str, states: Sequence[str], measurements: Sequence[str],
                        Phi: Matrix, Qc: Matrix, H: Matrix, R: Matrix, dt: Entry,
                        G: Matrix | Vector | None = None, values: Values | None = None,
                        x0: Vector | None = None, P0: Matrix | None = None,
                        P0_pattern: str | None = None, description: str = "",
                        source: str = "", parameters: Names | None = None,
                        examples: Values | None = None) -> LinearModel:
        """Discretise ``dx/dt = Phi x + G w`` (spectral density Qc) exactly over ``dt``.

        Free parameters not listed in ``parameters`` follow in order of first appearance
        in Phi, G, Qc, H, R, dt."""
        state_names = check_names(states, "states")
        n = len(state_names)
        table = SymbolTable()
        Phi_m = as_matrix(Phi, "Phi", table)
        check_shape(Phi_m, "Phi", (n, n), "states x states")
        G_m = (sympy.ImmutableMatrix.eye(n) if G is None
               else as_matrix(G, "G", table, vector=True))
        if G_m.rows != n:
            raise ShapeError(f"matrix G must have {n} rows (one per state), got "
                             f"{G_m.rows}x{G_m.cols}")
        Qc_m = as_matrix(Qc, "Qc", table)
        check_shape(Qc_m, "Qc", (G_m.cols, G_m.cols), "noise inputs x noise inputs")
        H_m = as_matrix(H, "H", table)
        R_m = as_matrix(R, "R", table)
        dt_e = normalize(dt, "dt", table)
        Phi_m, G_m, Qc_m, H_m, R_m = (table.finish(mat) for mat in (Phi_m, G_m, Qc_m, H_m, R_m))
        dt_e = table.finish(sympy.ImmutableMatrix([[dt_e]]))[0, 0]
        for s in table.by_name.values():
            if s.name in state_names:
                raise SymbolError(f"symbol {s.name!r} is a state name; a linear model's "
                                  "matrices cannot depend on the state")
        Qc_m = _symmetric(Qc_m, "Qc")
        real, back = real_stand_ins(table.by_name.values())
        given = normalize_values(values, table)
        F, Qd, method = discretize(*(mat.xreplace(real) for mat in (Phi_m, G_m, Qc_m)),
                                   dt_e.xreplace(real), given)
        F, Qd = F.xreplace(back), Qd.xreplace(back)
        present = F.free_symbols | Qd.free_symbols | H_m.free_symbols | R_m.free_symbols
        if method == "numeric-expm":  # symbols of Phi and dt are now numbers in F and Qd
            kept = {s.name for s in present}
            values = {k: v for k, v in given.items() if k in kept}
        first = [s.name for s in table.by_name.values() if s in present]
        if parameters is not None and (isinstance(parameters, str)
                                       or not isinstance(parameters, Sequence)):
            raise SymbolError("parameters must be a list of names (the order of p), got "
                              f"{type(parameters).__name__} {parameters!r}")
        listed = [p.name if isinstance(p, sympy.Symbol) else p for p in parameters or ()]
        for nm in listed:
            if nm not in table.by_name:
                raise SymbolError(f"parameters lists {nm!r}, which appears in no matrix of "
                                  f"model {name!r}")
        present_names = {s.name for s in present}
        order = [nm for nm in dict.fromkeys(listed + first) if nm in present_names]
        model = cls(name, states, measurements, F, H_m, Qd, R_m, G=None, values=values, x0=x0,
                    P0=P0, P0_pattern=P0_pattern, description=description, source=source,
                    parameters=order, examples=examples)
        model.continuous = {"Phi": Phi_m, "G": G_m, "Qc": Qc_m, "dt": dt_e,
                            "method": method}
        return model

    @classmethod
    def compose(cls, name: str, models: Sequence[LinearModel],
                suffixes: Sequence[str] | None = None, description: str = "",
                source: str = "") -> LinearModel:
        """Block-diagonal composition (model A = three model-B axes); models with
        per-step inputs are refused (their B, D and inputs are not composed)."""
        for mdl in models:
            if getattr(mdl, "inputs", ()):
                raise ModelError(f"compose: model {mdl.name!r} has per-step inputs; "
                                 "composing models with inputs is not supported")
        return structure.compose(cls, name, models, suffixes, description=description,
                                 source=source)

    def blocks(self):
        """Independent blocks of the model (see :func:`derive.structure.find_blocks`)."""
        return structure.find_blocks(self)


class NonlinearModel(_Model):
    """``x(k) = f(x(k-1), u(k)) + w(k)``, ``z(k) = h(x(k), u(k)) + v(k)`` (the GNSS paper).

    ``inputs`` are per-step input symbols (satellite coordinates in h, a measured speed or
    turn rate in f): they change every step and are passed to the generated filter beside
    z; the row u(k) given with z(k) drives the prediction into step k and that step's
    measurement (as the linear KF: row k of us goes with row k of zs). ``Qu`` (n_u x n_u,
    over ``inputs`` in order) is the covariance of the noise on u: the prediction adds
    ``Fu Qu Fu^T`` to Q with ``Fu = ∂f/∂u`` at x(k-1/k-1), u(k) (the IMU convention);
    inputs f does not use have zero columns in Fu.

    f, h, Q and R may hold guards (``sign``, ``Max``, ``Min``, ``Piecewise``): they are
    rewritten as selects (derive.guards), refused naming the entry when they cannot be.
    Q and R may depend on the states and inputs (the filters say where they evaluate
    them). ``angles``: the measurements that are angles (their innovations are wrapped to
    (-pi, pi]); each one's h must be an angle (:func:`is_angle`).
    """

    kind = "nonlinear"

    def __init__(self, name: str, states: Sequence[str],
                 measurements: Sequence[str] | None = None, f: Vector | None = None,
                 h: Vector | None = None, Q: Matrix | None = None, R: Matrix | None = None,
                 values: Values | None = None,
                 inputs: Sequence[str] | None = None, x0: Vector | None = None,
                 P0: Matrix | None = None, P0_pattern: str | None = None,
                 description: str = "", source: str = "",
                 parameters: Names | None = None, Qu: Matrix | None = None,
                 sensors: Sequence[Sensor] | None = None,
                 unit_norm: Sequence[Sequence[str]] | None = None,
                 examples: Values | None = None, rows: str = "scalar",
                 manifolds: Sequence[Mapping] | None = None,
                 angles: Sequence[str] | None = None) -> None:
        sensor_list = (_sensor_list(sensors, "nonlinear", {"measurements": measurements,
                                                           "h": h, "R": R})
                       if sensors is not None else ())
        if sensor_list:
            measurements = [z for sensor in sensor_list for z in sensor.measurements]
        for key, value in (("f", f), ("h", h), ("Q", Q), ("R", R)):
            if value is None and not (sensor_list and key in ("h", "R")):
                raise ModelError(f"NonlinearModel {name!r}: missing {key}")
        self._init_names(name, states, measurements, description, source)
        #: the manifold components (derive.manifolds) and where their tangent coordinates
        #: are; P, Q and P0 are n_tangent x n_tangent
        self.manifolds = parse_manifolds(manifolds, self.states)
        self.layout = TangentLayout.of(self.states, self.manifolds) if self.manifolds else None
        n, m, nt = self.n, self.m, self.n_tangent
        input_names = check_names(inputs, "inputs") if inputs else ()
        reserved = set(self.states) | set(input_names)
        if len(reserved) != n + len(input_names):
            raise SymbolError("an input has the same name as a state: "
                              f"{sorted(set(self.states) & set(input_names))}")
        table = SymbolTable()
        self.f = as_matrix(f, "f", table, vector=True)
        check_shape(self.f, "f", (n, 1), "one expression per state")
        if sensor_list:
            h, R = self._stack_sensors(sensor_list, table)
        self.h = as_matrix(h, "h", table, vector=True)
        check_shape(self.h, "h", (m, 1), "one expression per measurement")
        self.Q = as_matrix(Q, "Q", table)
        check_shape(self.Q, "Q", (nt, nt), "states x states" if nt == n else
                    "tangent x tangent coordinates " + ", ".join(self.tangent))
        self.R = as_matrix(R, "R", table)
        check_shape(self.R, "R", (m, m), "measurements x measurements")
        n_u = len(input_names)
        if Qu is None:
            self.Qu = sympy.ImmutableMatrix.zeros(n_u, n_u)
        elif not n_u:
            raise ShapeError("matrix Qu is given but the model declares no inputs "
                             "(inputs = [names of u])")
        else:
            self.Qu = as_matrix(Qu, "Qu", table)
            check_shape(self.Qu, "Qu", (n_u, n_u), "inputs x inputs")
        self.f, self.h, self.Q, self.R, self.Qu = (
            table.finish(mat) for mat in (self.f, self.h, self.Q, self.R, self.Qu))
        self.f = _guarded(self.f, "f", self.states)
        self.h = _guarded(self.h, "h", self.measurements)
        self.Q, self.R = _guarded(self.Q, "Q"), _guarded(self.R, "R")
        # the state and input symbols are the ones written in f and h
        self.state_symbols = tuple(table.by_name.get(s) or symbol(s) for s in self.states)
        self.inputs = tuple(table.by_name.get(u) or symbol(u) for u in input_names)
        used = set()
        for mat in (self.f, self.h, self.Q, self.R, self.Qu):
            used |= mat.free_symbols
        # Q and R may depend on the state and the inputs (evaluated where the filters say:
        # derive.filters.ekf, ukf); the noise Qu on the inputs may not
        bad = {s.name for s in self.Qu.free_symbols} & reserved
        if bad:
            raise SymbolError(f"matrix Qu depends on state or input {sorted(bad)[0]!r}")
        #: the inputs f (or Q) uses, in ``inputs`` order (predict's u)
        self.f_inputs = tuple(u for u in self.inputs
                              if u in self.f.free_symbols | self.Q.free_symbols)
        params = {s for s in used if s.name not in reserved}
        self._init_values(values, table, params, reserved, parameters)
        self._init_examples(examples)
        self._check_finite({"f": self.f, "h": self.h, "Q": self.Q, "R": self.R, "Qu": self.Qu})
        self.Q = _symmetric(self.Q, "Q")
        self.R = _symmetric(self.R, "R")
        self.Qu = _symmetric(self.Qu, "Qu")
        _check_definite(self.subs(self.Q), "Q", strict=False)
        if not sensor_list:  # else each sensor's R is checked under its name
            _check_definite(self.subs(self.R), "R", strict=True)
        if input_names:
            _check_definite(self.subs(self.Qu), "Qu", strict=False)
        self._initial(x0, P0, P0_pattern)
        if sensor_list and self.state_noise:
            raise ModelError(f"NonlinearModel {name!r}: with sensors, Q and R may not "
                             "depend on the state or the inputs (only a model without "
                             "sensors evaluates them at the estimate)")
        self.sensors = self._sensor_groups(sensor_list)
        self.unit_norm = _unit_norm_groups(unit_norm, self.states)
        self._check_manifold_states()
        if rows not in ROW_FORMS:
            raise ModelError(f"NonlinearModel {name!r}: rows must be one of "
                             f"{', '.join(ROW_FORMS)}, got {rows!r}")
        self.rows = rows
        #: the measurements declared angles: their innovations are wrapped to (-pi, pi]
        self.angles = _angle_measurements(angles, self.measurements, self.h,
                                          self.state_symbols)

    @property
    def state_noise(self) -> bool:
        """Whether Q or R depends on the state or the inputs (evaluated at the filter's
        estimate: derive.filters.ekf, ukf)."""
        moving = set(self.state_symbols) | set(self.inputs)
        return bool((self.Q.free_symbols | self.R.free_symbols) & moving)

    def angle_rows(self, names: Sequence[str] | None = None) -> tuple[bool, ...]:
        """For each measurement of ``names`` (default: all), whether it is an angle."""
        return tuple(z in self.angles for z in (self.measurements if names is None
                                                 else names))

    def _check_manifold_states(self) -> None:
        """A quaternion's states are in no unit-norm group (its injection keeps the norm)
        and start at unit norm in x0."""
        grouped = {s for group in self.unit_norm for s in group}
        for m in self.manifolds:
            both = [s for s in m.states if s in grouped]
            if both:
                raise SymbolError(f"state {both[0]!r} is in a manifold component ({m.kind}) "
                                  "and in unit_norm: a quaternion keeps its norm by its "
                                  "injection; leave it out of unit_norm")
            if m.kind != QUATERNION:
                continue
            q = [float(self.x0[self.states.index(s), 0]) for s in m.states]
            norm = float(np.sqrt(sum(v * v for v in q)))
            if abs(norm - 1.0) > 1e-12:
                raise MatrixPropertyError(f"x0 of quaternion ({', '.join(m.states)}) must have "
                                          f"unit norm, got {norm!r}")

    # The Jacobians are derived when first asked for (the EKF derives its own, simplified
    # and shared with f and h; these serve the references, the UKF and derive show).
    @functools.cached_property
    def F_jacobian(self) -> sympy.ImmutableMatrix:
        return jacobian(self.f, self.state_symbols)

    @functools.cached_property
    def H_jacobian(self) -> sympy.ImmutableMatrix:
        return jacobian(self.h, self.state_symbols)

    @functools.cached_property
    def Fu_jacobian(self) -> sympy.ImmutableMatrix:
        return (jacobian(self.f, self.inputs) if self.inputs
                else sympy.ImmutableMatrix.zeros(self.n, 0))

    def _stack_sensors(self, sensor_list, table: SymbolTable):
        """The sensors' h (stacked) and R (block diagonal), each checked under the
        sensor's name."""
        hs, Rs = [], []
        for sensor in sensor_list:
            label = f"sensor {sensor.name!r}"
            m_s = len(sensor.measurements)
            h_s = as_matrix(sensor.h, f"h of {label}", table, vector=True)
            check_shape(h_s, f"h of {label}", (m_s, 1), "one expression per measurement")
            hs.append(h_s)
            Rs.append(_sensor_R(sensor, table))
        return (sympy.ImmutableMatrix(sympy.Matrix.vstack(*hs)),
                sympy.ImmutableMatrix(sympy.diag(*Rs)))

    def _sensor_groups(self, sensor_list) -> tuple[SensorGroup, ...]:
        """The resolved sensors: row blocks of the stacked h and R; a sensor's h may use
        the states, parameters and its own inputs only."""
        groups, row = [], 0
        input_names = [u.name for u in self.inputs]
        for sensor in sensor_list:
            m_s = len(sensor.measurements)
            rows = slice(row, row + m_s)
            h_s = sympy.ImmutableMatrix(self.h[rows, :])
            used = [u.name for u in self.inputs if u in h_s.free_symbols]
            own = _sensor_inputs(sensor, input_names, used)
            stray = [u for u in used if u not in own]
            if stray:
                raise SymbolError(f"h of sensor {sensor.name!r} uses input {stray[0]!r}, which "
                                  f"is not one of the sensor's inputs {list(own)}")
            R_s = sympy.ImmutableMatrix(self.R[rows, rows])
            if not _R_given_per_call(sensor):
                _check_definite(self.subs(R_s), f"R of sensor {sensor.name!r}", strict=True)
            groups.append(SensorGroup(
                sensor.name, tuple(sensor.measurements), (row, row + m_s),
                tuple(u for u in self.inputs if u.name in own), R_s, h=h_s,
                R_argument=_R_given_per_call(sensor),
                update=_sensor_update(sensor, self.subs(R_s))))
            row += m_s
        return tuple(groups)

    def numeric_functions(self, params: Values | None = None
                          ) -> dict[str, Callable | np.ndarray]:
        """NumPy callables ``f``, ``F``, ``h(x, u)``, ``H(x, u)`` and arrays Q, R, Qu.

        ``f``, ``F`` (∂f/∂x) and ``Fu`` (∂f/∂u, n x n_u) take ``(x, u)`` when f uses
        inputs (``f_inputs``), else ``(x)``. Vectors come back flat (shape (n,) or (m,)),
        Jacobians as 2-D arrays. A Q or R that depends on the state or the inputs
        (:attr:`state_noise`) is a callable ``(x, u)`` too.
        """
        extra = self.parameter_values(params)
        moving = set(self.state_symbols) | set(self.inputs)
        constant = {name: mat for name, mat in (("Q", self.Q), ("R", self.R), ("Qu", self.Qu))
                    if not mat.free_symbols & moving}
        self._check_finite(constant, extra)
        X = sympy.Matrix(self.state_symbols)
        U = sympy.Matrix(self.inputs) if self.inputs else sympy.Matrix.zeros(0, 1)

        def fn(mat, with_u, matrix=False):
            e = self.subs(mat).xreplace(extra)
            args = [list(X), list(U)] if with_u else [list(X)]
            lam = sympy.lambdify(args, e, modules=[numpy_selects(), "numpy"], cse=True)
            shape = (mat.rows,) if mat.cols == 1 and not matrix else mat.shape

            def call(x, u=()):
                vals = [list(np.asarray(x, float).ravel())]
                if with_u:
                    vals.append(list(np.asarray(u, float).ravel()))
                return np.asarray(lam(*vals), dtype=float).reshape(shape)
            return call

        def num(mat):
            return np.array(self.subs(mat).xreplace(extra).evalf(17).tolist(), dtype=float)

        in_f = bool(self.f_inputs)
        return {"f": fn(self.f, in_f), "F": fn(self.F_jacobian, in_f),
                "Fu": fn(self.Fu_jacobian, in_f),
                "h": fn(self.h, True), "H": fn(self.H_jacobian, True),
                "Q": num(self.Q) if "Q" in constant else fn(self.Q, True, True),
                "R": num(self.R) if "R" in constant else fn(self.R, True, True),
                "Qu": num(self.Qu)}


def _guarded(mat: sympy.ImmutableMatrix, name: str, labels: Sequence[str] | None = None
             ) -> sympy.ImmutableMatrix:
    """``mat`` with its guards (sign, Max, Min, Piecewise) as selects (derive.guards); a
    guard that cannot be one is refused naming the entry (``h[bearing]``, ``R[0][1]``)."""
    def where(i: int, j: int) -> str:
        return f"{name}[{labels[i]}]" if labels is not None else f"{name}[{i}][{j}]"
    return sympy.ImmutableMatrix(mat.rows, mat.cols, lambda i, j: selects(mat[i, j],
                                                                          where(i, j)))


#: The functions whose value is an angle.
ANGLE_FUNCTIONS = (sympy.atan2, sympy.atan, sympy.asin, sympy.acos)


def is_angle(expr: sympy.Expr, states: Sequence[sympy.Symbol]) -> bool:
    """Whether ``expr`` is an angle: atan2, atan, asin or acos of anything, a state (a
    heading), or a sum of angles and terms free of the state (an offset, a parameter)."""
    if expr.func in ANGLE_FUNCTIONS or expr in states:
        return True
    if expr.is_Add:
        moving = [t for t in expr.args if t.free_symbols & set(states)]
        return bool(moving) and all(
            is_angle(t, states) or (t.could_extract_minus_sign() and is_angle(-t, states))
            for t in moving)
    return False


def _angle_measurements(angles, measurements: Sequence[str], h: sympy.MatrixBase,
                        states: Sequence[sympy.Symbol]) -> tuple[str, ...]:
    """The measurements declared angles, each a measurement whose h is an angle
    (:func:`is_angle`); anything else is refused naming it."""
    if angles is None:
        return ()
    if isinstance(angles, str):
        raise ModelError(f"angles must be a list of measurement names, got the string "
                         f"{angles!r}")
    names = check_names(angles, "angles")
    for z in names:
        if z not in measurements:
            raise SymbolError(f"angles names {z!r}, which is not a measurement")
        row = h[list(measurements).index(z), 0]
        if not is_angle(row, states):
            raise ModelError(f"measurement {z!r} is declared an angle but h[{z}] = {row} is "
                             "not one (an angle is atan2, atan, asin or acos of anything, a "
                             "state, or a sum of angles and terms free of the state)")
    return tuple(names)


def _unit_norm_groups(groups, states: Sequence[str]) -> tuple[tuple[str, ...], ...]:
    """The unit-norm groups as tuples of state names: each of two or more distinct states,
    no state in two groups (a string or a flat list of names is refused)."""
    if groups is None:
        return ()
    if isinstance(groups, str) or not isinstance(groups, Sequence):
        raise ModelError("unit_norm must be a list of groups of state names, e.g. "
                         f"[['q0', 'q1', 'q2', 'q3']], got {type(groups).__name__} {groups!r}")
    out: list[tuple[str, ...]] = []
    seen: set[str] = set()
    for i, group in enumerate(groups):
        if isinstance(group, str) or not isinstance(group, Sequence):
            raise ModelError(f"unit_norm[{i}] must be a list of state names, got "
                             f"{type(group).__name__} {group!r}")
        names = check_names(group, f"unit_norm[{i}] states")
        if len(names) < 2:
            raise ModelError(f"unit_norm[{i}] must name at least two states, got {list(names)}")
        for nm in names:
            if nm not in states:
                raise SymbolError(f"unit_norm[{i}] names {nm!r}, which is not a state")
            if nm in seen:
                raise SymbolError(f"unit_norm: state {nm!r} is in two groups")
            seen.add(nm)
        out.append(tuple(names))
    return tuple(out)


Model = LinearModel | NonlinearModel
"""A model object."""
ModelRef = LinearModel | NonlinearModel | str | os.PathLike
"""A model object, a catalog name or the path of a model file."""
