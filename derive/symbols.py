"""Turning user input into sympy objects: one symbol per name, exact numbers, checked names."""

from __future__ import annotations

import keyword
import math
import re
import sys
from collections.abc import Iterable, Mapping

import numpy as np
import sympy

from .errors import ModelError, NameError_, ShapeError, SymbolError
from .expressions import exact_number, parse_expression
from .guards import selects

#: Words that can never be a model, state, measurement or parameter name: they
#: would break generated Python or C99.
C_KEYWORDS = frozenset(
    """auto break case char const continue default do double else enum extern float for goto
    if inline int long register restrict return short signed sizeof static struct switch
    typedef union unsigned void volatile while _Bool _Complex _Imaginary main NULL fma sqrt
    size_t""".split()
)
#: C math functions and constants a generated file may call; they cannot be names either.
C_MATH = frozenset(
    "exp log sin cos tan asin acos atan atan2 sinh cosh tanh pow abs fabs pi".split())
RESERVED = (C_KEYWORDS | C_MATH | frozenset(keyword.kwlist) | frozenset(keyword.softkwlist))


def symbol(name: str) -> sympy.Symbol:
    """The symbol derive uses for ``name`` when the user gave no symbol of that name
    (real, no other assumptions): names in strings, states and inputs not written in f/h."""
    return sympy.Symbol(name, real=True)


def real_stand_ins(symbols: Iterable[sympy.Symbol]
                   ) -> tuple[dict[sympy.Symbol, sympy.Dummy], dict[sympy.Dummy, sympy.Symbol]]:
    """Real stand-ins for the symbols not known to be real, and the map back.

    Model entries are real, whatever assumptions the user's symbols carry, so derivatives
    and matrix exponentials are taken over real stand-ins (``d|x|/dx = sign(x)``, not
    ``re``/``im`` terms) and the user's symbols are put back afterwards."""
    forward = {s: sympy.Dummy(s.name, real=True) for s in symbols if s.is_real is not True}
    return forward, {v: k for k, v in forward.items()}


def jacobian(values: sympy.MatrixBase, wrt) -> sympy.ImmutableMatrix:
    """``d values / d wrt`` with every symbol taken as real (see `real_stand_ins`), the
    derivatives of guards as selects (``d|x|/dx = sign(x)``, derive.guards)."""
    real, back = real_stand_ins(values.free_symbols | set(wrt))
    stand_ins = [real.get(s, s) for s in wrt]
    jac = values.xreplace(real).jacobian(stand_ins).xreplace(back)
    return sympy.ImmutableMatrix(jac.applyfunc(lambda e: selects(e, "a Jacobian entry")))


def natural_key(name: str) -> tuple:
    """Sort key putting ``k2`` before ``k10`` (digit runs compare as numbers)."""
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part)
                 for part in re.split(r"(\d+)", name) if part)


def describe_symbol(sym: sympy.Symbol) -> str:
    """``Symbol('dt', positive=True)``: the symbol with the assumptions it was made with."""
    given = getattr(sym, "_assumptions_orig", None)
    if given is None:
        given = {k: v for k, v in sym.assumptions0.items() if k != "commutative"}
    given = {k: v for k, v in given.items() if k != "commutative"}
    extra = "".join(f", {k}={v}" for k, v in sorted(given.items()))
    return f"{type(sym).__name__}({sym.name!r}{extra})"


class SymbolTable:
    """The symbols of one model, by name, in order of first appearance.

    A symbol the user gave (inside a sympy entry, or as a ``values`` key) is kept as
    given, assumptions included. A name written in a string (an expression entry, a
    ``values`` key) means the model's symbol of that name: the user's if there is one,
    else ``symbol(name)``. Two different symbols with one name are ambiguous and refused.
    """

    def __init__(self) -> None:
        self.by_name: dict[str, sympy.Symbol] = {}
        self._given_at: dict[str, str] = {}

    @classmethod
    def known(cls, symbols: Iterable[sympy.Symbol], where: str) -> SymbolTable:
        """A table of symbols already fixed (a built model's), for checking new keys."""
        table = cls()
        for s in symbols:
            table.given(s, where)
        return table

    def given(self, sym: sympy.Symbol, where: str) -> None:
        """Record a symbol the user gave at ``where``; refuse a second one of its name."""
        name = sym.name
        if name in self._given_at:
            first = self.by_name[name]
            if first != sym:
                raise SymbolError(
                    f"two different symbols are named {name!r}: {describe_symbol(first)} in "
                    f"{self._given_at[name]} and {describe_symbol(sym)} in {where}; use one "
                    "symbol (the same assumptions) for one name")
            return
        self._given_at[name] = where
        self.by_name[name] = sym  # replaces a string's default, keeping its position

    def named(self, name: str) -> sympy.Symbol:
        """The model's symbol for ``name`` (recorded at its first appearance)."""
        return self.by_name.setdefault(name, symbol(name))

    def add_expr(self, expr: sympy.Basic, where: str, *, from_text: bool) -> None:
        """Record the symbols of one entry, in natural order of their names."""
        syms = sorted((s for s in expr.free_symbols if isinstance(s, sympy.Symbol)),
                      key=lambda s: natural_key(s.name))
        for s in syms:
            if from_text:
                self.named(s.name)
            else:
                self.given(s, where)

    def finish(self, mat: sympy.ImmutableMatrix) -> sympy.ImmutableMatrix:
        """``mat`` with every name written in a string bound to the model's symbol."""
        swap = {symbol(n): s for n, s in self.by_name.items() if s != symbol(n)}
        return mat.xreplace(swap) if swap else mat


def check_identifier(name: object, what: str) -> str:
    """Return ``name`` if it is a plain identifier usable in Python and C99."""
    if not isinstance(name, str):
        raise NameError_(f"{what} must be a string, got {type(name).__name__} {name!r}")
    if not name.isidentifier() or not name.isascii():
        raise NameError_(f"{what} {name!r} is not an identifier (letters, digits, underscore)")
    if name.startswith("_"):
        raise NameError_(f"{what} {name!r} must not start with an underscore")
    if name in RESERVED:
        raise NameError_(f"{what} {name!r} is a reserved word in Python or C")
    return name


def check_names(names: Iterable[object], what: str) -> tuple[str, ...]:
    """Check a list of names: identifiers, non-empty, no repeats."""
    if isinstance(names, str):
        raise NameError_(f"{what} must be a list of names, got the string {names!r}")
    if not isinstance(names, Iterable):
        raise NameError_(f"{what} must be a list of names, got {type(names).__name__} {names!r}")
    out = tuple(check_identifier(n, f"{what[:-1] if what.endswith('s') else what} name")
                for n in names)
    if not out:
        raise NameError_(f"{what} must not be empty")
    seen: set[str] = set()
    for n in out:
        if n in seen:
            raise NameError_(f"{what}: name {n!r} appears twice")
        seen.add(n)
    return out


DOUBLE_MAX = sympy.Rational(sys.float_info.max)
"""The largest finite double, exactly: numbers beyond it cannot reach generated code."""


def plain_number(value: object) -> int | float | None:
    """``value`` as a Python int or float if it is a real number of Python or NumPy
    (``np.float64``, ``np.float32``, ``np.int64``, ...; not a boolean), else None.
    NumPy scalars become the Python number they hold exactly."""
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value)
    return None


def decimal(value: sympy.Expr) -> str:
    """A number as a short decimal for messages (``1e+400``, ``0.1``, ``3``), not a
    fraction; a symbolic expression as its text."""
    if not value.is_number:
        return str(value)
    if value.is_Integer and abs(value) < 10**15:
        return str(value)
    try:
        as_float = float(value)
    except (OverflowError, TypeError, ValueError):
        as_float = math.inf
    if math.isfinite(as_float) and (as_float != 0 or value == 0):
        return repr(as_float)
    shown = sympy.Float(value, 17)
    if not shown.is_finite:
        return str(value)
    return re.sub(r"\.?0+e", "e", str(shown))


def number(value: object) -> sympy.Rational:
    """An exact sympy number for a Python or NumPy int or float (0.1 becomes 1/10).

    Refused: booleans, NaN and infinities, numbers beyond the double range (SymbolError)
    and integers too long to be exact numbers (ExpressionError)."""
    plain = plain_number(value)
    if plain is None:
        raise SymbolError(f"{value!r} is not a number")
    if isinstance(plain, float) and not math.isfinite(plain):
        raise SymbolError(f"number {plain!r} is not finite")
    exact = exact_number(plain)
    if abs(exact) > DOUBLE_MAX:
        raise SymbolError(f"number {decimal(exact)} is beyond the range of a double")
    return exact


def normalize(expr: object, where: str, table: SymbolTable) -> sympy.Expr:
    """Turn one matrix entry (sympy expression, number or plain-arithmetic string) into sympy.

    Numbers become exact; the symbols of sympy entries are kept as given and recorded in
    ``table``; names in strings become the table's symbols of those names.
    """
    if isinstance(expr, str):
        parsed = parse_expression(expr, table.by_name, allow_new=True, where=where)
        table.add_expr(parsed, where, from_text=True)
        return parsed
    if isinstance(expr, (bool, np.bool_)):
        raise SymbolError(f"{where}: a boolean is not a matrix entry")
    if plain_number(expr) is not None:
        try:
            return number(expr)
        except ModelError as exc:
            raise type(exc)(f"{where}: {exc}") from None
    if isinstance(expr, np.ndarray) and expr.shape == ():
        return normalize(expr.item(), where, table)
    if isinstance(expr, sympy.Basic):
        e = sympy.sympify(expr)
        if not isinstance(e, sympy.Expr) or e.has(sympy.I) or e.has(sympy.zoo, sympy.oo,
                                                                     sympy.nan):
            raise SymbolError(f"{where}: {expr!r} is not a finite real expression")
        try:
            if isinstance(e, sympy.Float):
                return number(float(e))
            floats = {f: number(float(f)) for f in e.atoms(sympy.Float)}
        except ModelError as exc:
            raise type(exc)(f"{where}: {exc}") from None
        e = e.xreplace(floats) if floats else e
        table.add_expr(e, where, from_text=False)
        return e
    raise SymbolError(f"{where}: cannot use {type(expr).__name__} {expr!r} as a matrix entry")


def as_matrix(value: object, name: str, table: SymbolTable, *,
              vector: bool = False) -> sympy.ImmutableMatrix:
    """A sympy matrix from a sympy matrix, a NumPy array or nested lists; entries normalised
    (symbols recorded in ``table``, row-major).

    ``vector=True`` accepts a flat list as a column. A scalar becomes a 1x1 matrix.
    """
    if isinstance(value, sympy.MatrixBase):
        rows = value.tolist()
    elif hasattr(value, "tolist") and hasattr(value, "shape"):
        rows = value.tolist()  # numpy array
        if not isinstance(rows, list):
            rows = [[rows]]
    elif isinstance(value, (list, tuple)):
        rows = list(value)
    else:
        rows = [[value]]
    if not rows:
        raise ShapeError(f"matrix {name} is empty")
    if all(not isinstance(r, (list, tuple)) for r in rows):
        rows = [[r] for r in rows] if vector or len(rows) > 1 else [list(rows)]
    if any(not isinstance(r, (list, tuple)) for r in rows):
        raise ShapeError(f"matrix {name}: mixes rows (lists) and single entries")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise ShapeError(f"matrix {name} is ragged: row lengths {sorted(widths)}")
    if widths == {0}:
        raise ShapeError(f"matrix {name} has empty rows")
    return sympy.ImmutableMatrix(
        [[normalize(e, f"{name}[{i}][{j}]", table) for j, e in enumerate(r)]
         for i, r in enumerate(rows)]
    )


def check_shape(mat: sympy.MatrixBase, name: str, shape: tuple[int, int], meaning: str) -> None:
    if mat.shape != shape:
        raise ShapeError(
            f"matrix {name} must be {shape[0]}x{shape[1]} ({meaning}), got "
            f"{mat.shape[0]}x{mat.shape[1]}"
        )


def normalize_values(values: Mapping[object, object] | None,
                     table: SymbolTable | None = None,
                     what: str = "values") -> dict[str, sympy.Rational]:
    """Map symbol names to exact numbers, in the order given; reject non-numbers, numbers
    that are not finite doubles and a name given twice. A symbol key is checked against
    ``table`` (another symbol of its name is ambiguous)."""
    if values is not None and not isinstance(values, Mapping):
        raise SymbolError(f"{what} must be a mapping from names to numbers, got "
                          f"{type(values).__name__}")
    out: dict[str, sympy.Rational] = {}
    for key, val in (values or {}).items():
        name = key.name if isinstance(key, sympy.Symbol) else key
        check_identifier(name, "parameter name")
        if isinstance(key, sympy.Symbol) and table is not None:
            table.given(key, what)
        if name in out:
            raise SymbolError(f"symbol {name!r} has two values")
        if isinstance(val, sympy.Basic):
            if not val.is_number:
                raise SymbolError(f"value of {name!r} must be a number, got {val}")
            try:
                out[name] = number(float(val)) if not val.is_Rational else val
            except (SymbolError, TypeError) as exc:
                raise SymbolError(f"value of {name!r}: {exc}") from None
            if abs(out[name]) > DOUBLE_MAX:
                raise SymbolError(f"value of {name!r}: number {decimal(out[name])} is beyond "
                                  "the range of a double")
            continue
        if plain_number(val) is None:
            raise SymbolError(f"value of {name!r} must be a number, got {val!r}")
        try:
            out[name] = number(val)
        except SymbolError as exc:
            raise SymbolError(f"value of {name!r}: {exc}") from None
    return out
