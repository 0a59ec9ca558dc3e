"""Products and negations read once, by a sum, folded into that sum (the C lowering with fma).

Staging gives every entry of a matrix its own temporary (:mod:`derive.staging`), so an
entry of ``K (P H^T)^T`` is ``t52 = P[9]*t3`` and the update reads it once, in
``t188 = P[0] - t52``; a negated entry is ``t13 = -t12`` read once in ``t14 = t1 + t13``.
Lowered statement by statement, such a product is a multiplication and the sum a
subtraction: the fma rule of :mod:`derive.lowering` sees a product only inside the
tree of the sum.  :func:`fold_single_use` moves each such temporary into its one reader
before the C lowering (``t188 = P[0] - P[9]*t3``, one fused negative multiply-add;
``t14 = t1 - P[120]*t7``, the negation gone), repeatedly, so a negation of a product
folds both.

What folds: a temporary read exactly once (results and checks count as reads), defined as
a product without division (a negation is the product with -1), whose one reader is a sum
in which it is a term ``k*t`` with a numeric ``k``, where ``k`` or the product's own
coefficient is ±1 (so the folded term multiplies exactly as before: ``k*(a*b)`` lowers
to ``mul(k, a*b)`` either way); and a negated symbol ``t = -s`` read any number of times,
each time as such a term of a sum (each reader subtracts ``s`` instead of adding ``t``:
nothing is computed twice).  Nothing else moves, and the operations left are those of
before less one multiplication or negation per fold (plus the fma contraction).

Python code has no fma and keeps its statements: only ``lower_program(use_fma=True)``
folds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import sympy

from derive.statements import Assign, Check, Statement, Temporary


def read_counts(body: Sequence[Statement], results: Mapping[str, tuple]
                ) -> dict[Temporary, int]:
    """How many times each temporary is read: every occurrence in a statement's expression
    or check, and in the results (also derive.schedule's count of uses)."""
    counts: dict[Temporary, int] = {}
    stack: list[sympy.Basic] = [st.expr if isinstance(st, Assign) else st.value
                                for st in body]
    stack.extend(v for values in results.values() for v in values)
    while stack:
        node = stack.pop()
        if isinstance(node, Temporary):
            counts[node] = counts.get(node, 0) + 1
        else:
            stack.extend(node.args)
    return counts


def is_product(expr: sympy.Expr) -> bool:
    """A product without division (the fma rule fuses only those)."""
    return bool(expr.is_Mul) and not any(
        a.is_Pow and a.exp.is_number and a.exp.is_negative for a in expr.args)


def _term_reads(body: Sequence[Statement]) -> dict[Temporary, int]:
    """How many times each temporary is read as a term ``k*t`` (``k`` a number) of a sum."""
    counts: dict[Temporary, int] = {}
    for st in body:
        if isinstance(st, Assign) and st.expr.is_Add:
            for term in st.expr.args:
                rest = term.as_coeff_Mul()[1]
                if isinstance(rest, Temporary):
                    counts[rest] = counts.get(rest, 0) + 1
    return counts


def _is_negated_atom(expr: sympy.Expr) -> bool:
    """``-s`` for a symbol ``s``."""
    coeff, rest = expr.as_coeff_Mul()
    return coeff == -1 and bool(rest.is_Symbol)


def fold_single_use(body: Sequence[Statement],
                    results: Mapping[str, tuple],
                    keep: frozenset[Temporary] = frozenset()) -> list[Statement]:
    """``body`` with each product or negation read once, as a term of a sum, folded into
    that sum, and each negated symbol read only as terms of sums folded into each of them
    (see the module docstring); the other statements keep their order. The statements
    assigning ``keep`` (the lanes of vector rows, lowered by their own form) are neither
    rewritten nor folded: a lane is computed in its chunk."""
    reads = read_counts(body, results)
    term_reads = _term_reads(body)
    products = {st.target: st.expr for st in body
                if isinstance(st, Assign) and st.target not in keep and is_product(st.expr)
                and (reads.get(st.target) == 1
                     or (_is_negated_atom(st.expr)
                         and term_reads.get(st.target) == reads.get(st.target)))}
    if not products:
        return list(body)
    folded: set[Temporary] = set()
    out: list[Statement] = []
    for st in body:
        if isinstance(st, Check) or not st.expr.is_Add or st.target in keep:
            out.append(st)
            continue
        expr = st.expr
        while True:
            terms, changed = [], False
            for term in sympy.Add.make_args(expr):
                coeff, rest = term.as_coeff_Mul()
                product = products.get(rest) if isinstance(rest, Temporary) else None
                if product is not None and (abs(coeff) == 1
                                            or abs(product.as_coeff_Mul()[0]) == 1):
                    terms.append(coeff * product)
                    folded.add(rest)
                    changed = True
                else:
                    terms.append(term)
            if not changed:
                break
            expr = sympy.Add(*terms)
            if not expr.is_Add:
                break
        out.append(st if expr is st.expr else Assign(st.target, expr))
    return [st for st in out if not (isinstance(st, Assign) and st.target in folded)]
