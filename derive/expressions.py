"""Safe parsing of expression strings (model files) into sympy, by an allow-list over `ast`.

The text is parsed with ``ast.parse(text, mode="eval")`` and the tree is walked; sympy
objects are built node by node. Nothing is ever passed to ``eval`` or ``sympify``.

Allowed:

- integer and decimal literals (``2``, ``0x1F``, ``1_000``, ``0.1``, ``2.5e-3``). A decimal
  literal becomes the exact rational its text denotes: ``0.1`` is ``Rational(1, 10)``, not
  the double nearest to it, so ``0.1*3 - 0.3`` is exactly zero;
- names: declared symbols (the ``names`` mapping) and the constant ``pi``; with
  ``allow_new=True`` an undeclared name becomes ``Symbol(name, real=True)``;
- ``+ - * / **`` and unary ``-`` and ``+``, with parentheses;
- calls, by bare name and with positional arguments only, of the functions in `FUNCTIONS`
  (among them the guards ``sign``, ``max`` and ``min``);
- ``Piecewise((value, condition), ..., (default, True))``: each condition one comparison
  ``<``, ``<=``, ``>`` or ``>=`` of two expressions (no chain), the last ``True``; each
  value one expression (generated code computes every branch and selects one:
  derive.guards).

Everything else (attribute access, subscripts, strings, f-strings, lambdas, comprehensions,
comparisons outside a Piecewise condition, boolean operators, conditional expressions,
``:=``, keyword or starred arguments, ...) raises `ExpressionError` naming the construct
and its line and column, as do names starting with an underscore and non-ASCII text.

Resource limits, checked before the sympy object they would guard is built: the text
length, the node count and nesting depth of the tree, the size of exponents (an exponent
is an integer literal, a small rational ``p/q`` or a decimal literal equal to one, a
name, or the negation of one of these), the number of bits of any exact number the
expression can produce, and its polynomial degree. Results holding ``zoo``, ``nan``,
``oo`` or ``I`` (``1/0``, ``sqrt(-1)``) are rejected too.
"""

from __future__ import annotations

import ast
import difflib
import math
import re
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from fractions import Fraction

import sympy

from derive.errors import ExpressionError

MAX_TEXT_LENGTH = 2000
"""Longest accepted expression text, in characters."""
MAX_NODES = 500
"""Most `ast` nodes an expression may have."""
MAX_DEPTH = 64
"""Deepest nesting of `ast` nodes (``-(-(-x))`` has depth 4)."""
MAX_EXPONENT = 64
"""Bound on an integer exponent and on the numerator and denominator of a rational one."""
MAX_NUMBER_BITS = 2048
"""Bound on the bits (numerator plus denominator) of any exact number built; 2048 bits
cover the double range (about 1e±308) with room for products of two such numbers."""
MAX_DEGREE = 256
"""Bound on the polynomial degree of the expression (``x**64 * y**64`` has degree 128)."""

FUNCTIONS: Mapping[str, tuple[Callable[..., sympy.Expr], int]] = {
    "sqrt": (sympy.sqrt, 1),
    "exp": (sympy.exp, 1),
    "log": (sympy.log, 1),
    "sin": (sympy.sin, 1),
    "cos": (sympy.cos, 1),
    "tan": (sympy.tan, 1),
    "asin": (sympy.asin, 1),
    "acos": (sympy.acos, 1),
    "atan": (sympy.atan, 1),
    "atan2": (sympy.atan2, 2),
    "sinh": (sympy.sinh, 1),
    "cosh": (sympy.cosh, 1),
    "tanh": (sympy.tanh, 1),
    "abs": (sympy.Abs, 1),
    "sign": (sympy.sign, 1),
    "max": (sympy.Max, 2),
    "min": (sympy.Min, 2),
}
"""The callable functions: name -> (sympy function, number of arguments)."""

PIECEWISE = "Piecewise"
"""The name of the guard by conditions (``Piecewise((a, x > 0), (b, True))``)."""
_RELATIONS: Mapping[type, Callable[..., sympy.Basic]] = {
    ast.Gt: sympy.StrictGreaterThan, ast.GtE: sympy.GreaterThan,
    ast.Lt: sympy.StrictLessThan, ast.LtE: sympy.LessThan,
}

CONSTANTS: Mapping[str, sympy.Expr] = {"pi": sympy.pi}
"""Names with a fixed value."""

RESERVED_NAMES = frozenset(FUNCTIONS) | frozenset(CONSTANTS) | {PIECEWISE}
"""Names that cannot be symbols (model files reject parameters or states named so)."""

_OPERATORS: Mapping[type, str] = {
    ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**",
    ast.FloorDiv: "//", ast.Mod: "%", ast.MatMult: "@", ast.LShift: "<<", ast.RShift: ">>",
    ast.BitOr: "|", ast.BitXor: "^", ast.BitAnd: "&",
    ast.USub: "unary -", ast.UAdd: "unary +", ast.Not: "'not'", ast.Invert: "'~'",
}

_CONSTRUCTS: Mapping[type, str] = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscript",
    ast.Slice: "slice",
    ast.Lambda: "lambda",
    ast.ListComp: "list comprehension",
    ast.SetComp: "set comprehension",
    ast.DictComp: "dict comprehension",
    ast.GeneratorExp: "generator expression",
    ast.IfExp: "conditional expression (x if c else y)",
    ast.Compare: "comparison",
    ast.BoolOp: "boolean operator (and/or)",
    ast.NamedExpr: "assignment expression (:=)",
    ast.Starred: "starred argument",
    ast.JoinedStr: "f-string",
    ast.FormattedValue: "f-string",
    ast.Tuple: "tuple",
    ast.List: "list",
    ast.Set: "set",
    ast.Dict: "dict",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield",
}

_CHAIN_OPERATORS = (ast.Add, ast.Sub, ast.Mult, ast.Div)
_NOT_COUNTED = (ast.expr_context, ast.operator, ast.unaryop, ast.boolop, ast.cmpop)
_DECIMAL = re.compile(r"(\d*)(?:\.(\d*))?(?:[eE]([+-]?\d+))?")
_UNSAFE_RESULT = (sympy.zoo, sympy.nan, sympy.oo, -sympy.oo, sympy.I)


@dataclass(frozen=True)
class _Built:
    """A built subexpression with static bounds on what combining it can cost."""

    expr: sympy.Expr
    bits: int
    degree: int


def _is_chain(node: ast.AST) -> bool:
    """A binary + - * / node (the operators whose left-nested chains are folded in a loop)."""
    return isinstance(node, ast.BinOp) and isinstance(node.op, _CHAIN_OPERATORS)


def parse_expression(
    text: str,
    names: Mapping[str, sympy.Expr],
    *,
    allow_new: bool = False,
    where: str = "",
) -> sympy.Expr:
    """Parse `text` into a sympy expression over the symbols in `names`.

    `where` prefixes every error message (e.g. ``"model.toml: [discrete] F[1][0]"``).
    Raises `ExpressionError` for anything outside the allow-list of the module docstring.
    """
    return _Parser(text, names, allow_new, where).parse()


def exact_number(value: float | Fraction, where: str = "") -> sympy.Rational:
    """The exact sympy number for a literal value: floats by their shortest decimal text
    (``0.1`` -> 1/10), so TOML numbers and expression literals agree."""
    prefix = f"{where}: " if where else ""
    if isinstance(value, bool) or not isinstance(value, (int, float, Fraction)):
        raise ExpressionError(f"{prefix}expected a number, got {type(value).__name__} {value!r}")
    if isinstance(value, float):
        return exact_decimal(repr(value), where)  # handles the sign (-0.5, -0.0)
    try:
        number = Fraction(value)
        _check_bits(number)
    except ValueError as error:
        shown = (_short(str(value)) if number.numerator.bit_length() < 4000
                 else f"of {number.numerator.bit_length()} bits")
        raise ExpressionError(f"{prefix}number {shown} {error}") from None
    return sympy.Rational(number.numerator, number.denominator)


def exact_decimal(text: str, where: str = "") -> sympy.Rational:
    """The exact number a decimal text denotes (``"-0.1"`` -> -1/10), sign allowed."""
    prefix = f"{where}: " if where else ""
    sign = -1 if text[:1] == "-" else 1
    try:
        number = _decimal_fraction(text[1:] if text[:1] in "+-" else text)
        _check_bits(number)
    except ValueError as error:
        raise ExpressionError(f"{prefix}number {_short(text)} {error}") from None
    return sympy.Rational(sign * number.numerator, number.denominator)


def _decimal_fraction(text: str) -> Fraction:
    """Exact value of a decimal literal's text; ValueError if it is not finite or would
    take too long to compute (``1e99999999``)."""
    match = _DECIMAL.fullmatch(text.replace("_", ""))
    if match is None or not (match.group(1) or match.group(2)):
        raise ValueError("is not a finite decimal number")
    whole, fraction, exponent = match.group(1), match.group(2) or "", match.group(3) or "0"
    digits = int(whole + fraction)
    if digits == 0:
        return Fraction(0)
    shift = int(exponent) - len(fraction)
    if abs(shift) > MAX_NUMBER_BITS:
        raise ValueError(f"is out of range (decimal exponent {shift})")
    return Fraction(digits * 10**shift) if shift >= 0 else Fraction(digits, 10**-shift)


def _check_bits(number: Fraction) -> int:
    """The bits of an exact number (numerator plus denominator), at most MAX_NUMBER_BITS."""
    bits = number.numerator.bit_length() + number.denominator.bit_length()
    if bits > MAX_NUMBER_BITS:
        raise ValueError(f"needs {bits} bits, more than the limit of {MAX_NUMBER_BITS}")
    return bits


def _short(text: str, limit: int = 60) -> str:
    return repr(text) if len(text) <= limit else repr(text[:limit] + "...")


class _Parser:
    """One parse: the text, the symbols in scope, and the error context."""

    def __init__(
        self, text: str, names: Mapping[str, sympy.Expr], allow_new: bool, where: str
    ) -> None:
        self.raw = text
        self.names = names
        self.allow_new = allow_new
        self.prefix = f"{where}: " if where else ""
        self.text = ""
        self.line_shift = 0
        self.column_shift = 0

    # -- errors ---------------------------------------------------------------------------

    def fail(self, message: str, node: ast.AST | None = None) -> ExpressionError:
        """The error for `message`, located at `node` (line and column in the raw text)."""
        position = ""
        if node is not None and hasattr(node, "lineno"):
            position = self.position(node.lineno, node.col_offset + 1)
        return ExpressionError(f"{self.prefix}in {_short(self.raw)}{position}: {message}")

    def position(self, line: int, column: int) -> str:
        if line == 1:
            column += self.column_shift
        return f" at line {line + self.line_shift}, column {column}"

    # -- entry ----------------------------------------------------------------------------

    def parse(self) -> sympy.Expr:
        if not isinstance(self.raw, str):
            raise ExpressionError(
                f"{self.prefix}expected an expression string, got {type(self.raw).__name__}"
            )
        if len(self.raw) > MAX_TEXT_LENGTH:
            raise ExpressionError(
                f"{self.prefix}expression is {len(self.raw)} characters long, "
                f"more than the limit of {MAX_TEXT_LENGTH}"
            )
        self.strip()
        if not self.text:
            raise ExpressionError(f"{self.prefix}empty expression")
        tree = self.syntax_tree()
        self.check_size(tree.body)
        built = self.build(tree.body)
        if built.expr.has(*_UNSAFE_RESULT):
            raise self.fail(
                f"expression evaluates to {built.expr} (a division by zero, or not real)"
            )
        return built.expr

    def strip(self) -> None:
        """Drop surrounding whitespace (Python rejects leading indentation) and refuse
        non-ASCII text (Python would silently NFKC-normalise identifiers)."""
        self.text = self.raw.strip()
        lead = self.raw[: len(self.raw) - len(self.raw.lstrip())]
        self.line_shift = lead.count("\n")
        self.column_shift = len(lead) - (lead.rfind("\n") + 1)
        for index, char in enumerate(self.raw):
            if not char.isascii():
                line = self.raw.count("\n", 0, index) + 1
                column = index - (self.raw.rfind("\n", 0, index) + 1) + 1
                raise ExpressionError(
                    f"{self.prefix}in {_short(self.raw)} at line {line}, column {column}: "
                    f"non-ASCII character {char!r} (symbol names must be ASCII)"
                )

    def syntax_tree(self) -> ast.Expression:
        try:
            with warnings.catch_warnings():  # e.g. invalid escapes in a (rejected) string
                warnings.simplefilter("ignore")
                return ast.parse(self.text, mode="eval")
        except SyntaxError as error:
            where = self.position(error.lineno, error.offset or 1) if error.lineno else ""
            raise ExpressionError(
                f"{self.prefix}in {_short(self.raw)}{where}: not a valid expression ({error.msg})"
            ) from None
        except (ValueError, RecursionError, MemoryError) as error:
            raise ExpressionError(
                f"{self.prefix}in {_short(self.raw)}: not a valid expression ({error})"
            ) from None

    def check_size(self, root: ast.AST) -> None:
        """Node count and depth, iteratively (the builder recurses, so this goes first).

        Operator and context nodes are not counted, and the left operand of a chain
        ``a + b - c * d / e`` stays at its parent's depth: the builder folds such chains
        in a loop, so ``x1 + x2 + ... + x100`` is long, not deep.
        """
        count = 0
        stack = [(root, 1)]
        while stack:
            node, depth = stack.pop()
            count += 1
            if count > MAX_NODES:
                raise self.fail(f"expression has more than {MAX_NODES} syntax nodes")
            if depth > MAX_DEPTH:
                raise self.fail(f"expression is nested more than {MAX_DEPTH} deep", node)
            for child in ast.iter_child_nodes(node):
                if isinstance(child, _NOT_COUNTED):
                    continue
                chained = _is_chain(node) and child is node.left and _is_chain(child)
                stack.append((child, depth if chained else depth + 1))

    # -- building -------------------------------------------------------------------------

    def build(self, node: ast.AST) -> _Built:
        if isinstance(node, ast.Constant):
            return self.constant(node)
        if isinstance(node, ast.Name):
            return self.name(node)
        if isinstance(node, ast.UnaryOp):
            return self.unary(node)
        if isinstance(node, ast.BinOp):
            return self.binary(node)
        if isinstance(node, ast.Call):
            return self.call(node)
        construct = _CONSTRUCTS.get(type(node), f"'{type(node).__name__}' syntax")
        raise self.fail(f"{construct} is not allowed", node)

    def constant(self, node: ast.Constant) -> _Built:
        number = self.literal(node)
        if number is None:
            value = node.value
            kinds = {bool: "boolean literal", str: "string literal", bytes: "bytes literal",
                     complex: "complex literal"}
            construct = kinds.get(type(value), f"literal {value!r}")
            raise self.fail(f"{construct} is not allowed", node)
        bits = number.numerator.bit_length() + number.denominator.bit_length()
        return _Built(sympy.Rational(number.numerator, number.denominator), bits, 0)

    def literal(self, node: ast.AST) -> Fraction | None:
        """The exact value of an int or decimal literal (None for any other node); a
        decimal literal is read from its text, so ``0.1`` is exactly 1/10."""
        if not isinstance(node, ast.Constant) or isinstance(node.value, bool):
            return None
        if isinstance(node.value, int):
            number = Fraction(node.value)
        elif isinstance(node.value, float):
            segment = ast.get_source_segment(self.text, node) or repr(node.value)
            try:
                number = _decimal_fraction(segment)
            except ValueError as error:
                raise self.fail(f"numeric literal {segment} {error}", node) from None
        else:
            return None
        try:
            _check_bits(number)
        except ValueError as error:
            raise self.fail(f"numeric literal {error}", node) from None
        return number

    def name(self, node: ast.Name) -> _Built:
        name = node.id
        if name.startswith("_"):
            raise self.fail(
                f"name {name!r} is not allowed (names may not start with an underscore)", node)
        if name in self.names:
            symbol = self.names[name]
            if not isinstance(symbol, sympy.Expr):
                raise TypeError(f"names[{name!r}] must be a sympy expression, not {symbol!r}")
            return _Built(symbol, 0, 1)
        if name in CONSTANTS:
            return _Built(CONSTANTS[name], 0, 0)
        if name in FUNCTIONS:
            raise self.fail(f"function {name!r} used without a call", node)
        if self.allow_new:
            return _Built(sympy.Symbol(name, real=True), 0, 1)
        raise self.fail(f"unknown symbol {name!r}{self.suggestion(name)}", node)

    def suggestion(self, name: str) -> str:
        known = sorted(self.names)
        close = difflib.get_close_matches(name, known, n=3)
        hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
        listing = ", ".join(known[:20]) + (", ..." if len(known) > 20 else "")
        return f"{hint}; declared: {listing or 'none'}"

    def unary(self, node: ast.UnaryOp) -> _Built:
        if not isinstance(node.op, (ast.USub, ast.UAdd)):
            raise self.fail(f"operator {_OPERATORS.get(type(node.op), '?')} is not allowed", node)
        operand = self.build(node.operand)
        expr = -operand.expr if isinstance(node.op, ast.USub) else operand.expr
        return _Built(expr, operand.bits, operand.degree)

    def binary(self, node: ast.BinOp) -> _Built:
        if isinstance(node.op, ast.Pow):
            return self.power(node)
        if not _is_chain(node):
            raise self.fail(f"operator {_OPERATORS.get(type(node.op), '?')} is not allowed", node)
        spine = [node]  # a left-nested chain a + b - c ..., folded without recursion
        while _is_chain(spine[-1].left):
            spine.append(spine[-1].left)
        left = self.build(spine[-1].left)
        for link in reversed(spine):
            right = self.build(link.right)
            bits = left.bits + right.bits + 1
            if isinstance(link.op, (ast.Add, ast.Sub)):
                degree = max(left.degree, right.degree)
            else:
                degree = left.degree + right.degree
            self.check_bounds(bits, degree, link)
            if isinstance(link.op, ast.Add):
                expr = left.expr + right.expr
            elif isinstance(link.op, ast.Sub):
                expr = left.expr - right.expr
            elif isinstance(link.op, ast.Mult):
                expr = left.expr * right.expr
            else:
                expr = left.expr / right.expr
            left = _Built(expr, bits, degree)
        return left

    def power(self, node: ast.BinOp) -> _Built:
        base = self.build(node.left)
        exponent = self.exponent(node.right)
        if exponent is None:  # a symbolic exponent: nothing is evaluated
            symbolic = self.build(node.right)
            return _Built(base.expr**symbolic.expr, base.bits, base.degree)
        scale = abs(exponent.numerator)
        bits, degree = base.bits * scale + 1, base.degree * scale
        self.check_bounds(bits, degree, node)
        return _Built(base.expr ** exact_number(exponent), bits, degree)

    def exponent(self, node: ast.AST) -> Fraction | None:
        """The value of a numeric exponent (None for a name), or an error if not allowed."""
        sign = 1
        inner = node
        if isinstance(inner, ast.UnaryOp) and isinstance(inner.op, (ast.USub, ast.UAdd)):
            sign = -1 if isinstance(inner.op, ast.USub) else 1
            inner = inner.operand
        if isinstance(inner, ast.Name):
            return None
        value = self.literal(inner)
        if value is None and isinstance(inner, ast.BinOp) and isinstance(inner.op, ast.Div):
            top, bottom = self.literal(inner.left), self.literal(inner.right)
            if top is not None and bottom and top.denominator == bottom.denominator == 1:
                value = top / bottom
        if value is None:
            raise self.fail(
                "exponent must be a number, a small fraction p/q or a name "
                f"(|p|, |q| <= {MAX_EXPONENT})",
                node,
            )
        if abs(value.numerator) > MAX_EXPONENT or value.denominator > MAX_EXPONENT:
            raise self.fail(f"exponent {value} is too large (limit {MAX_EXPONENT})", node)
        return sign * value

    def call(self, node: ast.Call) -> _Built:
        if not isinstance(node.func, ast.Name):
            construct = _CONSTRUCTS.get(type(node.func))
            if construct:
                raise self.fail(f"{construct} is not allowed", node.func)
            raise self.fail("call of a computed value is not allowed", node)
        name = node.func.id
        if name == PIECEWISE and not node.keywords:
            return self.piecewise(node)
        if name not in FUNCTIONS:
            allowed = ", ".join(sorted([*FUNCTIONS, PIECEWISE], key=str.lower))
            raise self.fail(f"call of {name!r} is not allowed (functions: {allowed})", node)
        if node.keywords:
            keyword = node.keywords[0]
            label = f"keyword argument {keyword.arg!r}" if keyword.arg else "'**' argument"
            raise self.fail(f"{label} is not allowed", keyword)
        for argument in node.args:
            if isinstance(argument, ast.Starred):
                raise self.fail("starred argument is not allowed", argument)
        function, arity = FUNCTIONS[name]
        if len(node.args) != arity:
            raise self.fail(
                f"{name}() takes {arity} argument{'s' if arity > 1 else ''}, "
                f"got {len(node.args)}",
                node,
            )
        arguments = [self.build(argument) for argument in node.args]
        bits = sum(argument.bits for argument in arguments) + 1
        degree = max(argument.degree for argument in arguments)
        self.check_bounds(bits, degree, node)
        return _Built(function(*(argument.expr for argument in arguments)), bits, degree)

    def piecewise(self, node: ast.Call) -> _Built:
        """``Piecewise((value, condition), ..., (default, True))``: see the module
        docstring; a branch that is not one value (a tuple, a list) is refused as a shape
        that differs from the others."""
        if not node.args:
            raise self.fail("Piecewise() needs at least one (value, condition) branch", node)
        pairs, bits, degree = [], 1, 0
        for k, branch in enumerate(node.args, 1):
            if not isinstance(branch, ast.Tuple) or len(branch.elts) != 2:
                raise self.fail(f"branch {k} of Piecewise must be a (value, condition) pair",
                                branch)
            value, condition = branch.elts
            if isinstance(value, (ast.Tuple, ast.List)):
                raise self.fail(f"branch {k} of Piecewise is a {type(value).__name__.lower()} "
                                f"of {len(value.elts)} values, not one value like a scalar "
                                "entry (branches must have one shape)", value)
            built = self.build(value)
            bits, degree = max(bits, built.bits), max(degree, built.degree)
            pairs.append((built.expr, self.condition(condition, k)))
        self.check_bounds(bits, degree, node)
        return _Built(sympy.Piecewise(*pairs), bits, degree)

    def condition(self, node: ast.AST, k: int) -> sympy.Basic:
        """A Piecewise condition: ``True``, or one comparison of two expressions."""
        if isinstance(node, ast.Constant) and node.value is True:
            return sympy.true
        if (isinstance(node, ast.Compare) and len(node.ops) == 1
                and type(node.ops[0]) in _RELATIONS):
            left, right = self.build(node.left), self.build(node.comparators[0])
            return _RELATIONS[type(node.ops[0])](left.expr, right.expr)
        raise self.fail(f"condition of branch {k} of Piecewise must be True or one "
                        "comparison <, <=, >, >= of two expressions", node)

    def check_bounds(self, bits: int, degree: int, node: ast.AST) -> None:
        if bits > MAX_NUMBER_BITS:
            raise self.fail(
                f"expression could build a number of about {bits} bits "
                f"(limit {MAX_NUMBER_BITS})",
                node,
            )
        if degree > MAX_DEGREE:
            raise self.fail(f"expression has degree {degree} (limit {MAX_DEGREE})", node)


_FLOAT_FUNCTIONS: Mapping[type, Callable[..., float]] = {
    sympy.exp: math.exp, sympy.log: math.log, sympy.sin: math.sin, sympy.cos: math.cos,
    sympy.tan: math.tan, sympy.asin: math.asin, sympy.acos: math.acos,
    sympy.atan: math.atan, sympy.atan2: math.atan2, sympy.sinh: math.sinh,
    sympy.cosh: math.cosh, sympy.tanh: math.tanh, sympy.Abs: abs,
}


def check_values(expr: sympy.Expr, values: Mapping[sympy.Symbol, sympy.Expr],
                 where: str = "") -> None:
    """Refuse parameter values that would make `expr` unbounded to evaluate, before sympy
    substitutes them (it evaluates ``10**k`` with ``k = 1e600`` exactly, without end).

    The parser bounds literal exponents; a parameter's value in an exponent gets the same
    bound (``dt**k`` with ``k = 1e8`` is refused like ``dt**100000000``), and every
    subexpression whose symbols all have values must be a finite real double
    (``exp(exp(exp(k)))`` with ``k = 1000`` is refused). Raises `ExpressionError`.
    """
    if values and expr.free_symbols & set(values):
        _ValueCheck(values, f"{where}: " if where else "").value(expr)


class _ValueCheck:
    """Double values of subexpressions (None where a symbol has no value), bottom-up."""

    def __init__(self, values: Mapping[sympy.Symbol, sympy.Expr], prefix: str) -> None:
        self.values = values
        self.prefix = prefix
        self.memo: dict[sympy.Basic, float | None] = {}

    def fail(self, node: sympy.Basic, message: str) -> ExpressionError:
        used = sorted((s for s in node.free_symbols if s in self.values), key=str)
        given = ", ".join(f"{s} = {_compact(self.values[s])}" for s in used)
        return ExpressionError(f"{self.prefix}with {given}, {_short(str(node))[1:-1]} "
                               f"{message}")

    def value(self, node: sympy.Basic) -> float | None:
        if node not in self.memo:
            self.memo[node] = self.compute(node)
        return self.memo[node]

    def compute(self, node: sympy.Basic) -> float | None:
        if node.is_Symbol:
            value = self.values.get(node)
            return None if value is None else _as_float(value)
        if node.is_Number or isinstance(node, sympy.NumberSymbol):
            return _as_float(node)
        arguments = [self.value(argument) for argument in node.args]
        if node.is_Pow:
            self.check_exponent(node)
        if any(argument is None for argument in arguments):
            return None
        try:
            if node.is_Add:
                result = math.fsum(arguments)
            elif node.is_Mul:
                result = math.prod(arguments)
            elif node.is_Pow:
                result = arguments[0] ** arguments[1]
            elif type(node) in _FLOAT_FUNCTIONS:
                result = _FLOAT_FUNCTIONS[type(node)](*arguments)
            else:
                return None
        except OverflowError:
            result = math.inf
        except (ValueError, ZeroDivisionError):
            raise self.fail(node, "is not a real number") from None
        if isinstance(result, complex):
            raise self.fail(node, "is not a real number")
        if not math.isfinite(result):
            raise self.fail(node, "is not finite as a double")
        return result

    def check_exponent(self, node: sympy.Pow) -> None:
        exponent = node.exp
        if not exponent.free_symbols & set(self.values):
            return
        exact = exponent.xreplace(self.values)  # the exponent's own powers are checked
        if exact.is_Rational and (abs(exact.p) > MAX_EXPONENT or exact.q > MAX_EXPONENT):
            raise self.fail(node, f"has the exponent {_compact(exact)}, "
                                  f"beyond the limit of {MAX_EXPONENT}")


def _as_float(number: sympy.Expr) -> float:
    try:
        return float(number)
    except OverflowError:
        return math.inf if number > 0 else -math.inf


def _compact(number: sympy.Expr) -> str:
    """A number's text, or its 6-digit approximation when the text is long."""
    text = str(number)
    if len(text) <= 24:
        return text
    magnitude = _as_float(number)
    return f"{magnitude:.6g}" if math.isfinite(magnitude) else f"a number of {len(text)} characters"
