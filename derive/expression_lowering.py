"""Lowering of sympy expressions to binary operation trees (:mod:`derive.trees`).

The one place that decides which operations an expression costs: the counter
(:mod:`derive.flops`) and both printers (:mod:`derive.emit`) walk the trees made
here, so a count is by construction the count of what is printed.

Rules (``e`` a sympy expression):

- a number, or any expression without free symbols (``sqrt(2)``, ``pi``), is one
  double constant; a symbol is a variable;
- ``Add``: terms in :func:`sympy.default_sort_key` order (of the program's
  ``order_names``, see below), numeric terms merged
  into one constant; a term with a negative numeric coefficient is subtracted
  as its positive part (``a - 2*b`` is ``sub(a, mul(2, b))``); the chain starts
  at the first positive term (all negative: ``neg`` of the first);
- ``Mul``: numeric factors merged into one coefficient ``c``; factors with a
  negative exponent form a denominator (``a/b`` is ``div(a, b)``, ``c/b`` is
  ``div(c, b)``; factors in the order of terms); ``c = -1`` is ``neg`` (or folds
  into a surrounding ``sub``); other ``c`` multiply first: ``mul(c, ...)``;
- ``x**k`` (integer ``k > 0``): ``k - 1`` multiplications; ``x**-k``:
  ``div(1, x**k)``; ``x**(1/2)``: ``sqrt``; ``x**(-1/2)``: ``div(1, sqrt(x))``;
  ``x**(k/2)``: ``mul(x**((k-1)/2), sqrt(x))``;
- with ``use_fma`` (C): in an ``Add`` each term whose tree is a product becomes
  ``fma(a, b, acc)`` on the chain of the other terms; a negative term ``-c*a``
  uses the negative constant (``fma(-c, a, acc)``), ``-a*b`` is the fused negative
  multiply-add ``fnma(a, b, acc)`` (``acc - a*b``); products whose operands
  are deepest, or read the carried state (x, P, temporaries), go last so the
  dependency chain from one step to the next stays short; a sum of products alone
  starts at the first of them (``mul``; ``neg(mul)`` when it is negative and no positive
  one is as early); before lowering, products and negations read once by a sum are
  folded into it (:func:`derive.single_use.fold_single_use`), so the rule sees them;
- the functions of :data:`FUNCTIONS` are calls ``call:NAME`` (C names);
- :class:`IfPresent` ``(z, a, b)`` is ``select(z, a, b)``: ``a`` where the input
  element ``z`` is not NaN, else ``b`` (the comparison is ``z == z``);
- :class:`IfAtMost` ``(v, bound, a, b)`` is ``gate(v, bound, a, b)``: ``a`` where
  ``v <= bound`` (a constant), else ``b`` (also for a NaN ``v``); no flop (innovation gating);
- :class:`derive.guards.IfGreater` ``(l, r, a, b)`` is ``if_gt(l, r, a, b)``: ``a`` where
  ``l > r``, else ``b``; :class:`derive.guards.IfAtLeast` is ``if_ge`` (``l >= r``): the
  guards ``sign``, ``Max``, ``Min`` and ``Piecewise`` of a model, both branches computed;
- each of ``select``, ``gate``, ``if_gt`` and ``if_ge`` is one comparison (``cmp``) and one
  select (``select``), no flop;
- anything else raises :class:`LoweringError`.

The order of terms and factors follows sympy's order of the symbols' names, so it can
change when symbols are renamed (``t10*t2*t7`` is ``(t10*t2)*t7``, ``t22*t27*t30`` is
``(t22*t27)*t30``). A program assembled from renamed copies of another
(:mod:`derive.filters.blockwise`) names in ``Program.order_names`` the symbol each of its
symbols copies: terms and factors are ordered as those of the copied program, so each
copy lowers to the operations of the original in the same order
(:mod:`derive.runs.blocks` carries identical copies in the lanes of one vector).

Operation kinds: :data:`derive.trees.KINDS`; the rules that price a shared subexpression
(:mod:`derive.optimise`) and the ones that lower a program (:mod:`derive.lowering`) are
these.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import sympy

from derive.errors import ModelError
from derive.guards import IfAtLeast, IfGreater
from derive.sort_keys import SortKeys
from derive.statements import is_number
from derive.trees import Const, Op, Tree, Var, depth

#: sympy function -> name of the C function (math.h) it lowers to.
FUNCTIONS = {
    sympy.sin: "sin", sympy.cos: "cos", sympy.tan: "tan", sympy.exp: "exp", sympy.log: "log",
    sympy.atan: "atan", sympy.atan2: "atan2", sympy.Abs: "fabs",
    sympy.ceiling: "ceil",  # an angle wrapped to (-pi, pi] (derive.manifolds.wrap)
}


class LoweringError(ModelError):
    """An expression the printers cannot emit (unsupported function or exponent)."""


class IfPresent(sympy.Function):
    """``IfPresent(z, a, b)``: ``a`` where the measurement ``z`` is present (not NaN), else ``b``.

    ``z`` is an input element (a symbol such as ``z[1]``); generated code tests it with
    ``z == z``, which is false for NaN only.  Folds when both branches are equal or ``z``
    is a number, and takes a common minus sign out (``IfPresent(z, -a, 0)`` is
    ``-IfPresent(z, a, 0)``) so that negated atoms stay foldable.
    """

    nargs = 3

    @classmethod
    def eval(cls, z, a, b):
        if a == b:
            return a
        if z.is_number:
            return b if z is sympy.nan else a
        if a.could_extract_minus_sign() and (b.is_zero or b.could_extract_minus_sign()):
            return -cls(z, -a, -b)
        return None


class IfAtMost(sympy.Function):
    """``IfAtMost(v, bound, a, b)``: ``a`` where ``v <= bound``, else ``b`` (a NaN ``v``
    gives ``b``); ``bound`` is a number. Generated code tests ``v <= bound`` once per
    select (innovation gating: the update applies while its NIS is within the bound).
    Folds when both branches are equal."""

    nargs = 4

    @classmethod
    def eval(cls, v, bound, a, b):
        if a == b:
            return a
        return None



def negative_number(value: sympy.Expr) -> bool:
    """``value.is_negative`` for a sympy number, answered directly for the kinds derivations
    make (a Rational by its numerator, a Float by comparison): sympy's assumption system
    deduces every fact of each new number it is asked about, about 0.1 ms each, which
    dominated the generation of dense models."""
    if value.is_Rational:
        return value.p < 0
    if value.is_Float:
        return bool(value < 0)
    return bool(value.is_negative)


_CONSTANTS: dict[sympy.Expr, float] = {}
"""constant_value's results by expression (numbers recur across a program's statements)."""


def constant_value(expr: sympy.Expr) -> float:
    """The double nearest to a numeric sympy expression; non-finite or complex raises."""
    known = _CONSTANTS.get(expr)
    if known is not None:
        return known
    result = _constant_value(expr)
    if len(_CONSTANTS) > 100_000:
        _CONSTANTS.clear()
    _CONSTANTS[expr] = result
    return result


def _constant_value(expr: sympy.Expr) -> float:
    value = expr if expr.is_Float else sympy.N(expr, 40)
    if not value.is_real:
        raise LoweringError(f"constant {expr} is not a real number")
    result = float(value)
    if not math.isfinite(result):
        raise LoweringError(f"constant {expr} is not finite as a double")
    return result


def _chain(kind: str, trees: list[Tree]) -> Tree | None:
    if not trees:
        return None
    acc = trees[0]
    for tree in trees[1:]:
        acc = Op(kind, (acc, tree))
    return acc


class ExpressionLowerer:
    """Lowers expressions by the rules above (the state ports and the order names of one
    program)."""

    def __init__(self, use_fma: bool, state_ports: tuple[str, ...] = (),
                 order_names: Mapping[sympy.Symbol, sympy.Symbol] | None = None,
                 sort_keys: SortKeys | None = None) -> None:
        self.use_fma = use_fma
        self.state_ports = frozenset(state_ports)
        self.order_names = dict(order_names or {})
        self.order = sort_keys if sort_keys is not None else SortKeys(self.order_names)
        """The key terms and factors are lowered in: sympy's order of an expression with
        its symbols named as in :attr:`order_names` (the symbols they copy); ``sort_keys``:
        a memo of those keys to share (its names must be ``order_names``)."""

    def lower(self, e: sympy.Basic) -> Tree:
        if is_number(e):
            return Const(constant_value(e))
        if e.is_Symbol:
            return Var(e.name)
        if e.is_Add:
            return self._add(e)
        if e.is_Mul:
            return self._product(*e.as_coeff_Mul())
        if e.is_Pow:
            return self._pow(e.base, e.exp)
        if isinstance(e, IfPresent):
            z, a, b = e.args
            if not z.is_Symbol:
                raise LoweringError(f"IfPresent tests an input element, not the expression {z}")
            return Op("select", (Var(z.name), self.lower(a), self.lower(b)))
        if isinstance(e, IfAtMost):
            v, bound, a, b = e.args
            if not bound.is_number:
                raise LoweringError(f"IfAtMost needs a numeric bound, got {bound}")
            return Op("gate", (self.lower(v), Const(constant_value(bound)), self.lower(a),
                               self.lower(b)))
        if isinstance(e, (IfGreater, IfAtLeast)):
            return Op("if_gt" if isinstance(e, IfGreater) else "if_ge",
                      tuple(self.lower(a) for a in e.args))
        name = FUNCTIONS.get(e.func)
        if name is not None:
            return Op(f"call:{name}", tuple(self.lower(a) for a in e.args))
        raise LoweringError(f"cannot emit {type(e).__name__} in {e}: generated code supports "
                            f"+ - * /, integer and half-integer powers and the functions "
                            f"{sorted(FUNCTIONS.values())} (guards: sign, Max, Min, Piecewise, "
                            "derive.guards)")

    def _power(self, base: sympy.Expr, k: int) -> Tree:
        b = self.lower(base)
        return _chain("mul", [b] * k)

    def _pow(self, base: sympy.Expr, exp: sympy.Expr) -> Tree:
        if exp.is_Integer:
            k = int(exp)
            if k > 0:
                return self._power(base, k)
            return Op("div", (Const(1.0), self._power(base, -k)))
        if exp.is_Rational and exp.q == 2:
            k = int(exp.p)
            if k < 0:
                return Op("div", (Const(1.0), self._pow(base, -exp)))
            root = Op("sqrt", (self.lower(base),))
            return root if k == 1 else Op("mul", (self._power(base, (k - 1) // 2), root))
        raise LoweringError(f"cannot emit the power {base}**{exp}: only integer and "
                            "half-integer exponents lower to * / sqrt")

    def _product(self, coeff: sympy.Expr, rest: sympy.Expr) -> Tree:
        """Tree of ``coeff * rest`` (``coeff`` a number)."""
        numerator: list[sympy.Expr] = []
        denominator: list[sympy.Expr] = []
        for factor in sympy.Mul.make_args(rest):
            if is_number(factor):
                coeff = coeff * factor
            elif factor.is_Pow and factor.exp.is_Rational and negative_number(factor.exp):
                denominator.append(sympy.Pow(factor.base, -factor.exp))
            else:
                numerator.append(factor)
        if coeff == 0:
            return Const(0.0)
        num = _chain("mul", [self.lower(f) for f in sorted(numerator, key=self.order)])
        den = _chain("mul", [self.lower(f) for f in sorted(denominator, key=self.order)])
        c = Const(constant_value(coeff))
        if den is None:
            if num is None:
                return c
            if coeff == 1:
                return num
            if coeff == -1:
                return Op("neg", (num,))
            return Op("mul", (c, num))
        if num is None:
            return Op("div", (c, den))
        if coeff == 1:
            return Op("div", (num, den))
        if coeff == -1:
            return Op("neg", (Op("div", (num, den)),))
        return Op("div", (Op("mul", (c, num)), den))

    def _add(self, e: sympy.Expr) -> Tree:
        return self.lower_sum(sympy.Add.make_args(e))

    def lower_sum(self, addends: Sequence[sympy.Expr]) -> Tree:
        """The tree of the sum of ``addends`` (the terms of a sympy Add: no two alike),
        as of ``sympy.Add(*addends)``, without building it."""
        constant = sympy.S.Zero
        terms: list[tuple[int, Tree]] = []
        for term in sorted(addends, key=self.order):
            if is_number(term):
                constant += term
                continue
            coeff, rest = term.as_coeff_Mul()
            if negative_number(coeff):
                terms.append((-1, self._product(-coeff, rest)))
            else:
                terms.append((1, self.lower(term)))
        if constant != 0:
            value = constant_value(constant)
            terms.insert(0, (1 if value > 0 else -1, Const(abs(value))))
        if not self.use_fma:
            return _signed_chain(terms)
        base: list[tuple[int, Tree]] = []
        products: list[tuple[int, Tree, Tree]] = []
        for sign, tree in terms:
            if isinstance(tree, Op) and tree.kind == "mul":
                left, right = tree.args
                if sign < 0 and isinstance(left, Const):
                    sign, left = 1, Const(-left.value)
                products.append((sign, left, right))
                continue
            base.append((sign, tree))

        def key(product: tuple[int, Tree, Tree]) -> tuple[bool, int]:
            _, left, right = product
            return (_late(left, self.state_ports) or _late(right, self.state_ports),
                    max(depth(left), depth(right)))
        products.sort(key=key)
        if base:
            acc = _signed_chain(base)
        else:
            # start at the first product, or at a positive one as early (no negation)
            start = next((k for k, p in enumerate(products)
                          if p[0] > 0 and key(p) == key(products[0])), 0)
            sign, left, right = products.pop(start)
            acc = Op("mul", (left, right)) if sign > 0 else Op("neg", (Op("mul", (left, right)),))
        for sign, left, right in products:
            acc = Op("fma" if sign > 0 else "fnma", (left, right, acc))
        return acc


#: The state a time-varying filter carries from one step to the next: (input port, the
#: output that becomes it in the next step), the default of lower_program's state ports.
#: A unit declares its own (derive.runs.unit.Unit.carried).
CARRIED = (("x", "x_new"), ("P", "P_new"))
#: Input ports that carry the filter's state from one step to the next.
STATE_PORTS = tuple(port for port, _ in CARRIED)


def _late(tree: Tree, state_ports: frozenset[str]) -> bool:
    """True when ``tree`` reads the carried state (an element of a port of
    ``state_ports``, or a temporary).

    In an fma chain such products go last, so the step-to-step dependency runs
    through as few fmas as possible: with x_new = a x0 + b x1 + c z the chain is
    fma(b, x1, fma(a, x0, c*z)), two fmas deep from the state, not three.
    """
    if isinstance(tree, Var):
        return tree.name.split("[")[0] in state_ports or "[" not in tree.name
    if isinstance(tree, Op):
        return any(_late(a, state_ports) for a in tree.args)
    return False


def _signed_chain(terms: list[tuple[int, Tree]]) -> Tree:
    start = next((k for k, (sign, _) in enumerate(terms) if sign > 0), None)
    if start is None:
        first = terms[0][1]
        # a negative constant is printed signed (-1.0), not negated: no operation
        acc: Tree = Const(-first.value) if isinstance(first, Const) else Op("neg", (first,))
        rest = terms[1:]
    else:
        acc = terms[start][1]
        rest = terms[:start] + terms[start + 1:]
    for sign, tree in rest:
        acc = Op("add" if sign > 0 else "sub", (acc, tree))
    return acc


def lower(expr: sympy.Basic, *, use_fma: bool = False) -> Tree:
    """The operation tree of one expression (see the module docstring)."""
    return ExpressionLowerer(use_fma).lower(sympy.sympify(expr))



def expression_lowerer(*, use_fma: bool = False,
                       state_ports: tuple[str, ...] = STATE_PORTS) -> RememberingLowerer:
    """One expression's tree exactly as :func:`lower_program` lowers it inside a program
    (same fma and ordering rules), remembered per expression and per subexpression, with
    each term's sort key: for passes that lower the same statements again and again,
    each time with a term or two changed (derive.schedule scores each rewrite it tries).
    Called with an expression; ``lower_sum(terms)`` lowers a sum from its terms."""
    return RememberingLowerer(use_fma, state_ports)


class RememberingLowerer(ExpressionLowerer):
    """A lowerer that lowers and orders each subexpression once (trees are immutable,
    so a remembered one is shared)."""

    def __init__(self, use_fma: bool, state_ports: tuple[str, ...]) -> None:
        super().__init__(use_fma, state_ports)
        self.trees: dict[sympy.Basic, Tree] = {}

    def __call__(self, e: sympy.Basic) -> Tree:
        return self.lower(e)

    def lower(self, e: sympy.Basic) -> Tree:
        tree = self.trees.get(e)
        if tree is None:
            tree = self.trees[e] = super().lower(e)
        return tree
