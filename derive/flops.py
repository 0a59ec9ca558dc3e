"""Exact operation counts of generated code, and two independent ways to check them.

:func:`count` counts the lowered trees of an optimised program
(:mod:`derive.lowering`), i.e. exactly what the printers print.  Two checks
that do not trust the lowering:

- :class:`CountingFloat`: a float whose arithmetic increments counters; running
  a generated Python function on CountingFloat inputs must reproduce
  ``count(program, "python")``;
- :func:`count_c_text` / :func:`count_c_function`: tokenise emitted C and count
  its operators; must reproduce ``count(program, "c")``.

``flops`` = add + sub + mul + div + sqrt + 2 fma (negations and comparisons
and selects are reported, not counted as flops); ``instructions`` = every operation.  ``fma`` counts
both fused multiply-adds of the C lowering, ``a*b + c`` (``DERIVE_FMA``) and ``c - a*b``
(``DERIVE_FNMA``, :data:`derive.trees.FUSED_KINDS`): one instruction, two flops each.  A
``select`` (:class:`derive.expression_lowering.IfPresent`, the missing-measurement test), a
``gate`` and a guard's ``if_gt``/``if_ge`` (:mod:`derive.guards`) are one comparison each
(``z == z``, ``v <= bound``, ``l > r``, ``l >= r``), counted as ``cmp``, and one select of
two computed values, counted as ``select``.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import fields, replace
from typing import TYPE_CHECKING

from derive.lowering import lower_program
from derive.rows import VECTOR_LANES, VECTOR_TYPES
from derive.trees import OpCount, count_trees

#: The C vector types of generated code and their lanes.
_VECTOR_LANES = dict.fromkeys(VECTOR_TYPES.values(), VECTOR_LANES)

if TYPE_CHECKING:
    from derive.lowering import LoweredProgram
    from derive.program import Program

#: The languages derive prints, each with its rules of counting here.
LANGUAGES = ("python", "c")


def count_lowered(lowered: LoweredProgram) -> OpCount:
    """Operations of a lowered program (the results are atoms and cost nothing)."""
    return count_trees([*(statement.tree for statement in lowered.body),
                        *(leaf for _, leaves in lowered.results for leaf in leaves)])


def count(program: Program, lang: str = "python", *, use_fma: bool | None = None) -> OpCount:
    """Exact operations of ``program.optimize()`` as printed in ``lang`` ("python" or "c").

    C uses fma unless ``use_fma=False``; Python never does.
    """
    if lang not in LANGUAGES:
        raise ValueError(f"unknown language {lang!r}; expected one of {LANGUAGES}")
    if use_fma is None:
        use_fma = lang == "c"
    if use_fma and lang == "python":
        raise ValueError("Python code has no fma: count(program, 'python', use_fma=False)")
    return count_lowered(lower_program(program, use_fma=use_fma))


# -- the dynamic proof -----------------------------------------------------------------


class OpCounter:
    """Mutable tallies shared by the CountingFloats of one run."""

    def __init__(self) -> None:
        self.tally = {f.name: 0 for f in fields(OpCount)}

    def bump(self, kind: str) -> None:
        self.tally[kind] += 1

    def snapshot(self) -> OpCount:
        """The counts so far."""
        return OpCount(**self.tally)

    def wrap(self, values) -> list[CountingFloat]:
        """CountingFloats for a flat sequence of numbers."""
        return [CountingFloat(float(v), self) for v in values]


class CountingFloat:
    """A float whose + - * / unary minus, ``** 0.5`` and comparisons are counted.

    Arithmetic with plain numbers (constants in generated code) is counted too;
    the result is again a CountingFloat on the same counter.  ``==`` and ``!=``
    count as comparisons as well (``z == z`` is the NaN test of a select), so a
    CountingFloat is not hashable.
    """

    __slots__ = ("value", "counter")
    __hash__ = None  # type: ignore[assignment]

    def __init__(self, value: float, counter: OpCounter) -> None:
        self.value = float(value)
        self.counter = counter

    def _other(self, other) -> float | None:
        if isinstance(other, CountingFloat):
            return other.value
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return float(other)
        return None

    def _result(self, kind: str, value: float) -> CountingFloat:
        self.counter.bump(kind)
        return CountingFloat(value, self.counter)

    def __add__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("add", self.value + o)

    def __radd__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("add", o + self.value)

    def __sub__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("sub", self.value - o)

    def __rsub__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("sub", o - self.value)

    def __mul__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("mul", self.value * o)

    def __rmul__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("mul", o * self.value)

    def __truediv__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("div", self.value / o)

    def __rtruediv__(self, other):
        o = self._other(other)
        return NotImplemented if o is None else self._result("div", o / self.value)

    def __neg__(self):
        return self._result("neg", -self.value)

    def __pos__(self):
        return self

    def __pow__(self, exponent):
        if exponent != 0.5:
            raise TypeError(f"CountingFloat supports ** 0.5 (sqrt) only, not ** {exponent!r}")
        return self._result("sqrt", self.value ** 0.5)

    def _compare(self, other, op) -> bool:
        o = self._other(other)
        if o is None:
            return NotImplemented
        self.counter.bump("cmp")
        return op(self.value, o)

    def __gt__(self, other):
        return self._compare(other, float.__gt__)

    def __ge__(self, other):
        return self._compare(other, float.__ge__)

    def __lt__(self, other):
        return self._compare(other, float.__lt__)

    def __le__(self, other):
        return self._compare(other, float.__le__)

    def __eq__(self, other):
        return self._compare(other, float.__eq__)

    def __ne__(self, other):
        return self._compare(other, float.__ne__)

    def __abs__(self):
        return self._result("calls", abs(self.value))

    def __float__(self) -> float:
        return self.value

    def derive_selected(self, value) -> CountingFloat:
        """``value`` chosen by a select (generated ``_if_present``, ``_if_at_most``,
        ``_if_greater``, ``_if_at_least``): counts one ``select`` and returns ``value`` as a
        CountingFloat on this counter (itself if it is one), so that a select that picks a
        constant keeps what follows counted."""
        self.counter.bump("select")
        if isinstance(value, CountingFloat):
            return value
        return CountingFloat(value, self.counter)

    def __repr__(self) -> str:
        return f"CountingFloat({self.value!r})"

    def _call(self, fn) -> CountingFloat:
        return self._result("calls", fn(self.value))

    # NumPy ufuncs on objects call these methods (np.sin(obj) -> obj.sin()).
    def sin(self):
        return self._call(math.sin)

    def cos(self):
        return self._call(math.cos)

    def tan(self):
        return self._call(math.tan)

    def exp(self):
        return self._call(math.exp)

    def log(self):
        return self._call(math.log)

    def arctan(self):
        return self._call(math.atan)

    def arctan2(self, other):
        return self._result("calls", math.atan2(self.value, float(other)))

    def ceil(self):
        return self._call(math.ceil)

    __ceil__ = ceil  # NumPy's ceil of an object calls math.ceil


# -- counting emitted C ----------------------------------------------------------------

_TOKEN = re.compile(
    r"\s*(?:(?P<number>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)"
    r"|(?P<name>[A-Za-z_]\w*)"
    r"|(?P<op>>=|<=|==|!=|&&|\|\||\+\+|--|->|[-+*/%()\[\]{},;=!<>?:&|.~^]))"
)
_COMPARISONS = {">", "<", ">=", "<=", "==", "!="}
_UNARY_BEFORE = {"(", "[", ",", "=", "return", "?", ":", "{", "}", ";", "!",
                 "+", "-", "*", "/", "<", ">", "<=", ">=", "==", "!=", "&&", "||"}


def _tokens(text: str) -> list[tuple[str, str]]:
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    text = re.sub(r"//[^\n]*", " ", text)
    text = re.sub(r"^\s*#[^\n]*", " ", text, flags=re.M)
    out = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            if text[pos:].strip() == "":
                break
            raise ValueError(f"cannot tokenise C text at: {text[pos:pos + 40]!r}")
        pos = m.end()
        kind = m.lastgroup
        out.append((kind, m.group(kind)))
    return out


#: A chunk of vector rows in generated C (derive.emit.c_vector): the vector form, then the
#: scalar lanes.
_CHUNK = re.compile(r"^[ \t]*#if DERIVE_VECTOR[ \t]*\n(.*?)^[ \t]*#else[ \t]*\n(.*?)"
                    r"^[ \t]*#endif[ \t]*$", re.M | re.S)
_VECTOR_STATEMENT = re.compile(r"const (\w+) \w+ = (.*?);\s*$", re.S)


def count_c_text(text: str, fma_name: str = "DERIVE_FMA",
                 fnma_name: str = "DERIVE_FNMA", *, vector: bool = True) -> OpCount:
    """Count the arithmetic in C statements by their operators.

    ``+ - * /`` binary; unary minus is ``neg`` unless it is the sign of a numeric
    literal; ``fma_name(`` and ``fnma_name(`` are an fma each (the negative one is
    ``c - a*b``, as :class:`OpCount` counts it), ``sqrt(`` a sqrt, other ``name(`` calls
    (except ``if``, ``return``, ``sizeof``, ``for``/``while`` and ``DERIVE_FAIL``, a failed
    check's branch-free status, derive.emit.c_printer) are calls;
    ``> < >= <= == !=`` are comparisons, ``?`` a select.

    A chunk of vector rows (``#if DERIVE_VECTOR`` ... ``#else`` ... ``#endif``) counts as
    its vector statement once per lane (``DERIVE_VFMA`` an fma), with ``vector``; as its
    scalar lanes without.
    """
    extra = OpCount()
    if "DERIVE_VECTOR" in text:
        def chunk(m: re.Match) -> str:
            nonlocal extra
            if not vector:
                return m.group(2)
            for line in m.group(1).split(";"):
                found = _VECTOR_STATEMENT.match(line.strip() + ";")
                if found is not None and found.group(1) in _VECTOR_LANES:
                    ops = count_c_text(found.group(2), "DERIVE_VFMA", "DERIVE_VFNMA")
                    extra = extra + ops.scaled(_VECTOR_LANES[found.group(1)])
            return ""
        text = _CHUNK.sub(chunk, text)
    return extra + _count_tokens(text, fma_name, fnma_name)


def _count_tokens(text: str, fma_name: str, fnma_name: str) -> OpCount:
    tokens = _tokens(text)
    tally = dict.fromkeys((f.name for f in fields(OpCount)), 0)
    prev: str | None = None
    depth = 0  # inside [...]: an element's address, not arithmetic of the program
    for k, (kind, tok) in enumerate(tokens):
        nxt = tokens[k + 1] if k + 1 < len(tokens) else (None, None)
        if kind == "name" and nxt[1] == "(":
            if tok in (fma_name, fnma_name):
                tally["fma"] += 1
            elif tok == "sqrt":
                tally["sqrt"] += 1
            elif tok not in ("if", "return", "sizeof", "for", "while", "switch", "void",
                             "__builtin_shufflevector", "DERIVE_FAIL"):
                tally["calls"] += 1
        elif kind == "op" and not depth:
            unary = prev is None or prev in _UNARY_BEFORE
            if tok == "-":
                if not unary:
                    tally["sub"] += 1
                elif nxt[0] != "number":
                    tally["neg"] += 1
            elif tok == "+" and not unary:
                tally["add"] += 1
            elif tok == "*" and not unary:
                tally["mul"] += 1
            elif tok == "/":
                tally["div"] += 1
            elif tok in _COMPARISONS:
                tally["cmp"] += 1
            elif tok == "?":
                tally["select"] += 1
        if tok == "[":
            depth += 1
        elif tok == "]":
            depth -= 1
        prev = tok
    return OpCount(**tally)


def c_function_body(source: str, function_name: str) -> str:
    """The text between the braces of the definition of ``function_name`` in C source
    (comments removed).  Each definition is looked up once per source
    (:func:`_c_definitions`): a whole-catalog check asks for thousands."""
    bodies = _c_definitions(source)
    if function_name not in bodies:
        bodies[function_name] = _find_body(_without_comments(source), function_name)
    body = bodies[function_name]
    if body is None:
        raise ValueError(f"no definition of {function_name!r} in the C source")
    return body


@functools.lru_cache(maxsize=8)
def _without_comments(source: str) -> str:
    return re.sub(r"/\*.*?\*/", " ", source, flags=re.S)


@functools.lru_cache(maxsize=8)
def _c_definitions(source: str) -> dict[str, str | None]:
    """The bodies of ``source``'s functions found so far (None: no definition)."""
    return {}


_PARENS, _BRACES, _SPACE = re.compile(r"[()]"), re.compile(r"[{}]"), re.compile(r"\s*")


def _closing(pattern: re.Pattern, text: str, pos: int) -> int:
    """The position after the bracket closing the one just before ``pos`` (the end of
    ``text`` if it is never closed)."""
    depth = 1
    for m in pattern.finditer(text, pos):
        depth += 1 if m.group() in "({" else -1
        if not depth:
            return m.end()
    return len(text)


def _find_body(text: str, function_name: str) -> str | None:
    """The body of the first ``function_name(...)`` in ``text`` followed by a brace."""
    for m in re.finditer(rf"\b{re.escape(function_name)}\s*\(", text):
        pos = _SPACE.match(text, _closing(_PARENS, text, m.end())).end()
        if text.startswith("{", pos):
            end = _closing(_BRACES, text, pos + 1)
            return text[pos + 1:end - 1]
    return None


def count_c_function(source: str, function_name: str) -> OpCount:
    """:func:`count_c_text` of the body of one function in C source, a call of a function
    the source defines counted as that function's operations (:func:`count_c_calls`)."""
    return count_c_calls(source, c_function_body(source, function_name))


def count_c_calls(source: str, text: str) -> OpCount:
    """:func:`count_c_text` of ``text``, where a call of a function that ``source`` defines
    counts as that function's operations, not as a call (a generated step, run's loop and
    run_tracks call the step body: the step's statements printed once in the file)."""
    total = count_c_text(text)
    called = re.findall(r"\b([A-Za-z_]\w*)\s*\(", re.sub(r"/\*.*?\*/", " ", text, flags=re.S))
    for name in called:
        if name in _C_WORDS:
            continue
        try:
            body = c_function_body(source, name)
        except ValueError:  # not defined here: a math.h call, a macro
            continue
        total = total + count_c_calls(source, body)
        total = replace(total, calls=total.calls - 1)
    return total


_C_WORDS = ("if", "return", "sizeof", "for", "while", "switch", "void", "sqrt", "DERIVE_FMA",
            "DERIVE_FNMA", "DERIVE_FAIL")
