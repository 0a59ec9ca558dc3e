"""Print lowered trees and programs as C99.

Arithmetic is plain ``+ - * /``; ``sqrt`` and math.h calls by name; an fma is
``DERIVE_FMA(a, b, c)``, a macro each file defines (:data:`FMA_MACRO_LINES`):
the hardware ``fma()`` where ``FP_FAST_FMA`` says it is fast (e.g. with
``-march=native``), else ``((a) * (b) + (c))``, so baseline x86-64 code needs no
libm beyond sqrt; a fused negative multiply-add ``c - a*b`` is ``DERIVE_FNMA(a, b, c)``,
``fma((a), -(b), (c))`` or ``((c) - (a) * (b))`` alike.  A select (the missing-measurement
test) is
``((z[i] == z[i]) ? a : b)``, false only for NaN, so such code must not be compiled
with ``-ffast-math`` (which assumes there is no NaN); a guard (:mod:`derive.guards`) is
``((l > r) ? a : b)`` or ``((l >= r) ? a : b)`` of two values computed before it, which
compilers turn into a compare and a blend (no branch).  Constants are printed with
``repr`` (shortest round trip, always with a ``.`` or an exponent, so C reads a double).

Every function takes the :class:`~derive.precision.Precision` of the file (default
double): in float code the element type is ``float``, a constant is the float nearest
the double (shortest round trip, ``f`` suffix), math.h functions are the ``f`` ones
(``sqrtf``, ``sinf``) and ``DERIVE_FMA`` is ``fmaf`` where ``FP_FAST_FMAF`` says it is fast,
so that the code is clean under ``-Wdouble-promotion -Wfloat-conversion``.
"""

from __future__ import annotations

from collections.abc import Callable

from derive.emit.c_vector import CLOSE, ELSE, ChunkPrinter, vector_macro_lines
from derive.emit.python_printer import InfixPrinter
from derive.lowering import LoweredAssign, LoweredCheck, LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.trees import FUSED_KINDS, Tree

FMA_NAME = "DERIVE_FMA"
#: Defined where the file's own DERIVE_FMA is the hardware fma (one rounding), and where it
#: is a product and a sum (two): a vector path (derive.emit.c_lanes) fuses exactly when
#: the scalar one does; neither is defined where the build defines DERIVE_FMA itself.
FMA_FUSED = "DERIVE_FMA_FUSED"
FMA_PLAIN = "DERIVE_FMA_PLAIN"


FNMA_NAME = "DERIVE_FNMA"


def fma_macro_lines(precision: Precision = DOUBLE) -> list[str]:
    """The ``.c`` file's definitions of ``DERIVE_FMA`` and ``DERIVE_FNMA``: the hardware
    ``fma`` (``fmaf``) where ``FP_FAST_FMA`` (``FP_FAST_FMAF``) says it is fast, else
    ``((a) * (b) + (c))``; ``DERIVE_FNMA(a, b, c)`` (``c - a*b``) is that fma with the
    product's sign folded, ``DERIVE_FMA((a), -(b), (c))`` (one rounding, as a negative
    multiply-add instruction), and ``((c) - (a) * (b))`` in the plain build, which rounds as
    a product and a subtraction (a build that defines DERIVE_FMA itself gets the former).

    The sign goes on the second factor: the lowering orders a product's factors as sympy
    does, input elements before temporaries, so in the rows of an update
    (``DERIVE_FNMA(P[9], t3, P[0])``, ``DERIVE_FNMA(P[25], t3, P[1])``, ...) the negated
    factor is the one the statements share, negated once, and GCC's SLP vectoriser keeps
    the rows (the INS/GNSS baro update with ``-O3 -march=native``: 94 ns per call, against
    105 ns with the first factor negated and 87 ns for the unfused product and
    subtraction)."""
    return ["#ifndef DERIVE_FMA",
            f"#if defined({precision.fast_fma})",
            f"#define DERIVE_FMA(a, b, c) {precision.math('fma')}((a), (b), (c))",
            f"#define {FMA_FUSED} 1",
            "#else",
            "#define DERIVE_FMA(a, b, c) ((a) * (b) + (c))",
            f"#define {FMA_PLAIN} 1",
            "#endif",
            "#endif",
            f"#ifndef {FNMA_NAME}",
            f"#if defined({FMA_PLAIN})",
            f"#define {FNMA_NAME}(a, b, c) ((c) - (a) * (b))",
            "#else",
            f"#define {FNMA_NAME}(a, b, c) DERIVE_FMA((a), -(b), (c))",
            "#endif",
            "#endif"]


FMA_MACRO_LINES = fma_macro_lines()


def macro_lines(lowered: list[LoweredProgram], precision: Precision = DOUBLE) -> list[str]:
    """The ``.c`` file's macros for ``lowered``: :func:`fma_macro_lines` when a program
    fuses, then :func:`~derive.emit.c_vector.vector_macro_lines` when one has vector rows."""
    fused = any(lp.kinds() & FUSED_KINDS for lp in lowered)
    rows = any(lp.rows for lp in lowered)
    return ((fma_macro_lines(precision) if fused else [])
            + (vector_macro_lines(precision, fused=fused) if rows else []))


class CPrinter(InfixPrinter):
    """C99 spelling in one precision (double by default)."""

    def __init__(self, names=None, precision: Precision = DOUBLE) -> None:
        super().__init__(names)
        self.precision = precision

    def const(self, value: float) -> str:
        text = self.precision.literal(value)
        return f"({text})" if text.startswith("-") else text

    def call(self, kind: str, args: list[str]) -> str:
        if kind == "sqrt":
            return f"{self.precision.math('sqrt')}({args[0]})"
        if kind == "fma":
            return f"{FMA_NAME}({', '.join(args)})"
        if kind == "fnma":
            return f"{FNMA_NAME}({', '.join(args)})"
        if kind == "select":
            z, a, b = args
            return f"(({z} == {z}) ? {a} : {b})"
        if kind == "gate":
            v, bound, a, b = args
            return f"(({v} <= {bound}) ? {a} : {b})"
        if kind in ("if_gt", "if_ge"):
            left, right, a, b = args
            return f"(({left} {'>' if kind == 'if_gt' else '>='} {right}) ? {a} : {b})"
        if kind.startswith("call:"):
            return f"{self.precision.math(kind[5:])}({', '.join(args)})"
        raise ValueError(f"no C spelling for operation {kind!r}")


def expression(tree: Tree, precision: Precision = DOUBLE) -> str:
    """C text of one lowered tree."""
    return CPrinter(precision=precision).expression(tree)


def comment_text(text: str) -> str:
    """``text`` made safe inside a C block comment (ASCII, no ``*/``)."""
    safe = text.encode("ascii", "replace").decode("ascii")
    return safe.replace("*/", "* /").replace("/*", "/ *")


def needs_math_h(lowered: list[LoweredProgram]) -> bool:
    """True when sqrt, fma or a math.h call is printed."""
    for lp in lowered:
        for kind in lp.kinds():
            if kind in ("sqrt", "fma", "fnma") or kind.startswith("call:"):
                return True
    return False


def parameters(lowered: LoweredProgram, restrict: str = "restrict",
               precision: Precision = DOUBLE) -> list[str]:
    """C parameters: the inputs except ``p``, the outputs, then ``p``; ``restrict``: how
    the pointers are qualified (a header spells it with :func:`restrict_macro`)."""
    real = precision.c_type
    inputs = [p for p in lowered.inputs if p.name != PARAMETER_PORT]
    params = [f"const {real} *{restrict} {p.name}" for p in inputs]
    params += [f"{real} *{restrict} {p.name}" for p in lowered.outputs]
    params += [f"const {real} *{restrict} {p.name}" for p in lowered.inputs
               if p.name == PARAMETER_PORT]
    return params


RESTRICT_NAME = "DERIVE_RESTRICT"


def restrict_macro(symbol_prefix: str = "") -> str:
    """The name a header spells ``restrict`` with: ``PREFIX`` DERIVE_RESTRICT."""
    return f"{symbol_prefix}{RESTRICT_NAME}"


def restrict_lines(symbol_prefix: str = "") -> list[str]:
    """The header's definition of :func:`restrict_macro`, so that it is includable from C
    and C++: ``restrict`` in C99 and later, ``__restrict__`` in GCC and Clang C++,
    ``__restrict`` in MSVC C++, nothing otherwise; guarded, so that every header of one
    prefix may define it (the definitions are identical)."""
    name = restrict_macro(symbol_prefix)
    return [f"#ifndef {name}",
            "#if defined(__cplusplus)",
            "#if defined(__GNUC__) || defined(__clang__)",
            f"#define {name} __restrict__",
            "#elif defined(_MSC_VER)",
            f"#define {name} __restrict",
            "#else",
            f"#define {name}",
            "#endif",
            "#elif defined(__STDC_VERSION__) && __STDC_VERSION__ >= 199901L",
            f"#define {name} restrict",
            "#else",
            f"#define {name}",
            "#endif",
            "#endif"]


def argument_order(lowered: LoweredProgram) -> list[str]:
    """Port names in C parameter order."""
    return [p.split()[-1] for p in parameters(lowered)]


def prototype(lowered: LoweredProgram, prefix: str, restrict: str = "restrict",
              precision: Precision = DOUBLE) -> str:
    """``int|void PREFIX_NAME(...)`` (no semicolon); int when the program has checks."""
    result = "int" if lowered.has_checks else "void"
    params = parameters(lowered, restrict, precision)
    return f"{result} {prefix}_{lowered.name}({', '.join(params)})"


def pattern_check_lines(check: LoweredCheck, element: str | None = None,
                        precision: Precision = DOUBLE) -> list[str]:
    """``if (!(P[k] == 0.0)) return STATUS;`` for one zero check; ``element``: the C text
    to test instead of the checked input element (run tests P0)."""
    name = check.tree.args[0].name
    value = element or name
    return [f"if (!({value} == {precision.zero()})) {{",
            f"    return {check.status}; /* outside P's pattern */",
            "}"]


#: ``FAIL(status, code, passes)`` sets ``status`` to ``code`` when it is 0 and ``passes`` is
#: false, with no branch (``(status) |= (!(passes) & !(status)) * (code)``): GCC 12
#: vectorises a loop over lanes around such checks for AVX2 (``-march=znver3``,
#: ``x86-64-v3``) as for AVX-512, where ``if (!(passes) && !status) status = code;`` it
#: vectorises only with AVX-512's masked stores. The C text counts it as the comparisons
#: of ``passes`` (derive.flops), as the ``if`` it replaces. Defined by :data:`FAIL_LINES`.
FAIL = "DERIVE_FAIL"
FAIL_LINES = [
    f"#ifndef {FAIL}",
    f"#define {FAIL}(status, code, passes) ((status) |= (!(passes) & !(status)) * (code))",
    "#endif",
]


def presence_lines(checks: list[LoweredCheck], printer: CPrinter,
                   status: str | None = None) -> list[str]:
    """One test of the presence checks of a program (they share one status): the
    comparisons joined by ``&`` (no branch between them, so a loop over tracks around them
    is still vectorised), then the status returned, or set in ``status`` when it is 0."""
    test = " & ".join(f"({c.passes(printer.expression(c.tree.args[0]))})" for c in checks)
    comment = f"/* {comment_text(checks[0].message)} */"
    if status is not None:
        return [f"{FAIL}({status}, {checks[0].status}, {test}); {comment}"]
    return [f"if (!({test})) {{", f"    return {checks[0].status}; {comment}", "}"]


def function_parts(lowered: LoweredProgram, prefix: str,
                   precision: Precision = DOUBLE) -> dict:
    """Precomputed strings of one function: ``signature`` and ``body`` lines (unindented)."""
    used = lowered.used_inputs()
    body = [f"(void){p.name};" for p in lowered.inputs if p.name not in used]
    body += statements(lowered, precision)
    if lowered.has_checks:
        body.append("return 0;")
    return {"signature": prototype(lowered, prefix, precision=precision), "body": body}


def statements(lowered: LoweredProgram, precision: Precision = DOUBLE,
               element: Callable[[str, int], str] | None = None,
               status: str | None = None) -> list[str]:
    """The program's statements (unindented) in ``precision``: its temporaries and checks,
    then its results written to the output arrays; no declarations, no final ``return 0``.

    ``element(port, index)``: the C text of an element of a port (default ``x[3]``);
    ``status``: the name of an int a failed check sets, when it is still 0, instead of
    returning, through :data:`FAIL` (the statements then run to the end and no branch is
    in them, so a loop over tracks around them is vectorised, with AVX2 as with AVX-512's
    masked stores); pattern checks always return."""
    printer = CPrinter(None if element is None else
                       lambda v: v.name if v.index is None else element(v.base, v.index),
                       precision=precision)
    body: list[str] = []
    place = element or (lambda name, k: f"{name}[{k}]")
    chunks = {chunk.targets[0]: chunk for chunk in lowered.rows}
    vectors = ChunkPrinter(printer, precision, lowered) if chunks else None
    statements = list(lowered.body)
    at = 0
    while at < len(statements):
        st = statements[at]
        at += 1
        if isinstance(st, LoweredCheck) and st.is_presence:  # a program's share one status
            group = [st]
            while (at < len(statements) and isinstance(statements[at], LoweredCheck)
                   and statements[at].is_presence):
                group.append(statements[at])
                at += 1
            body += presence_lines(group, printer, status)
            continue
        chunk = chunks.get(st.target) if isinstance(st, LoweredAssign) else None
        if chunk is not None:
            lanes = statements[at - 1:at - 1 + len(chunk.targets)]
            at += len(chunk.targets) - 1
            scalar = [f"const {precision.c_type} {lane.target} = "
                      f"{printer.expression(lane.tree)};" for lane in lanes
                      if lane.target in vectors.scalar_live]
            body += vectors.lines(chunk, scalar, place)
        elif isinstance(st, LoweredAssign):
            body.append(f"const {precision.c_type} {st.target} = "
                        f"{printer.expression(st.tree)};")
        elif st.is_pattern:
            body += pattern_check_lines(st, precision=precision)
        elif status is not None:
            value = printer.expression(st.tree.args[0])
            body.append(f"{FAIL}({status}, {st.status}, {st.passes(value, precision.zero())});"
                        f" /* {comment_text(st.message)} */")
        else:
            value = printer.expression(st.tree.args[0])
            body += [f"if (!({st.passes(value, precision.zero())})) {{",
                     f"    return {st.status}; /* {comment_text(st.message)} */",
                     "}"]
    early = set() if vectors is None else vectors.scalar_early
    scalar = [f"{place(name, k)} = {printer.expression(leaf)};"
              for name, leaves in lowered.results for k, leaf in enumerate(leaves)
              if (name, k) not in early]
    if vectors is None:
        return body + scalar
    # a scalar statement only chunks' vectors read (their lanes, in the scalar form, are
    # left out where nothing reads them) is unused in the scalar form
    only_vector = [f"(void){st.target};" for st in lowered.body
                   if isinstance(st, LoweredAssign) and st.target not in vectors.order
                   and st.target not in vectors.scalar_live]
    return body + vectors.store_lines(place) + [ELSE] + only_vector + scalar + [CLOSE]
