"""The optimiser of straight-line programs: the passes behind :meth:`Program.optimize`.

Passes, in order: constant folding and copy propagation with merging of
identical right-hand sides (:func:`_forward`); staging of integer powers
(:func:`_stage_powers`); sharing of common subexpressions across the whole body,
each kept only when it lowers the operation count of the lowered Python form
(:func:`_share`, priced by :class:`_CostCache` through :mod:`derive.expression_lowering`
and :mod:`derive.trees`); dead-code elimination (:func:`_dead_code`); renumbering
``t0, t1, ...`` in order (:func:`_renumber`).  Deterministic.

The layers of the program core, bottom-up: :mod:`derive.statements` (what a body holds),
:mod:`derive.trees` (operation trees and their counts), :mod:`derive.expression_lowering`,
:mod:`derive.rows` (vector chunks), this module, :mod:`derive.program` (building, and
``optimize`` as the entry point), :mod:`derive.lowering` (whole programs lowered) and
:mod:`derive.flops` (counts of programs and of printed code).
"""

from __future__ import annotations

from bisect import bisect_left, insort
from collections.abc import Sequence
from dataclasses import replace
from fractions import Fraction

import sympy

from derive.errors import MatrixPropertyError
from derive.expression_lowering import ExpressionLowerer
from derive.monomials import sum_of
from derive.statements import (
    NON_FINITE,
    NONNEGATIVE,
    POSITIVE,
    PRESENT,
    Assign,
    Statement,
    Temporary,
    is_atom,
    is_number,
    live_statements,
    rename,
    substitute,
    with_arguments,
)
from derive.trees import count_tree

Cost = tuple[int, int]  # (flops, instructions) of the lowered Python form


def optimize_body(body: list[Statement], results: dict[str, tuple[sympy.Expr, ...]],
                   fresh) -> tuple[list[Statement], dict[str, tuple[sympy.Expr, ...]]]:
    costs = _CostCache()
    body, results = _forward(body, results)
    body = _stage_powers(body, fresh)
    body, results = _forward(body, results)
    plain, plain_results = _dead_code(body, results)
    shared, shared_results = _forward(_share(body, fresh, costs), results)
    shared, shared_results = _dead_code(shared, shared_results)
    if costs.total(shared) > costs.total(plain):
        shared, shared_results = plain, plain_results
    return _renumber(shared, shared_results)


class _CostCache:
    """(flops, instructions) of expressions, lowered as Python prints them."""

    def __init__(self) -> None:
        self._cache: dict[sympy.Expr, Cost] = {}
        self._lowerer = ExpressionLowerer(use_fma=False)   # one memo of sort keys
        self.order = self._lowerer.order

    def __call__(self, expr: sympy.Expr) -> Cost:
        cost = self._cache.get(expr)
        if cost is None:
            n = count_tree(self._lowerer.lower(sympy.sympify(expr)))
            cost = self._cache[expr] = (n.flops, n.instructions)
        return cost

    def total(self, body: Sequence[Statement]) -> Cost:
        flops = instructions = 0
        for st in body:
            f, i = self(st.expr) if isinstance(st, Assign) else (0, 1)
            flops, instructions = flops + f, instructions + i
        return flops, instructions


def _forward(body: Sequence[Statement], results: dict[str, tuple[sympy.Expr, ...]]):
    """Constant folding, copy propagation, merging of identical right-hand sides and checks."""
    subst: dict[sympy.Symbol, sympy.Expr] = {}
    seen: dict[sympy.Expr, Temporary] = {}
    checked: set[sympy.Expr] = set()
    out: list[Statement] = []
    for st in body:
        if isinstance(st, Assign):
            expr = substitute(st.expr, subst) if subst else st.expr
            # Program.let refuses a non-finite expression, so only folding makes one
            if expr is not st.expr and expr.has(*NON_FINITE):
                raise MatrixPropertyError(f"{st.target} = {st.expr} is not finite after folding "
                                          f"({expr}): a structurally zero divisor")
            if is_atom(expr):
                subst[st.target] = expr
            elif expr in seen:
                subst[st.target] = seen[expr]
            else:
                seen[expr] = st.target
                out.append(st if expr is st.expr else Assign(st.target, expr))
        else:
            value = substitute(st.value, subst) if subst else st.value
            if value.is_number:
                holds = (value.is_positive if st.relation == POSITIVE else
                         value.is_nonnegative if st.relation == NONNEGATIVE else
                         value.is_finite if st.relation == PRESENT else value.is_zero)
                if holds is not True:
                    raise MatrixPropertyError(f"{st.message} (the value is structurally {value})")
            elif (st.relation, value) not in checked:
                checked.add((st.relation, value))
                out.append(replace(st, value=value))
    new_results = {name: tuple(substitute(v, subst) for v in values)
                   for name, values in results.items()}
    return out, new_results


def _stage_powers(body: Sequence[Statement], fresh) -> list[Statement]:
    """Give non-atomic bases of powers a temporary; build ``x**k``, ``|k| >= 4``, by squaring."""
    out: list[Statement] = []
    for st in body:
        if not isinstance(st, Assign):
            out.append(st)
            continue

        def emit(expr: sympy.Expr) -> Temporary:
            target = fresh("pow")
            out.append(Assign(target, expr))
            return target

        expr = _expand_powers(st.expr, emit)
        out.append(st if expr is st.expr else Assign(st.target, expr))
    return out


def _expand_powers(expr: sympy.Expr, emit) -> sympy.Expr:
    if is_atom(expr):
        return expr
    args = [_expand_powers(a, emit) for a in expr.args]
    if any(a is not b for a, b in zip(args, expr.args)):
        expr = expr.func(*args)
    if not expr.is_Pow:
        return expr
    base, exp = expr.base, expr.exp
    simple = exp in (-1, sympy.Rational(1, 2), sympy.Rational(-1, 2))
    staged = False
    if not is_atom(base) and not simple:
        base, staged = emit(base), True
    if exp.is_Integer and abs(exp) >= 4:
        k = abs(int(exp))
        factors, square = [], base
        while True:
            if k & 1:
                factors.append(square)
            k >>= 1
            if not k:
                break
            square = emit(square ** 2)
        value = sympy.Mul(*factors)
        return value if exp > 0 else 1 / value
    return sympy.Pow(base, exp) if staged else expr


def _subexpressions(expr: sympy.Expr):
    """Non-atomic subtrees of ``expr`` in preorder, plus the coefficient-free part of
    every Mul with a numeric coefficient (``a*b`` of ``-2*a*b``)."""
    stack = [expr]
    while stack:
        e = stack.pop()
        if is_atom(e):
            continue
        yield e
        if e.is_Mul and len(e.args) > 2:
            coeff, rest = e.as_coeff_Mul()
            if coeff != 1:
                yield rest
        stack.extend(reversed(e.args))


def _occurrences(expr: sympy.Expr, target: sympy.Expr) -> int:
    if expr == target:
        return 1
    if is_atom(expr):
        return 0
    if expr.is_Mul:
        coeff, rest = expr.as_coeff_Mul()
        if coeff != 1 and rest == target:
            return 1
    return sum(_occurrences(a, target) for a in expr.args)


def _replace(expr: sympy.Expr, target: sympy.Expr, symbol: sympy.Symbol) -> sympy.Expr:
    if expr == target:
        return symbol
    if is_atom(expr):
        return expr
    if expr.is_Mul:
        coeff, rest = expr.as_coeff_Mul()
        if coeff != 1 and rest == target:
            return coeff * symbol
    args = [_replace(a, target, symbol) for a in expr.args]
    if all(a is b for a, b in zip(args, expr.args)):
        return expr
    if expr.is_Add:
        return sum_of(args)
    if isinstance(expr, sympy.Function) and not all(is_number(a) for a in args):
        return with_arguments(expr, args)
    return expr.func(*args)


def _share(body: Sequence[Statement], fresh, cost: _CostCache) -> list[Statement]:
    """Common-subexpression sharing across the body, one candidate at a time, largest first;
    a candidate is shared only where that lowers (flops, instructions)."""
    stmts: dict[int, Statement] = dict(enumerate(body))
    pos: dict[int, Fraction] = {sid: Fraction(sid) for sid in stmts}
    keys: list[Fraction] = sorted(pos.values())
    occ: dict[sympy.Expr, list[int]] = {}
    for sid, st in stmts.items():
        if isinstance(st, Assign):
            for node in _subexpressions(st.expr):
                occ.setdefault(node, []).append(sid)
    candidates = [e for e, ids in occ.items() if len(ids) >= 2]
    candidates.sort(key=lambda e: (-cost(e)[1], cost.order(e)))

    def place_before(sid: int, first: int) -> None:
        if sid in pos:
            keys.remove(pos[sid])
        k = bisect_left(keys, pos[first])
        low = keys[k - 1] if k else pos[first] - 1
        pos[sid] = (low + pos[first]) / 2
        insort(keys, pos[sid])

    next_id = len(body)
    for cand in candidates:
        users = [sid for sid in dict.fromkeys(occ[cand])
                 if _occurrences(stmts[sid].expr, cand)]
        if sum(_occurrences(stmts[sid].expr, cand) for sid in users) < 2:
            continue
        root = next((sid for sid in users if stmts[sid].expr == cand), None)
        symbol = stmts[root].target if root is not None else fresh("cse")
        others = [sid for sid in users if sid != root]
        new_exprs = {sid: _replace(stmts[sid].expr, cand, symbol) for sid in others}
        before = [cost(stmts[sid].expr) for sid in users]
        after = [cost(cand)] + [cost(e) for e in new_exprs.values()]
        if (sum(c[0] for c in after), sum(c[1] for c in after)) >= (
                sum(c[0] for c in before), sum(c[1] for c in before)):
            continue
        first = min(others, key=pos.__getitem__)
        if root is None:
            root, next_id = next_id, next_id + 1
            stmts[root] = Assign(symbol, cand)
            for node in _subexpressions(cand):
                if node != cand and node in occ:
                    occ[node].append(root)
            place_before(root, first)
        elif pos[root] > pos[first]:
            place_before(root, first)
        for sid, expr in new_exprs.items():
            stmts[sid] = Assign(stmts[sid].target, expr)
    return [stmts[sid] for sid in sorted(stmts, key=pos.__getitem__)]


def _dead_code(body: Sequence[Statement], results: dict[str, tuple[sympy.Expr, ...]]):
    """Drop assignments that reach neither an output nor a check."""
    return live_statements(body, results), results


def _renumber(body: Sequence[Statement], results: dict[str, tuple[sympy.Expr, ...]]):
    """Name the temporaries t0, t1, ... in order."""
    names: dict[sympy.Symbol, sympy.Symbol] = {}
    for st in body:
        if isinstance(st, Assign):
            names[st.target] = Temporary(f"t{len(names)}")
    out: list[Statement] = []
    for st in body:  # an injective renaming: rebuilt without sympy's flatten
        if isinstance(st, Assign):
            out.append(Assign(names[st.target], rename(st.expr, names)))
        else:
            out.append(replace(st, value=rename(st.value, names)))
    return out, {name: tuple(rename(v, names) for v in values)
                 for name, values in results.items()}
