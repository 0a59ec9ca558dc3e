"""The expression parser: allowed syntax gives the right sympy value, anything else is an
ExpressionError naming the construct and its position, within the resource limits."""

from fractions import Fraction

import pytest
import sympy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import expressions
from derive.errors import ExpressionError, ModelError, ModelFileError
from derive.expressions import exact_decimal, exact_number, parse_expression

x, y, dt, sq2 = (sympy.Symbol(n, real=True) for n in ("x", "y", "dt", "sq2"))
NAMES = {"x": x, "y": y, "dt": dt, "sq2": sq2}


def parse(text, **kw):
    return parse_expression(text, NAMES, **kw)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("1", sympy.Integer(1)),
        ("0.1", sympy.Rational(1, 10)),
        ("0.1*3 - 0.3", sympy.Integer(0)),
        ("2.5e-3", sympy.Rational(1, 400)),
        ("1_000.5e-3", sympy.Rational(2001, 2000)),
        (".5", sympy.Rational(1, 2)),
        ("2.", sympy.Integer(2)),
        ("0x1F", sympy.Integer(31)),
        ("dt/2", dt / 2),
        ("dt**3/3 * sq2", dt**3 * sq2 / 3),
        ("-x**2", -(x**2)),
        ("(-x)**2", x**2),
        ("+x - -y", x + y),
        ("2**-3", sympy.Rational(1, 8)),
        ("x**(1/2)", sympy.sqrt(x)),
        ("x**0.5", sympy.sqrt(x)),
        ("x**-(3/2)", x ** sympy.Rational(-3, 2)),
        ("x**dt", x**dt),
        ("x**-dt", x ** (-dt)),
        ("pi/2", sympy.pi / 2),
        ("sqrt((y - x)**2 + dt**2) + sq2", sympy.sqrt((y - x) ** 2 + dt**2) + sq2),
        ("atan2(y, x)", sympy.atan2(y, x)),
        ("abs(x) + exp(x) + log(dt) + sin(x) + cos(x) + tan(x)",
         sympy.Abs(x) + sympy.exp(x) + sympy.log(dt) + sympy.sin(x) + sympy.cos(x)
         + sympy.tan(x)),
        ("asin(x) * acos(x) * atan(x)", sympy.asin(x) * sympy.acos(x) * sympy.atan(x)),
        ("sinh(x) - cosh(x) + tanh(x)", sympy.sinh(x) - sympy.cosh(x) + sympy.tanh(x)),
        ("  dt + 1  ", dt + 1),
        ("(x\n + y)", x + y),
        ("x  # a comment", x),
        ("x**64", x**64),
        ("1e300 * 1e-300", sympy.Integer(1)),
        ("0e99999999 + x", x),
    ],
)
def test_allowed_expressions(text, expected):
    result = parse(text)
    assert result == expected
    assert not result.atoms(sympy.Float), "decimal literals must become exact rationals"


def test_new_symbols_only_when_allowed():
    k = parse("2*k", allow_new=True)
    assert k == 2 * sympy.Symbol("k", real=True)
    assert next(iter(k.free_symbols)).is_real
    with pytest.raises(ExpressionError, match=r"unknown symbol 'k'"):
        parse("2*k")


def test_unknown_symbol_suggests_close_match_and_lists_declared():
    with pytest.raises(ExpressionError) as info:
        parse("dtt/2", where="m.toml: [discrete] G[0][0]")
    message = str(info.value)
    assert message.startswith("m.toml: [discrete] G[0][0]: ")
    assert "unknown symbol 'dtt'" in message
    assert "did you mean 'dt'?" in message
    assert "declared: dt, sq2, x, y" in message


def test_error_class_hierarchy():
    assert issubclass(ExpressionError, ModelFileError)
    assert issubclass(ExpressionError, ModelError)


FORBIDDEN = [
    ("__import__('os')", ["call of '__import__'", "column 1"]),
    ("().__class__", ["attribute access", "column 1"]),
    ("x.y", ["attribute access", "line 1, column 1"]),
    ("x + y.real", ["attribute access", "column 5"]),
    ("a[0]", ["subscript", "column 1"]),
    ("x + a[1:2]", ["subscript", "column 5"]),
    ("lambda: 1", ["lambda", "column 1"]),
    ("[i for i in x]", ["list comprehension"]),
    ("{i for i in x}", ["set comprehension"]),
    ("(i for i in x)", ["generator expression"]),
    ("{i: 1 for i in x}", ["dict comprehension"]),
    ("'s'", ["string literal", "column 1"]),
    ("x + 's'", ["string literal", "column 5"]),
    ("b'x'", ["bytes literal"]),
    ("f'{x}'", ["f-string"]),
    ("x if y else dt", ["conditional expression"]),
    ("x < 1", ["comparison"]),
    ("x and y", ["boolean operator"]),
    ("not x", ["'not'"]),
    ("~x", ["'~'"]),
    ("(x := 1)", ["assignment expression", "column 2"]),
    ("x // 2", ["operator //"]),
    ("x % 2", ["operator %"]),
    ("x @ y", ["operator @"]),
    ("x << 2", ["operator <<"]),
    ("x | y", ["operator |"]),
    ("sqrt(x=1)", ["keyword argument 'x'", "column 6"]),
    ("sqrt(**{})", ["'**' argument"]),
    ("sqrt(*x)", ["starred argument", "column 6"]),
    ("foo(x)", ["call of 'foo'", "functions: abs, acos"]),
    ("x(1)", ["call of 'x'"]),
    ("[sqrt][0](x)", ["subscript"]),
    ("(x + 1)(2)", ["call of a computed value"]),
    ("__import__('os').system('true')", ["attribute access", "column 1"]),
    ("sqrt(x, y)", ["sqrt() takes 1 argument, got 2"]),
    ("atan2(x)", ["atan2() takes 2 arguments, got 1"]),
    ("sqrt", ["function 'sqrt' used without a call"]),
    ("_x", ["name '_x'", "underscore"]),
    ("x + __class__", ["name '__class__'", "column 5"]),
    ("True", ["boolean literal"]),
    ("None", ["literal None"]),
    ("1j", ["complex literal"]),
    ("...", ["literal Ellipsis"]),
    ("(1, 2)", ["tuple"]),
    ("[1]", ["list"]),
    ("{1}", ["set"]),
    ("{}", ["dict"]),
    ("1/0", ["zoo", "division by zero"]),
    ("log(0)", ["zoo"]),
    ("sqrt(-1)", ["not real"]),
    ("x**99999999", ["exponent 99999999 is too large", "column 4"]),
    ("x**(3/128)", ["exponent 3/128 is too large"]),
    ("x**(y + 1)", ["exponent must be a number, a small fraction p/q or a name"]),
    ("2**2**2", ["exponent must be"]),
    ("(2**64)**64", ["bits"]),
    ("((1e30**64))", ["bits"]),
    ("x**64 * x**64 * x**64 * x**64 * x", ["degree 257"]),
    ("1e999", ["numeric literal", "bits"]),
    ("1e-99999999", ["out of range"]),
    ("9" * 700, ["numeric literal", "bits"]),
    ("(" * 300 + "x" + ")" * 300, ["not a valid expression", "nested parentheses"]),
    ("-" * 100 + "x", ["nested more than 64 deep"]),
    ("+".join(["x"] * 600), ["more than 500 syntax nodes"]),
    ("x + " * 2500 + "x", ["10001 characters long", "limit of 2000"]),
    ("x" + "+(x" * 70 + ")" * 70, ["nested more than 64 deep"]),
    ("", ["empty expression"]),
    ("   ", ["empty expression"]),
    ("x +", ["not a valid expression", "line 1"]),
    ("import os", ["not a valid expression"]),
    ("x = 1", ["not a valid expression"]),
    ("x\n+ 1", ["not a valid expression", "line 2"]),
    ("x\0", ["not a valid expression"]),
    ("σ + 1", ["non-ASCII character 'σ'", "column 1"]),
    ("x + ﬁ", ["non-ASCII character", "column 5"]),
    ("(x\n + y.z)", ["attribute access", "line 2, column 4"]),
]


@pytest.mark.parametrize("text, words", FORBIDDEN, ids=[t[:30] for t, _ in FORBIDDEN])
def test_forbidden_constructs_are_named_with_their_position(text, words):
    with pytest.raises(ExpressionError) as info:
        parse(text, where="f.toml: [discrete] F[1][0]")
    message = str(info.value)
    assert message.startswith("f.toml: [discrete] F[1][0]: ")
    for word in words:
        assert word in message, (word, message)


def test_position_counts_stripped_leading_whitespace():
    with pytest.raises(ExpressionError, match="line 1, column 7"):
        parse("  x + y.z")
    with pytest.raises(ExpressionError, match="line 2, column 7"):
        parse("\n  x + y.z")


def test_non_string_text_and_non_sympy_names():
    with pytest.raises(ExpressionError, match="expected an expression string"):
        parse_expression(3, NAMES)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="names"):
        parse_expression("x", {"x": "__import__('os')"})  # type: ignore[dict-item]


def test_limits_are_stated_as_constants():
    assert expressions.MAX_TEXT_LENGTH == 2000
    assert expressions.MAX_DEPTH == 64
    assert expressions.MAX_EXPONENT == 64
    # Just inside each limit is accepted, just outside is not.
    assert parse("x**64") == x**64
    with pytest.raises(ExpressionError, match="too large"):
        parse("x**65")
    assert parse("-" * 63 + "x") == -x  # 63 unary minuses and the name: depth 64
    with pytest.raises(ExpressionError, match="nested"):
        parse("-" * 64 + "x")
    assert parse("x" + " " * 1999) == x
    assert parse(" + ".join(["x"] * 250)) == 250 * x  # a long chain is not deep
    with pytest.raises(ExpressionError, match="characters long"):
        parse("x" + " " * 2000)


def test_exact_numbers():
    assert exact_number(0.1) == sympy.Rational(1, 10)
    assert exact_number(3) == 3
    assert exact_number(Fraction(2, 3)) == sympy.Rational(2, 3)
    assert exact_decimal("-0.01") == sympy.Rational(-1, 100)
    assert exact_decimal("+1.5E+2") == 150
    assert exact_decimal("0.0e-99999999") == 0
    for bad in (True, "1", None):
        with pytest.raises(ExpressionError, match="expected a number"):
            exact_number(bad)  # type: ignore[arg-type]
    for bad in ("inf", "-nan", "1e-99999999", "", "1.2.3"):
        with pytest.raises(ExpressionError, match="where: number"):
            exact_decimal(bad, where="where")
    with pytest.raises(ExpressionError, match="not a finite"):
        exact_number(float("inf"))
    with pytest.raises(ExpressionError, match="bits"):
        exact_number(2**5000)


# -- generated expressions: the parser agrees with sympy built directly ------------------

def _leaf():
    names = st.sampled_from(sorted(NAMES)).map(lambda n: (n, NAMES[n]))
    ints = st.integers(0, 10**6).map(lambda i: (str(i), sympy.Integer(i)))
    decimals = st.fractions(min_value=0, max_value=1000, max_denominator=1000).map(
        lambda f: (str(f.numerator), sympy.Rational(f.numerator, 1)) if f.denominator == 1
        else (f"({f.numerator}/{f.denominator})", sympy.Rational(f.numerator, f.denominator)))
    literal = st.decimals(min_value=0, max_value=10**6, places=4, allow_nan=False).map(
        lambda d: (str(d), sympy.Rational(str(d))))
    return names | ints | decimals | literal


def _combine(children):
    binary = st.tuples(children, st.sampled_from("+-*/"), children).map(
        lambda t: (f"({t[0][0]}) {t[1]} ({t[2][0]})",
                   {"+": sympy.Add, "-": lambda a, b: a - b, "*": sympy.Mul,
                    "/": lambda a, b: a / b}[t[1]](t[0][1], t[2][1])))
    power = st.tuples(children, st.integers(-4, 4)).map(
        lambda t: (f"({t[0][0]})**({t[1]})", t[0][1] ** t[1]))
    negate = children.map(lambda c: (f"-({c[0]})", -c[1]))
    call = st.tuples(st.sampled_from(["sin", "exp", "atan", "abs"]), children).map(
        lambda t: (f"{t[0]}({t[1][0]})", expressions.FUNCTIONS[t[0]][0](t[1][1])))
    return binary | power | negate | call


GENERATED = st.recursive(_leaf(), _combine, max_leaves=12)


@settings(max_examples=300, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(GENERATED)
def test_generated_expressions_match_direct_sympy(pair):
    text, expected = pair
    if expected.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo, sympy.I):
        with pytest.raises(ExpressionError):
            parse(text)
    else:
        assert parse(text) == expected


# -- fuzz: anything is an ExpressionError or a sympy expression, quickly -----------------

VALID = [
    "dt/2", "sqrt((x - y)**2 + dt**2) + sq2", "dt**3/3*sq2", "atan2(y, x) * pi",
    "-(x**-2) + 0.25e1", "exp(-dt) * cos(x)**2", "x**(1/2) + abs(y)",
]
ALPHABET = "xydtsq2_0123456789.eE+-*/%()[]{},:;'\"\\ \n#@!?<>=&|^~`abcfilmnoprwz"


def _check_only_expression_errors(text):
    try:
        result = parse_expression(text, NAMES)
    except ExpressionError:
        return
    assert isinstance(result, sympy.Expr)


@settings(max_examples=1000, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(alphabet=ALPHABET, max_size=120) | st.text(max_size=60))
def test_fuzz_random_text(text):
    _check_only_expression_errors(text)


@st.composite
def _mutated(draw):
    text = draw(st.sampled_from(VALID))
    for _ in range(draw(st.integers(1, 4))):
        position = draw(st.integers(0, len(text)))
        action = draw(st.sampled_from(["insert", "delete", "replace", "repeat"]))
        piece = draw(st.text(alphabet=ALPHABET, min_size=1, max_size=4)
                     | st.sampled_from(["**64", "**", ".__class__", "[0]", "(", ")", "1e308",
                                        "lambda:", "_", "sqrt(", "9" * 40, "**(1/3)"]))
        if action == "insert":
            text = text[:position] + piece + text[position:]
        elif action == "delete":
            text = text[:position] + text[position + len(piece):]
        elif action == "replace":
            text = text[:position] + piece + text[position + len(piece):]
        else:
            text = text[:position] + text[position:] * draw(st.integers(2, 40))
    return text


@settings(max_examples=1000, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(_mutated())
def test_fuzz_mutated_expressions(text):
    _check_only_expression_errors(text)
