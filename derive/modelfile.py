"""Model files: a model declared in TOML, turned into a LinearModel or NonlinearModel.

A model file has a ``[model]`` table, an optional ``[parameters]`` table, exactly one of
``[discrete]``, ``[continuous]``, ``[nonlinear]`` or ``[compose]``, and an optional
``[initial]`` table::

    [model]
    name = "mpt3d_b"          # identifier; used in generated function names
    description = "..."       # optional
    source = "..."            # optional: where the model comes from
    states = ["s", "v"]       # identifiers (optional for [compose]: then checked)
    measurements = ["z"]

    [parameters]              # every symbol used in an expression is declared here
    dt = 1.0                  # a value: a constant of the model
    sq2 = { value = 0.01, description = "process noise variance" }
    k = { description = "no value: a free runtime parameter p[..]" }  # p in table order

    [discrete]                # x(k+1) = F x(k) + G w(k), z(k) = H x(k) + v(k)
    F = [[1, "dt"], [0, 1]]   # rows; entries are numbers or expression strings
    G = [["dt/2"], [1]]       # optional (identity); a flat list is a column
    inputs = ["a"]            # optional per-step known inputs u(k) (not in any matrix):
    B = ["dt**2/2", "dt"]     # x(k+1) = F x(k) + B u(k) + G w(k), z(k+1) = H x(k+1)
    D = [[0]]                 # + D u(k) + v; B (n x n_u), D (m x n_u), each optional (zero)
    H = [[1, "dt"]]
    Q = "sq2"                 # a 1x1 matrix may be a scalar
    R = "sr2"

    [continuous]              # dx/dt = Phi x + G w, spectral density Qc; discretised
    Phi = [[0, 1], [0, 0]]    # exactly over dt (F = exp(Phi dt), Van Loan Qd)
    G = [0, 1]
    Qc = "sq2"
    H = [[1, 0]]
    R = "sr2"
    dt = "dt"                 # an expression (or a number)

    [nonlinear]               # x(k) = f(x(k-1), u(k)) + w, z(k) = h(x(k), u(k)) + v
    inputs = ["xs1"]          # optional per-step inputs u (not parameters, not states)
    f = ["x"]                 # n expressions in states, inputs and parameters
    h = ["sqrt((xs1 - x)**2) + b"]   # m expressions in states, inputs and parameters
    Q = [[0.01]]              # parameters only
    R = "sigma2"
    Qu = [[0]]                # optional (zero): noise on u, n_u x n_u; Q += Fu Qu Fu^T

    [compose]                 # block-diagonal composition of linear models
    blocks = [{ model = "mpt3d_b", suffix = "x" }, { model = "axis.toml", suffix = "y" }]

    [initial]                 # optional; numbers or expressions in valued parameters
    x0 = [0, 0]
    P0 = [[0, 0], [0, 0]]
    P0_pattern = "zero"       # "dense" | "zero" | "diagonal" | "block"

Numbers are exact: a TOML float is read from its text, so ``0.1`` is 1/10, like the
literal ``0.1`` in an expression (see `derive.expressions`). Expressions may use declared
parameters (plus states and inputs where stated above), ``pi``, ``+ - * / **`` and the
functions of `derive.expressions.FUNCTIONS`. A parameter that no expression uses is an
error (it is most likely a typo). A ``[compose]`` block's ``model`` is a catalog name or a
relative path to a model file inside the composing file's directory; composition needs no
``[parameters]`` or ``[initial]`` (the blocks carry theirs; same-named symbols are shared).
docs/model-files.md has complete examples.

Reading is bounded: regular files only, at most `MAX_FILE_BYTES` read; the TOML shape
(nesting, dotted keys, digits) is scanned before parsing (`derive.toml_limits`); states,
measurements and inputs are counted before any per-name work, also across [compose]
blocks (a file named by several blocks is built once); parameter values are checked
where they would make an expression unbounded (`derive.expressions.check_values`).
docs/model-files.md lists the limits.

Every problem raises a `derive.errors.ModelFileError` naming the file, the table and the
key (an expression problem raises its subclass `ExpressionError`); problems found by the
model classes keep their own `ModelError` subclass, with the file named in the message.
"""

from __future__ import annotations

import difflib
import os
import re
import stat
import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path, PurePath
from typing import Any

import sympy

from derive import catalog_files
from derive.domains import DOMAINS, NONNEGATIVE, holds
from derive.errors import ModelError, ModelFileError
from derive.expressions import (
    RESERVED_NAMES,
    check_values,
    exact_decimal,
    exact_number,
    parse_expression,
)
from derive.forms import ROW_FORMS
from derive.model import (
    P0_PATTERNS,
    R_ARGUMENT,
    SENSOR_UPDATES,
    LinearModel,
    NonlinearModel,
    Sensor,
)
from derive.structure import largest_block_size
from derive.symbols import check_identifier
from derive.toml_limits import toml_shape_problem

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

MAX_FILE_BYTES = 1_000_000
"""Largest model file accepted (at most this much is read, whatever the file system says)."""
MAX_COMPOSE_DEPTH = 8
"""Deepest nesting of [compose] files."""
MAX_STATES = 256
"""Most states of a model, composed or not, when it splits into independent blocks of at
most MAX_BLOCK_SIZE states and measurements (derive.structure.find_blocks): filters that
derive such a model block by block do work linear in the blocks (120 constant-velocity
axes, 240 states, take seconds)."""
MAX_MEASUREMENTS = 256
"""Most measurements of a model (with the same condition)."""
MAX_BLOCK_SIZE = 32
"""Most states, and most measurements, of one independent block of a model, and of a
model derived whole (nonlinear, continuous, or a filter that does not work block by
block: derive.filters.blockwise.whole_size): the generated filters are unrolled, with
work growing as the cube of the part derived at once (32 states take tens of seconds)."""
MAX_INPUTS = 128
"""Most per-step inputs of a model."""
_MAX_NAMES = {"states": MAX_STATES, "measurements": MAX_MEASUREMENTS, "inputs": MAX_INPUTS,
              "angles": MAX_MEASUREMENTS}

KINDS = ("discrete", "continuous", "nonlinear", "compose")
_TABLE_KEYS: Mapping[str, tuple[str, ...]] = {
    "model": ("name", "description", "source", "states", "measurements"),
    "parameters": (),
    "discrete": ("F", "G", "H", "Q", "R", "inputs", "B", "D"),
    "continuous": ("Phi", "G", "Qc", "H", "R", "dt"),
    "nonlinear": ("f", "h", "Q", "R", "inputs", "Qu", "unit_norm", "rows", "manifolds",
                  "angles"),
    "compose": ("blocks",),
    "initial": ("x0", "P0", "P0_pattern"),
    "sensors": (),
}
_SENSOR_KEYS: Mapping[str, tuple[str, ...]] = {
    "discrete": ("measurements", "H", "D", "R", "inputs", "update"),
    "nonlinear": ("measurements", "h", "R", "inputs", "update"),
}
_SENSOR_REQUIRED: Mapping[str, tuple[str, ...]] = {
    "discrete": ("measurements", "H", "R"),
    "nonlinear": ("measurements", "h", "R"),
}
_REQUIRED: Mapping[str, tuple[str, ...]] = {
    "model": ("name",),
    "discrete": ("F", "H", "Q", "R"),  # H and R (h and R) come from [sensors.NAME] if any
    "continuous": ("Phi", "Qc", "H", "R", "dt"),
    "nonlinear": ("f", "h", "Q", "R"),
    "compose": ("blocks",),
}
_PARAMETER_KEYS = ("value", "description", "example", "domain")
_BLOCK_KEYS = ("model", "suffix")


def _continuous_time_step(doc: dict[str, Any]) -> str | None:
    """The name a ``[continuous]`` table's dt is, when it is one name alone (``dt =
    "dt"``): a free parameter named so is the time step, nonnegative unless declared."""
    table = doc.get("continuous")
    value = table.get("dt") if isinstance(table, dict) else None
    return value.strip() if isinstance(value, str) and value.strip().isidentifier() else None


class _Decimal:
    """A TOML float kept as its text, so that ``0.1`` stays exactly 1/10."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def load_model_file(path: str | Path) -> LinearModel | NonlinearModel:
    """Load the model declared in the TOML file at `path`."""
    file = Path(path)
    return _Loader(()).load_path(file, str(path), _key(file), str(path))


def loads_model(text: str, *, source: str = "<string>") -> LinearModel | NonlinearModel:
    """Load a model from TOML text; `source` names it in error messages. A [compose]
    block may then name catalog models only (relative paths need a file)."""
    return _Loader(()).load_text(text, source, None, source)


def _key(path: Path) -> str:
    try:
        return str(path.resolve())
    except (OSError, RuntimeError):
        return str(path.absolute())


def _kind_name(value: object) -> str:
    if isinstance(value, _Decimal):
        return "float"
    return {dict: "table", list: "array", str: "string"}.get(type(value), type(value).__name__)


def _suggest(word: str, choices: list[str] | tuple[str, ...]) -> str:
    """' (did you mean ...?)' for the closest choice, ignoring case, or ''."""
    by_lower = {choice.lower(): choice for choice in choices}
    close = difflib.get_close_matches(word.lower(), list(by_lower), n=1, cutoff=0.5)
    return f" (did you mean {by_lower[close[0]]!r}?)" if close else ""


@contextmanager
def _model_errors(source: str) -> Iterator[None]:
    """Name the file in errors raised by the model classes, keeping their class."""
    try:
        yield
    except ModelFileError:
        raise
    except ModelError as error:
        raise type(error)(f"{source}: {error}") from error


class _Loader:
    """Loads one file and, through [compose], the files it names (`chain` guards cycles)."""

    def __init__(self, chain: tuple[str, ...],
                 loaded: dict[str, LinearModel | NonlinearModel] | None = None) -> None:
        self.chain = chain
        self.loaded = {} if loaded is None else loaded  # key -> model, shared by the chain

    # -- reading --------------------------------------------------------------------------

    def load_path(self, path: Path, source: str, key: str,
                  reading: str) -> LinearModel | NonlinearModel:
        """Load the file at `path`, named `source` in its own errors and `reading` in an
        error reading it (a [compose] block names the composing file and the block)."""
        if key in self.loaded:
            return self.loaded[key]
        data = _read_regular_file(path, reading)
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as error:
            raise ModelFileError(f"{source}: not UTF-8 text ({error.reason} at byte "
                                 f"{error.start})") from None
        return self.load_text(text, source, path.parent, key)

    def load_text(
        self, text: str, source: str, base_dir: Path | None, key: str
    ) -> LinearModel | NonlinearModel:
        if key in self.loaded:
            return self.loaded[key]
        if key in self.chain:
            cycle = " -> ".join([*self.chain[self.chain.index(key):], key])
            raise ModelFileError(f"{source}: [compose] cycle: {cycle}")
        if len(self.chain) >= MAX_COMPOSE_DEPTH:
            raise ModelFileError(
                f"{source}: [compose] nested more than {MAX_COMPOSE_DEPTH} deep")
        if not isinstance(text, str):
            raise ModelFileError(f"{source}: model text must be a string")
        if len(text) > MAX_FILE_BYTES:
            raise ModelFileError(f"{source}: model text is longer than {MAX_FILE_BYTES}")
        if not text.strip():
            raise ModelFileError(f"{source}: model file is empty")
        problem = toml_shape_problem(text)
        if problem is not None:
            raise ModelFileError(f"{source}: not accepted as a model file: {problem}")
        try:
            document = tomllib.loads(text, parse_float=_Decimal)
        except tomllib.TOMLDecodeError as error:
            raise ModelFileError(f"{source}: not valid TOML: {_toml_error(error, text)}") \
                from None
        except (ValueError, RecursionError, MemoryError) as error:  # beyond the scan's bounds
            raise ModelFileError(f"{source}: not accepted as a model file: "
                                 f"{type(error).__name__}: {error}") from None
        model = _File(document, source, base_dir, _Loader((*self.chain, key), self.loaded)) \
            .build()
        self.loaded[key] = model
        return model


def _read_regular_file(path: Path, reading: str) -> bytes:
    """At most MAX_FILE_BYTES + 1 bytes of a regular file (a FIFO or a device such as
    /dev/zero is refused before it is read; the size is not trusted)."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        descriptor = os.open(path, flags)
    except OSError as error:
        raise ModelFileError(f"{reading}: cannot read model file: {error.strerror}") from None
    try:
        mode = os.fstat(descriptor).st_mode
        if not stat.S_ISREG(mode):
            kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
                    else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
                    else "not a regular file")
            raise ModelFileError(f"{reading}: cannot read model file: it is {kind}, and a "
                                 "model file must be a regular file")
        with os.fdopen(descriptor, "rb", closefd=False) as stream:
            data = stream.read(MAX_FILE_BYTES + 1)
    except OSError as error:
        raise ModelFileError(f"{reading}: cannot read model file: {error.strerror}") from None
    finally:
        os.close(descriptor)
    if len(data) > MAX_FILE_BYTES:
        raise ModelFileError(f"{reading}: model file is more than {MAX_FILE_BYTES} bytes "
                             "(the limit)")
    return data


_TOML_AT = re.compile(r"\(at line (\d+), column \d+\)")


def _toml_error(error: Exception, text: str) -> str:
    """The parser's message, naming the key of a duplicate assignment (tomllib only says
    it cannot overwrite a value)."""
    message = str(error)
    where = _TOML_AT.search(message)
    if not message.startswith("Cannot overwrite a value") or where is None:
        return message
    lines = text.splitlines()
    number = int(where.group(1))
    line = lines[number - 1] if 0 < number <= len(lines) else ""
    key = line.split("=", 1)[0].strip() if "=" in line else ""
    if not key:
        return message
    return f"the key {key!r} is set twice (the second time at line {number})"


class _File:
    """One parsed TOML document being turned into a model."""

    def __init__(
        self, document: dict[str, Any], source: str, base_dir: Path | None, loader: _Loader
    ) -> None:
        self.doc = document
        self.source = source
        self.base_dir = base_dir
        self.loader = loader
        self.symbols: dict[str, sympy.Symbol] = {}
        self.values: dict[str, sympy.Rational] = {}
        self.used_in_initial: set[str] = set()
        self.used: set[str] = set()
        self.sensor_used: set[str] = set()
        self.examples: dict[str, float] = {}

    # -- errors and plain values ----------------------------------------------------------

    def error(self, where: str, message: str) -> ModelFileError:
        return ModelFileError(f"{self.source}: {where}: {message}")

    def table(self, name: str, required: bool = False) -> dict[str, Any] | None:
        value = self.doc.get(name)
        if value is None:
            if required:
                raise self.error(f"[{name}]", "missing table")
            return None
        if not isinstance(value, dict):
            raise self.error(f"[{name}]", f"must be a table, got {_kind_name(value)}")
        required = _REQUIRED.get(name, ())
        if name in _SENSOR_KEYS and "sensors" in self.doc:  # the sensors give h/H and R
            required = tuple(k for k in required if k not in ("h", "H", "R"))
        self.check_keys(value, _TABLE_KEYS[name], f"[{name}]", required)
        return value

    def check_keys(
        self, table: dict[str, Any], allowed: tuple[str, ...], where: str,
        required: tuple[str, ...] = (),
    ) -> None:
        for key in table:
            if key not in allowed:
                listing = ", ".join(allowed)
                raise self.error(where, f"unknown key {key!r}{_suggest(key, allowed)}; "
                                        f"allowed: {listing}")
        for key in required:
            if key not in table:
                raise self.error(where, f"missing required key {key!r}")

    def string(self, table: dict[str, Any], key: str, where: str, default: str = "") -> str:
        value = table.get(key, default)
        if not isinstance(value, str):
            raise self.error(f"{where} {key}", f"must be a string, got {_kind_name(value)}")
        return value

    def identifier(self, value: object, where: str) -> str:
        try:
            name = check_identifier(value, "name")
        except ModelError as error:
            raise self.error(where, str(error)) from None
        if name in RESERVED_NAMES:
            raise self.error(where, f"{name!r} is the name of a function or constant of "
                                    "expressions")
        return name

    def names(self, table: dict[str, Any], key: str, where: str) -> list[str]:
        value = table.get(key)
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise self.error(f"{where} {key}", f"must be a list of strings, got "
                                               f"{_kind_name(value)} {value!r}")
        if not value:
            raise self.error(f"{where} {key}", "must not be empty")
        limit = _MAX_NAMES[key]
        if len(value) > limit:
            raise self.error(f"{where} {key}", f"{len(value)} names, more than the limit of "
                                               f"{limit}")
        names = [self.identifier(item, f"{where} {key}") for item in value]
        seen: set[str] = set()
        for name in names:
            if name in seen:
                raise self.error(f"{where} {key}", f"name {name!r} appears twice")
            seen.add(name)
        return names

    # -- entries and matrices -------------------------------------------------------------

    def entry(self, value: object, where: str, names: Mapping[str, sympy.Symbol]) -> sympy.Expr:
        if isinstance(value, str):
            expr = parse_expression(value, names, where=f"{self.source}: {where}")
            check_values(expr, {self.symbols[name]: number
                                for name, number in self.values.items()},
                         where=f"{self.source}: {where}")
            return expr
        if isinstance(value, _Decimal):
            return exact_decimal(value.text, where=f"{self.source}: {where}")
        if isinstance(value, int) and not isinstance(value, bool):
            return exact_number(value, where=f"{self.source}: {where}")
        raise self.error(where, f"must be a number or an expression string, got "
                                f"{_kind_name(value)} {value!r}")

    def matrix(
        self, value: object, where: str, names: Mapping[str, sympy.Symbol], *,
        column: bool = False,
    ) -> list[list[sympy.Expr]]:
        """Rows of entries; a scalar is 1x1; a flat list is a column if `column`."""
        if not isinstance(value, list):
            return [[self.entry(value, where, names)]]
        if not value:
            raise self.error(where, "must not be empty")
        if all(not isinstance(row, list) for row in value):
            if not column:
                raise self.error(where, "must be a list of rows, e.g. [[1, 0], [0, 1]]")
            return [[self.entry(item, f"{where}[{i}]", names)] for i, item in enumerate(value)]
        for i, row in enumerate(value):
            if not isinstance(row, list):
                raise self.error(f"{where}[{i}]", f"must be a row (a list), got "
                                                  f"{_kind_name(row)}")
            if not row:
                raise self.error(f"{where}[{i}]", "row is empty")
            if len(row) != len(value[0]):
                raise self.error(where, f"is not rectangular: row 0 has {len(value[0])} "
                                        f"entries, row {i} has {len(row)}")
        return [[self.entry(item, f"{where}[{i}][{j}]", names) for j, item in enumerate(row)]
                for i, row in enumerate(value)]

    def vector(
        self, value: object, where: str, names: Mapping[str, sympy.Symbol]
    ) -> list[sympy.Expr]:
        if not isinstance(value, list) or not value:
            raise self.error(where, f"must be a non-empty list, got {_kind_name(value)}")
        return [self.entry(item, f"{where}[{i}]", names) for i, item in enumerate(value)]

    # -- tables ---------------------------------------------------------------------------

    def build(self) -> LinearModel | NonlinearModel:
        for key in self.doc:
            if key not in _TABLE_KEYS:
                raise self.error("top level", f"unknown table {key!r}"
                                              f"{_suggest(key, tuple(_TABLE_KEYS))}; allowed: "
                                              f"{', '.join(_TABLE_KEYS)}")
        kinds = [kind for kind in KINDS if kind in self.doc]  # [sensors] is not a kind
        if len(kinds) != 1:
            found = ", ".join(f"[{kind}]" for kind in kinds) or "none"
            raise self.error("top level", "needs exactly one of [discrete], [continuous], "
                                          f"[nonlinear], [compose]; found {found}")
        kind = kinds[0]
        model = self.table("model", required=True)
        header = {
            "name": self.identifier(model["name"], "[model] name"),
            "description": self.string(model, "description", "[model]"),
            "source": self.string(model, "source", "[model]"),
        }
        if kind == "compose":
            return self.bounded(self.compose(model, header), "[compose] blocks")
        sensors = self.sensor_tables(kind)
        for key in ("states",) + (() if sensors else ("measurements",)):
            if key not in model:
                raise self.error("[model]", f"missing required key {key!r}")
        if sensors and "measurements" in model:
            raise self.error("[model] measurements", "not allowed with [sensors.NAME] tables: "
                                                     "each sensor lists its own measurements")
        states = self.names(model, "states", "[model]")
        measurements = (self.names(model, "measurements", "[model]") if not sensors else
                        [z for _, table in sensors for z in table["measurements"]])
        if kind in ("nonlinear", "continuous"):  # derived (discretised) whole
            for key, names in (("states", states), ("measurements", measurements)):
                if len(names) > MAX_BLOCK_SIZE:
                    raise self.error(f"[model] {key}", f"{len(names)} names, more than the "
                                                       f"limit of {MAX_BLOCK_SIZE} of a "
                                                       f"[{kind}] model")
        body = self.table(kind)
        if sensors:
            for key in ("h", "H", "R", "D"):
                if key in body:
                    raise self.error(f"[{kind}] {key}", "not allowed with [sensors.NAME] "
                                                        "tables: each sensor gives its own")
        inputs = self.names(body, "inputs", f"[{kind}]") if "inputs" in body else []
        self.read_parameters(states, measurements, inputs, f"[{kind}] inputs")
        if kind == "nonlinear":
            arguments = self.nonlinear(body, states, inputs, bool(sensors))
        else:
            arguments = self.linear(body, kind, bool(sensors))
        if sensors:
            arguments["sensors"] = [self.sensor(kind, name, table, states, inputs)
                                    for name, table in sensors]
        arguments.update(self.initial(kind))
        arguments["values"] = {name: value for name, value in self.values_used(arguments)}
        # p follows the [parameters] table (tomllib keeps its order)
        arguments["parameters"] = [name for name in self.symbols if name in self.used]
        if self.examples:
            arguments["examples"] = {k: v for k, v in self.examples.items()
                                     if k in arguments["parameters"]}
        return self.bounded(self.construct(kind, header, states,
                                           None if sensors else measurements, arguments),
                            "[model] states")

    def bounded(self, model: LinearModel | NonlinearModel,
                where: str) -> LinearModel | NonlinearModel:
        """``model`` when no part of it a filter must derive at once is larger than
        MAX_BLOCK_SIZE (its largest independent block), else the error naming the sizes."""
        largest = largest_block_size(model)
        if largest > MAX_BLOCK_SIZE:
            raise self.error(where, f"{model.n} states and {model.m} measurements whose "
                                    f"largest independent block has {largest} states or "
                                    f"measurements, more than the limit of {MAX_BLOCK_SIZE} "
                                    "(F, G Q G^T, H and R must split into blocks that small)")
        return model

    def read_parameters(self, states: list[str], measurements: list[str],
                        inputs: list[str], inputs_where: str) -> None:
        table = self.doc.get("parameters", {})
        if not isinstance(table, dict):
            raise self.error("[parameters]", f"must be a table, got {_kind_name(table)}")
        taken = dict.fromkeys(states, "a state")
        taken.update(dict.fromkeys(measurements, "a measurement"))
        for name in inputs:
            if name in taken:
                raise self.error(inputs_where, f"{name!r} is also {taken[name]}")
            taken[name] = "an input"
        time_step = _continuous_time_step(self.doc)
        for name, spec in table.items():
            where = f"[parameters] {name}"
            self.identifier(name, where)
            if name in taken:
                raise self.error(where, f"{name!r} is also {taken[name]}")
            domain = None
            if isinstance(spec, dict):
                self.check_keys(spec, _PARAMETER_KEYS, where)
                self.string(spec, "description", where)
                value = spec.get("value")
                domain = spec.get("domain")
                if domain is not None and (not isinstance(domain, str) or domain not in DOMAINS):
                    raise self.error(f"{where} domain", f"must be one of {', '.join(DOMAINS)}, "
                                                        f"got {_kind_name(domain)} {domain!r}")
                if "example" in spec:
                    example = spec["example"]
                    if value is not None:
                        raise self.error(f"{where} example", "only a free parameter (no value) "
                                                             "takes an example")
                    if isinstance(example, bool) or not isinstance(example, (int, _Decimal)):
                        raise self.error(f"{where} example", f"must be a number, got "
                                                             f"{_kind_name(example)} "
                                                             f"{example!r}")
                    self.examples[name] = float(str(example))
                    if domain is not None and not holds(self.examples[name], domain):
                        raise self.error(f"{where} example", f"must be {domain} (its domain), "
                                                             f"got {example!r}")
            else:
                value = spec
            if value is not None:
                if isinstance(value, str) or not isinstance(value, (int, _Decimal)) or \
                        isinstance(value, bool):
                    raise self.error(where, f"value must be a number, got {_kind_name(value)} "
                                            f"{value!r}")
                self.values[name] = self.entry(value, where, {})
                if domain is not None and not holds(float(self.values[name]), domain):
                    raise self.error(f"{where} value", f"must be {domain} (its domain), "
                                                       f"got {value!r}")
            elif domain is None and name == time_step:  # [continuous] dt = "NAME", free
                domain = NONNEGATIVE
            # the domain is the symbol's assumption, as a model built in Python declares it
            self.symbols[name] = sympy.Symbol(name, real=True, **({domain: True} if domain
                                                                   else {}))

    def sensor_tables(self, kind: str) -> list[tuple[str, dict[str, Any]]]:
        """The ``[sensors.NAME]`` tables in file order (empty without [sensors]), each
        with its keys checked and its measurements read."""
        value = self.doc.get("sensors")
        if value is None:
            return []
        if kind not in _SENSOR_KEYS:
            raise self.error("[sensors]", f"sensors are declared with [discrete] or "
                                          f"[nonlinear], not [{kind}]")
        if not isinstance(value, dict) or not value:
            raise self.error("[sensors]", "must hold one table per sensor, [sensors.NAME]")
        out = []
        for name, table in value.items():
            where = f"[sensors.{name}]"
            self.identifier(name, where)
            if not isinstance(table, dict):
                raise self.error(where, f"must be a table, got {_kind_name(table)}")
            self.check_keys(table, _SENSOR_KEYS[kind], where, _SENSOR_REQUIRED[kind])
            table = dict(table)
            table["measurements"] = self.names(table, "measurements", where)
            out.append((name, table))
        return out

    def sensor(self, kind: str, name: str, table: dict[str, Any], states: list[str],
               inputs: list[str]) -> Sensor:
        """One sensor's Sensor: its matrices read like the model's (h in states, inputs
        and parameters; H, D, R in parameters)."""
        where = f"[sensors.{name}]"
        own = None
        if "inputs" in table:
            value = table["inputs"]
            if not isinstance(value, list) or not all(isinstance(u, str) for u in value):
                raise self.error(f"{where} inputs", f"must be a list of strings, got "
                                                    f"{_kind_name(value)} {value!r}")
            for u in value:
                if u not in inputs:
                    raise self.error(f"{where} inputs", f"{u!r} is not one of the model's "
                                                        f"inputs {inputs}")
            own = list(value)
        matrices: dict[str, Any] = {"R": R_ARGUMENT if table["R"] == R_ARGUMENT else
                                    self.matrix(table["R"], f"{where} R", self.symbols)}
        if kind == "nonlinear":
            names = {**self.symbols, **{s: sympy.Symbol(s, real=True) for s in states},
                     **{u: sympy.Symbol(u, real=True) for u in inputs}}
            matrices["h"] = self.vector(table["h"], f"{where} h", names)
        else:
            matrices["H"] = self.matrix(table["H"], f"{where} H", self.symbols)
            if "D" in table:
                matrices["D"] = self.matrix(table["D"], f"{where} D", self.symbols, column=True)
        for value in matrices.values():
            self.sensor_used |= {symbol.name for item in _flatten(value)
                                 for symbol in item.free_symbols}
        update = table.get("update", "batch")
        if update not in SENSOR_UPDATES:
            raise self.error(f"{where} update", f"must be one of {', '.join(SENSOR_UPDATES)}, "
                                                f"got {_kind_name(update)} {update!r}")
        return Sensor(name, table["measurements"], inputs=own, update=update, **matrices)

    def linear(self, body: dict[str, Any], kind: str, sensors: bool = False) -> dict[str, Any]:
        names = self.symbols
        where = f"[{kind}]"
        keys = (("F", "Q") if sensors else ("F", "H", "Q", "R")) if kind == "discrete" \
            else ("Phi", "Qc", "H", "R")
        arguments: dict[str, Any] = {
            key: self.matrix(body[key], f"{where} {key}", names) for key in keys
        }
        for key in ("G", "B", "D"):
            if key in body:
                arguments[key] = self.matrix(body[key], f"{where} {key}", names, column=True)
        if "inputs" in body:
            arguments["inputs"] = self.names(body, "inputs", where)
        if kind == "continuous":
            dt = body["dt"]
            if isinstance(dt, list):
                raise self.error(f"{where} dt", "must be a number or an expression string")
            arguments["dt"] = self.entry(dt, f"{where} dt", names)
        return arguments

    def nonlinear(self, body: dict[str, Any], states: list[str],
                  inputs: list[str], sensors: bool = False) -> dict[str, Any]:
        state_names = {**self.symbols, **{s: sympy.Symbol(s, real=True) for s in states}}
        input_names = {**state_names, **{u: sympy.Symbol(u, real=True) for u in inputs}}
        return {
            "f": self.vector(body["f"], "[nonlinear] f", input_names),
            **({} if sensors else {
                "h": self.vector(body["h"], "[nonlinear] h", input_names),
                "R": self.matrix(body["R"], "[nonlinear] R", input_names)}),
            "Q": self.matrix(body["Q"], "[nonlinear] Q", input_names),
            "inputs": inputs or None,
            **({"Qu": self.matrix(body["Qu"], "[nonlinear] Qu", self.symbols)}
               if "Qu" in body else {}),
            **({"unit_norm": self.unit_norm(body["unit_norm"], states)}
               if "unit_norm" in body else {}),
            **({"rows": self.row_form(body)} if "rows" in body else {}),
            # checked by derive.manifolds.parse_manifolds, which names the component
            **({"manifolds": body["manifolds"]} if "manifolds" in body else {}),
            **({"angles": self.names(body, "angles", "[nonlinear] angles")}
               if "angles" in body else {}),
        }

    def row_form(self, body: dict[str, Any]) -> str:
        """``rows = "scalar" | "vector"``: how the EKF derives its dense covariance work."""
        form = self.string(body, "rows", "[nonlinear]")
        if form not in ROW_FORMS:
            raise self.error("[nonlinear] rows", f"{form!r} is not one of "
                             f"{', '.join(ROW_FORMS)}{_suggest(form, ROW_FORMS)}")
        return form

    def unit_norm(self, value: object, states: list[str]) -> list[list[str]]:
        """``unit_norm = [["q0", "q1", ...], ...]``: groups of state names."""
        where = "[nonlinear] unit_norm"
        if not isinstance(value, list) or not value or not all(
                isinstance(group, list) and all(isinstance(s, str) for s in group)
                for group in value):
            raise self.error(where, "must be a list of lists of state names, e.g. "
                                    f"[[\"q0\", \"q1\", \"q2\", \"q3\"]], got {value!r}")
        for i, group in enumerate(value):
            for name in group:
                if name not in states:
                    raise self.error(f"{where}[{i}]", f"{name!r} is not a state")
        return value

    def initial(self, kind: str) -> dict[str, Any]:
        """x0, P0 and P0_pattern, with valued parameters replaced by their values."""
        table = self.table("initial")
        if table is None:
            return {}
        out: dict[str, Any] = {}
        if "x0" in table:
            out["x0"] = [self.numeric(e, f"[initial] x0[{i}]")
                         for i, e in enumerate(self.vector(table["x0"], "[initial] x0",
                                                           self.symbols))]
        if "P0" in table:
            rows = self.matrix(table["P0"], "[initial] P0", self.symbols)
            out["P0"] = [[self.numeric(e, f"[initial] P0[{i}][{j}]") for j, e in enumerate(row)]
                         for i, row in enumerate(rows)]
        if "P0_pattern" in table:
            pattern = self.string(table, "P0_pattern", "[initial]")
            if pattern not in P0_PATTERNS:
                raise self.error("[initial] P0_pattern", f"{pattern!r} is not one of "
                                 f"{', '.join(P0_PATTERNS)}{_suggest(pattern, P0_PATTERNS)}")
            out["P0_pattern"] = pattern
        return out

    def numeric(self, expr: sympy.Expr, where: str) -> sympy.Expr:
        values = {self.symbols[name]: value for name, value in self.values.items()}
        result = expr.xreplace(values)
        free = sorted(symbol.name for symbol in result.free_symbols)
        if free:
            raise self.error(where, f"uses free parameter {free[0]!r}; initial values must be "
                                    "numbers or expressions in parameters with a value")
        self.used_in_initial |= {symbol.name for symbol in expr.free_symbols}
        return result

    def values_used(self, arguments: dict[str, Any]) -> list[tuple[str, float | int]]:
        """The values of parameters used in the model matrices; unused parameters are
        errors, parameters used only in [initial] are substituted there and not passed."""
        used: set[str] = set(self.sensor_used)
        for key, value in arguments.items():
            if key in ("x0", "P0", "P0_pattern", "inputs", "sensors", "unit_norm", "rows",
                       "manifolds") \
                    or value is None:
                continue
            for item in _flatten(value):
                used |= {symbol.name for symbol in item.free_symbols}
        self.used = used
        for name in self.symbols:
            if name not in used and name not in self.used_in_initial:
                raise self.error(f"[parameters] {name}", "declared but used in no expression")
        return [(name, _plain(value)) for name, value in sorted(self.values.items())
                if name in used]

    def construct(self, kind: str, header: dict[str, str], states: list[str],
                  measurements: list[str], arguments: dict[str, Any]):
        with _model_errors(self.source):
            if kind == "discrete":
                return LinearModel(header["name"], states, measurements, **arguments,
                                   description=header["description"], source=header["source"])
            if kind == "continuous":
                return LinearModel.from_continuous(
                    header["name"], states, measurements, **arguments,
                    description=header["description"], source=header["source"])
            return NonlinearModel(header["name"], states, measurements, **arguments,
                                  description=header["description"], source=header["source"])

    # -- composition ----------------------------------------------------------------------

    def compose(self, model: dict[str, Any], header: dict[str, str]) -> LinearModel:
        for table in ("parameters", "initial"):
            if table in self.doc:
                raise self.error(f"[{table}]", "not allowed with [compose]: the blocks carry "
                                               "their own parameters and initial values")
        blocks = self.table("compose")["blocks"]
        if not isinstance(blocks, list) or not blocks:
            raise self.error("[compose] blocks", f"must be a non-empty list of tables "
                                                 f"{{ model = ..., suffix = ... }}, got "
                                                 f"{_kind_name(blocks)}")
        if len(blocks) > MAX_STATES:
            raise self.error("[compose] blocks", f"{len(blocks)} blocks, more than the limit "
                                                 f"of {MAX_STATES} states")
        models, suffixes = [], []
        states = measurements = 0
        for i, block in enumerate(blocks):
            where = f"[compose] blocks[{i}]"
            if not isinstance(block, dict):
                raise self.error(where, f"must be a table, got {_kind_name(block)}")
            self.check_keys(block, _BLOCK_KEYS, where, ("model",))
            loaded = self.block_model(self.string(block, "model", where), f"{where} model")
            if not isinstance(loaded, LinearModel):
                raise self.error(f"{where} model", f"{loaded.name!r} is not a linear model")
            states, measurements = states + loaded.n, measurements + loaded.m
            for count, limit, what in ((states, MAX_STATES, "states"),
                                       (measurements, MAX_MEASUREMENTS, "measurements")):
                if count > limit:
                    raise self.error(f"{where} model", f"the composed model reaches {count} "
                                                       f"{what} here, more than the limit of "
                                                       f"{limit}")
            models.append(loaded)
            suffixes.append(self.string(block, "suffix", where) if "suffix" in block else None)
        if len({s is None for s in suffixes}) > 1:
            raise self.error("[compose] blocks", "give a suffix for every block or for none")
        with _model_errors(self.source):
            composed = LinearModel.compose(
                header["name"], models, None if suffixes[0] is None else suffixes,
                description=header["description"], source=header["source"])
        for key in ("states", "measurements"):
            if key in model:
                declared = self.names(model, key, "[model]")
                actual = list(getattr(composed, key))
                if declared != actual:
                    raise self.error(f"[model] {key}", f"declares {declared} but the composed "
                                                       f"model has {actual}")
        return composed

    def block_model(self, reference: str, where: str) -> LinearModel | NonlinearModel:
        if reference.isidentifier():
            try:
                text = catalog_files.read_text(reference)
            except ModelError as error:
                raise self.error(where, str(error)) from None
            label = catalog_files.label(reference)
            return self.loader.load_text(text, label, None, label)
        relative = PurePath(reference)
        if relative.is_absolute() or not reference:
            raise self.error(where, f"{reference!r} must be a catalog name or a relative path")
        if self.base_dir is None:
            raise self.error(where, f"{reference!r}: a path needs a model file to be relative "
                                    "to (this model was given as text)")
        base = Path(_key(self.base_dir))
        target = Path(_key(self.base_dir / relative))
        if base != target and base not in target.parents:
            raise self.error(where, f"{reference!r} leaves the directory of {self.source}")
        label = str(Path(self.source).parent / relative)
        return self.loader.load_path(target, label, str(target),
                                     f"{self.source}: {where}: {reference!r}")


def _flatten(value: object) -> Iterator[sympy.Expr]:
    if isinstance(value, list):
        for item in value:
            yield from _flatten(item)
    elif isinstance(value, sympy.Basic):
        yield value


def _plain(value: sympy.Rational) -> float | int:
    """A parameter value for the model classes (they take floats)."""
    return int(value) if value.is_Integer else float(value)
