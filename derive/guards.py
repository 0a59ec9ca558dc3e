"""Guarded expressions as selects: ``sign``, ``Max``, ``Min`` and ``Piecewise`` rewritten
into two functions of four arguments that generated code computes without a branch.

- :class:`IfGreater` ``(l, r, a, b)``: ``a`` where ``l > r``, else ``b``;
- :class:`IfAtLeast` ``(l, r, a, b)``: ``a`` where ``l >= r``, else ``b``.

Both branches are computed; the select picks one (C ``((l > r) ? a : b)``, one comparison
and one select in the counts). A NaN in ``l`` or ``r`` makes the comparison false: the
result is ``b``.

The rewrite (:func:`selects`), the guard's side stated:

- ``Piecewise((e1, c1), (e2, c2), ..., (en, True))``: nested selects, the first condition
  that holds chooses; each condition is one comparison ``<``, ``<=``, ``>``, ``>=`` of two
  expressions (``l < r`` is ``r > l``); the last branch must be the default (``True``);
- ``Max(a, b)``: ``IfAtLeast(a, b, a, b)``, ``Min(a, b)``: ``IfAtLeast(b, a, a, b)``; more
  arguments fold from the left. At a tie the first argument is taken, and a numeric
  argument (the guard's bound, ``Max(v, eps)``) goes last, so at ``v = eps`` the value
  and the derivative are ``v``'s; a NaN argument gives the last one;
- ``sign(x)``: ``IfGreater(x, 0, 1, IfGreater(0, x, -1, 0))``: 1, -1, and 0 at zero and
  for NaN;
- ``Abs`` stays a call (``fabs``: exact, NaN to NaN); its derivative, ``sign``, becomes the
  selects above (``d|x|/dx = 0`` at ``x = 0``).

Derivatives of a select are the selects of the branches' derivatives under the same
condition (:meth:`IfGreater._eval_derivative`): the derivative at the boundary is the
side the condition chooses there (``l > r`` false at a tie: ``b``'s; ``l >= r``: ``a``'s).
"""

from __future__ import annotations

import numpy as np
import sympy

from derive.errors import ModelError


class GuardError(ModelError):
    """A guarded expression generated code cannot compute (no default branch, a
    condition that is not one comparison, branches that are not scalars)."""


class _Select(sympy.Function):
    """``a`` where ``l REL r``, else ``b``; ``REL`` fixed by the subclass."""

    nargs = 4
    relation = ""

    @classmethod
    def _holds(cls, difference: sympy.Expr) -> bool | None:
        raise NotImplementedError

    @classmethod
    def eval(cls, left, right, a, b):
        if a == b:
            return a
        if left.is_number and right.is_number:
            holds = cls._holds(left - right)
            if holds is not None:
                return a if holds else b
        return None

    def _eval_derivative(self, s):
        left, right, a, b = self.args
        return guarded(type(self), left, right, a.diff(s), b.diff(s))

    def _eval_is_real(self):
        return self.args[2].is_real and self.args[3].is_real

    def _eval_is_finite(self):
        a, b = self.args[2:]
        if a.is_finite and b.is_finite:
            return True
        return None

    def _sympystr(self, printer):
        left, right, a, b = (printer.doprint(e) for e in self.args)
        return f"({a} if {left} {self.relation} {right} else {b})"


class IfGreater(_Select):
    """``a`` where ``l > r``, else ``b`` (also for a NaN ``l`` or ``r``)."""

    relation = ">"

    @classmethod
    def _holds(cls, difference):
        return difference.is_positive


class IfAtLeast(_Select):
    """``a`` where ``l >= r``, else ``b`` (also for a NaN ``l`` or ``r``)."""

    relation = ">="

    @classmethod
    def _holds(cls, difference):
        return difference.is_nonnegative


class _Guard:
    """A divisor of a select's branch kept off zero where that branch is not chosen: the
    divisor d where the select's condition chooses its branch, else 1 (``(l, r, d, 1)``
    in its ``a`` branch, ``(l, r, 1, d)`` in its ``b`` branch). Its derivative is d's
    alone: it is read only inside the branch, where it is d."""

    def _eval_derivative(self, s):
        a, b = self.args[2:]
        return (b if a == 1 else a).diff(s)


class GuardGreater(_Guard, IfGreater):
    """:class:`IfGreater` guarding a divisor (:class:`_Guard`)."""


class GuardAtLeast(_Guard, IfAtLeast):
    """:class:`IfAtLeast` guarding a divisor (:class:`_Guard`)."""


SELECTS = (IfGreater, IfAtLeast)
_GUARD_OF = {IfGreater: GuardGreater, IfAtLeast: GuardAtLeast}


def _kept_off_zero(expr: sympy.Expr, select, left, right, chosen: bool) -> sympy.Expr:
    """``expr`` (a branch of ``select(left, right, ...)``: the ``a`` branch where
    ``chosen``) with each divisor that shares a symbol with the condition guarded: the
    base of a power with a negative exponent replaced by the select's guard of it (the base
    where the branch is chosen, else 1), unless it is that guard already."""
    if not isinstance(expr, sympy.Basic) or expr.is_Atom:
        return expr
    symbols = left.free_symbols | right.free_symbols
    guard = _GUARD_OF[select]

    def divisor(e) -> bool:
        if not (e.is_Pow and e.exp.is_number and e.exp.is_negative) or e.base.is_number:
            return False
        base = e.base
        if isinstance(base, guard) and base.args[:2] == (left, right) \
                and (base.args[3] == 1) == chosen:
            return False
        return bool(base.free_symbols & symbols)

    def kept(e):
        base = guard(left, right, e.base, sympy.S.One) if chosen else \
            guard(left, right, sympy.S.One, e.base)
        return sympy.Pow(base, e.exp)

    return expr.replace(divisor, kept)


def guarded(select, left, right, a: sympy.Expr, b: sympy.Expr) -> sympy.Expr:
    """``select(left, right, a, b)`` (IfGreater or IfAtLeast) whose branches divide only by
    numbers that are off zero where the branch is not chosen (:func:`_kept_off_zero`): the
    branch not taken is computed (a select, no jump) but never divides by zero, so C gets
    no infinity and Python on plain floats no ZeroDivisionError; each guard is one more
    comparison and select, counted as such."""
    select = next(cls for cls in SELECTS if issubclass(select, cls))
    return select(left, right, _kept_off_zero(a, select, left, right, True),
                  _kept_off_zero(b, select, left, right, False))
#: What :func:`selects` rewrites (and what a derivative of ``Abs`` brings back).
GUARDS = (sympy.Piecewise, sympy.Max, sympy.Min, sympy.sign)


def _condition(cond, a: sympy.Expr, b: sympy.Expr, where: str) -> sympy.Expr:
    if cond is sympy.true:
        return a
    if cond is sympy.false:
        return b
    if isinstance(cond, sympy.StrictGreaterThan):
        return guarded(IfGreater, cond.lhs, cond.rhs, a, b)
    if isinstance(cond, sympy.GreaterThan):
        return guarded(IfAtLeast, cond.lhs, cond.rhs, a, b)
    if isinstance(cond, sympy.StrictLessThan):
        return guarded(IfGreater, cond.rhs, cond.lhs, a, b)
    if isinstance(cond, sympy.LessThan):
        return guarded(IfAtLeast, cond.rhs, cond.lhs, a, b)
    raise GuardError(f"{where}: condition {cond} is not one comparison (<, <=, >, >=) of two "
                     "expressions")


def _scalar(value, where: str, k: int) -> sympy.Expr:
    if not isinstance(value, sympy.Expr) or isinstance(value, sympy.MatrixBase):
        raise GuardError(f"{where}: branch {k} of Piecewise is {type(value).__name__} "
                         f"{value}, not a scalar like the others (branches must have one "
                         "shape)")
    return value


def _extremum(func, args: tuple[sympy.Expr, ...]) -> sympy.Expr:
    ordered = sorted(args, key=lambda e: (e.is_number, sympy.default_sort_key(e)))
    acc = ordered[0]
    for other in ordered[1:]:
        acc = guarded(IfAtLeast, acc, other, acc, other) if func is sympy.Max else \
            guarded(IfAtLeast, other, acc, acc, other)
    return acc


def selects(expr: sympy.Expr, where: str = "expression") -> sympy.Expr:
    """``expr`` with every ``Piecewise``, ``Max``, ``Min`` and ``sign`` rewritten as
    selects (the module docstring); GuardError naming ``where`` for one that cannot be."""
    if not isinstance(expr, sympy.Basic) or expr.is_Atom or not expr.has(*GUARDS):
        return expr
    if isinstance(expr, sympy.Piecewise):
        pairs = expr.args
        if pairs[-1].cond is not sympy.true:
            raise GuardError(f"{where}: Piecewise has no default (a last branch with "
                             "condition True), so some states have no value")
        acc = selects(_scalar(pairs[-1].expr, where, len(pairs)), where)
        for k in range(len(pairs) - 2, -1, -1):
            value = selects(_scalar(pairs[k].expr, where, k + 1), where)
            cond = pairs[k].cond
            if isinstance(cond, sympy.core.relational.Relational):
                cond = cond.func(selects(cond.lhs, where), selects(cond.rhs, where))
            acc = _condition(cond, value, acc, where)
        return acc
    args = tuple(selects(a, where) for a in expr.args)
    if expr.func in (sympy.Max, sympy.Min):
        return _extremum(expr.func, args)
    if expr.func is sympy.sign:
        x = args[0]
        return IfGreater(x, 0, sympy.S.One, IfGreater(0, x, -sympy.S.One, sympy.S.Zero))
    return expr.func(*args)


def has_guards(expr: sympy.Basic) -> bool:
    """Whether ``expr`` holds a select, or a guard or ``Abs`` a derivative turns into one."""
    return bool(expr.has(*SELECTS, *GUARDS, sympy.Abs))


def numpy_selects() -> dict:
    """The selects as NumPy functions, for ``sympy.lambdify(..., modules=[this, "numpy"])``
    (the references evaluate the model as generated code does)."""
    greater = lambda left, right, a, b: np.where(np.greater(left, right), a, b)  # noqa: E731
    at_least = lambda left, right, a, b: np.where(np.greater_equal(left, right), a, b)  # noqa: E731
    return {"IfGreater": greater, "IfAtLeast": at_least, "GuardGreater": greater,
            "GuardAtLeast": at_least}


__all__ = ["GUARDS", "SELECTS", "GuardAtLeast", "GuardError", "GuardGreater", "IfAtLeast",
           "IfGreater", "guarded", "has_guards", "numpy_selects", "selects"]
