"""Turning user input into sympy objects: one symbol per name, exact numbers, checked names."""

from __future__ import annotations

import keyword
import math
from collections.abc import Iterable, Mapping

import sympy

from .errors import NameError_, ShapeError, SymbolError

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
    """The one symbol derive uses for ``name`` (real, no other assumptions)."""
    return sympy.Symbol(name, real=True)


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


def number(value: float | int) -> sympy.Expr:
    """An exact sympy number for a Python int or float (0.1 becomes 1/10)."""
    if isinstance(value, bool):
        raise SymbolError(f"a boolean {value!r} is not a number")
    if not isinstance(value, int) and not math.isfinite(value):
        raise SymbolError(f"number {value!r} is not finite")
    from .expressions import exact_number

    return exact_number(value)


def normalize(expr: object, where: str) -> sympy.Expr:
    """Turn one matrix entry (sympy expression, number or plain-arithmetic string) into sympy.

    Every symbol is replaced by ``symbol(name)`` so that symbols with the same name
    are the same symbol whatever assumptions the user gave them.
    """
    if isinstance(expr, str):
        from .expressions import parse_expression

        return parse_expression(expr, {}, allow_new=True, where=where)
    if isinstance(expr, (bool,)):
        raise SymbolError(f"{where}: a boolean is not a matrix entry")
    if isinstance(expr, (int, float)) or (hasattr(expr, "dtype")
                                          and getattr(expr, "shape", None) == ()):
        try:
            return number(expr if isinstance(expr, (int, float)) else float(expr))
        except SymbolError as exc:
            raise SymbolError(f"{where}: {exc}") from None
    if isinstance(expr, sympy.Basic):
        e = sympy.sympify(expr)
        if isinstance(e, sympy.Float):
            return number(float(e))
        floats = {f: number(float(f)) for f in e.atoms(sympy.Float)}
        syms = {s: symbol(s.name) for s in e.free_symbols if isinstance(s, sympy.Symbol)}
        e = e.xreplace({**floats, **syms})
        if not isinstance(e, sympy.Expr) or e.has(sympy.I) or e.has(sympy.zoo, sympy.oo,
                                                                     sympy.nan):
            raise SymbolError(f"{where}: {expr!r} is not a finite real expression")
        return e
    raise SymbolError(f"{where}: cannot use {type(expr).__name__} {expr!r} as a matrix entry")


def as_matrix(value: object, name: str, *, vector: bool = False) -> sympy.ImmutableMatrix:
    """A sympy matrix from a sympy matrix, a NumPy array or nested lists; entries normalised.

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
        [[normalize(e, f"{name}[{i}][{j}]") for j, e in enumerate(r)] for i, r in enumerate(rows)]
    )


def check_shape(mat: sympy.MatrixBase, name: str, shape: tuple[int, int], meaning: str) -> None:
    if mat.shape != shape:
        raise ShapeError(
            f"matrix {name} must be {shape[0]}x{shape[1]} ({meaning}), got "
            f"{mat.shape[0]}x{mat.shape[1]}"
        )


def normalize_values(values: Mapping[object, object] | None) -> dict[str, sympy.Expr]:
    """Map symbol names to exact numbers; reject non-numbers and a name given twice."""
    out: dict[str, sympy.Expr] = {}
    for key, val in (values or {}).items():
        name = key.name if isinstance(key, sympy.Symbol) else key
        check_identifier(name, "parameter name")
        if name in out:
            raise SymbolError(f"symbol {name!r} has two values")
        if isinstance(val, sympy.Basic):
            if not val.is_number:
                raise SymbolError(f"value of {name!r} must be a number, got {val}")
            val = float(val)
        if not isinstance(val, (int, float)) or isinstance(val, bool):
            raise SymbolError(f"value of {name!r} must be a number, got {val!r}")
        try:
            out[name] = number(val)
        except SymbolError as exc:
            raise SymbolError(f"value of {name!r}: {exc}") from None
    return dict(sorted(out.items()))
