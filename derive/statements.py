"""The statements of a straight-line program, and the symbols they read and write.

The lowest layer of the program core (:mod:`derive.program` builds programs from
these, :mod:`derive.optimise` rewrites their bodies, :mod:`derive.lowering` lowers
them): input elements (``P[3]``, how generated code reads an input), temporaries
(``t0``), assignments ``tK = expr`` and runtime checks.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import sympy
from sympy.core.basic import _args_sortkey
from sympy.core.function import AppliedUndef

from derive.monomials import product_of, sum_of


class InputElement(sympy.Symbol):
    """One element of an input port; its name is how generated code reads it (``P[3]``)."""


class Temporary(sympy.Symbol):
    """A temporary of a program (``t0``, ``t1``, ... once optimised)."""



@dataclass(frozen=True)
class Assign:
    """``target = expr``."""

    target: Temporary
    expr: sympy.Expr


#: The relations a runtime check can require of its value (PRESENT: not NaN, an input
#: element compared with itself).
POSITIVE, ZERO, NONNEGATIVE, PRESENT = "positive", "zero", "nonnegative", "present"
#: How generated code compares a checked value with 0 (with itself for PRESENT), per
#: relation.
OPERATORS = {POSITIVE: ">", ZERO: "==", NONNEGATIVE: ">=", PRESENT: "=="}


@dataclass(frozen=True)
class Check:
    """Runtime check ``value > 0`` (``relation`` POSITIVE, a pivot), ``value >= 0``
    (NONNEGATIVE), ``value == 0`` (ZERO: an input element outside a declared sparsity
    pattern) or ``value == value`` (PRESENT: a measurement that is not NaN); ``value`` is
    an atom. A NaN fails every relation. Fails with ``message``.

    ``parameter``: for the check of a free parameter's declared domain (``value`` an
    element of ``p``; derive.domains), the parameter's name: generated Python names the
    value it refuses, and the check is dropped with the dead code when nothing else in
    the program reads that element; empty for every other check. ``measurement``: for a
    presence check, the name of the measurement ``value`` holds (the presence checks of a
    program share one status, and what fails names the measurement)."""

    value: sympy.Expr
    message: str
    relation: str = POSITIVE
    parameter: str = ""
    measurement: str = ""

    @property
    def text(self) -> str:
        """``value > 0``, ``value >= 0``, ``value == 0`` or ``value == value``."""
        if self.relation == PRESENT:
            return f"{self.value} == {self.value}"
        return f"{self.value} {OPERATORS[self.relation]} 0"


Statement = Assign | Check


def is_atom(expr: sympy.Basic) -> bool:
    """True for what needs no temporary: a symbol or a numeric constant."""
    return bool(expr.is_Symbol or is_number(expr))


def is_number(expr: sympy.Basic) -> bool:
    """``expr.is_number``, each sum, product, power and applied function remembered: sympy
    walks the arguments' trees again at every node, which made number tests a tenth of
    the optimiser's and the lowering's time on a large program."""
    if expr.is_Symbol:
        return False
    if expr.is_Number:
        return True
    if not expr.args:
        return bool(expr.is_number)
    return _composite_is_number(expr)


@functools.lru_cache(maxsize=1 << 17)
def _composite_is_number(expr: sympy.Basic) -> bool:
    if ((expr.is_Add or expr.is_Mul or expr.is_Pow or isinstance(expr, sympy.Function))
            and not isinstance(expr, AppliedUndef)):  # sympy's Expr.is_number, memoised
        return all(is_number(arg) for arg in expr.args)
    return bool(expr.is_number)


#: Values an expression of a program must never hold (a structurally zero divisor).
NON_FINITE = (sympy.zoo, sympy.nan, sympy.oo, -sympy.oo)


def live_statements(body: Sequence[Statement], results: Mapping[str, tuple]) -> list[Statement]:
    """``body`` without the assignments that reach neither a result nor a check (dead
    code), and without the domain checks of parameters that nothing else left reads, in
    order."""
    live = {v for values in results.values() for v in values if isinstance(v, Temporary)}
    out: list[Statement] = []
    for st in reversed(body):
        if isinstance(st, Assign):
            if st.target not in live:
                continue
            expr = st.expr
        else:
            expr = st.value
        out.append(st)
        live.update(s for s in expr.free_symbols if isinstance(s, Temporary))
    out.reverse()
    read = {v for values in results.values() for v in values if isinstance(v, InputElement)}
    for st in out:
        if not (isinstance(st, Check) and st.parameter):
            expr = st.expr if isinstance(st, Assign) else st.value
            read.update(s for s in expr.free_symbols if isinstance(s, InputElement))
    return [st for st in out if not (isinstance(st, Check) and st.parameter
                                     and st.value not in read)]


def rename(expr: sympy.Basic, names: Mapping[sympy.Symbol, sympy.Symbol]) -> sympy.Basic:
    """:func:`substitute` for ``names`` an injective map of symbols to symbols (the
    temporaries renumbered), without sympy's flatten: an injective renaming merges no
    terms and no factors, so a sum or product rebuilt is its renamed arguments in
    sympy's order (the number first, the rest by ``_args_sortkey``, as flatten leaves
    them), built as they are. The same expression as substitute's, argument order
    included."""
    return _replaced(expr, names, renaming=True)


def substitute(expr: sympy.Basic, mapping: Mapping[sympy.Basic, sympy.Basic]) -> sympy.Basic:
    """``expr.xreplace(mapping)``, except that an applied function whose arguments are
    not all numbers after the replacement is rebuilt without its ``eval``: sympy's
    ``sin``, ``cos``, ... search a changed argument for multiples of pi and of i and for a
    sign to pull out, assumption queries that cost milliseconds an argument (a sum of
    a state and a sigma-point offset) and find nothing for the atoms derive substitutes.
    The result equals xreplace's wherever that ``eval`` would not rewrite the call."""
    return _replaced(expr, mapping, renaming=False)


def with_arguments(call: sympy.Function, args: Sequence[sympy.Basic]) -> sympy.Function:
    """The applied function ``call`` with its arguments replaced one for one by ``args``,
    not evaluated: ``call.func(*args, evaluate=False)`` as sympy builds it (its ``nargs``
    included), without the set of admissible argument counts sympy builds again for
    each call (20 µs, against 1 µs for this)."""
    out = sympy.Basic.__new__(type(call), *args)
    out.nargs = call.nargs
    return out


def _replaced(expr: sympy.Basic, mapping: Mapping[sympy.Basic, sympy.Basic],
              renaming: bool) -> sympy.Basic:
    memo: dict[sympy.Basic, sympy.Basic] = {}

    def walk(node: sympy.Basic) -> sympy.Basic:
        hit = mapping.get(node)
        if hit is not None:
            return hit
        if not node.args:
            return node
        done = memo.get(node)
        if done is not None:
            return done
        args = tuple(walk(arg) for arg in node.args)
        if all(new is old for new, old in zip(args, node.args)):
            out = node
        elif renaming and (node.is_Add or node.is_Mul) and node.is_commutative:
            lead = 1 if args[0].is_Number else 0
            out = node.func._from_args(args[:lead] + tuple(sorted(args[lead:],
                                                                  key=_args_sortkey)), True)
        elif isinstance(node, sympy.Function) and not all(is_number(a) for a in args):
            out = with_arguments(node, args)
        elif node.is_Add:
            out = sum_of(args)
        elif node.is_Mul:
            out = product_of(args)
        else:
            out = node.func(*args)
        memo[node] = out
        return out

    return walk(expr) if mapping else expr
