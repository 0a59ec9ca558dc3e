"""The difference form of a vector function: g(x) and D = g(x + δ) - g(x) as two
straight-line programs in which the large terms of g cancel before anything is rounded.

A sigma-point filter needs the spreads g(x + δ_i) - mean; computed as written, they
subtract numbers of the size of g (a pseudorange: 2e7 m, float32 spacing 2 m) to leave
numbers of the size of δ's effect (metres), and the rounding of g is all that is left.
The difference form derives D from g's expression tree, node by node (``e'`` the node at
x + δ, computed as ``e + D[e]``; nothing is evaluated at x + δ itself):

* ``D[x_j] = δ_j``; ``D[e] = 0`` for an ``e`` free of the state (numbers, inputs,
  parameters);
* ``D[a + b] = D[a] + D[b]``; ``D[c a] = c D[a]`` for a factor c free of the state;
  ``D[a b] = D[a] b' + a D[b]``;
* ``D[a²] = D[a] (2 a + D[a])``; ``D[a^k] = D[a a^(k-1)]`` for an integer k > 2;
  ``D[1/a] = -D[a] / (a a')``, ``D[a^-k] = D[1/a^k]``;
* ``D[sqrt(a)] = D[a] / (sqrt(a') + sqrt(a))``, ``D[a^(-1/2)] = D[1/sqrt(a)]``;
* ``D[sin a] = 2 cos(a + D[a]/2) sin(D[a]/2)``, ``D[cos a] = -2 sin(a + D[a]/2) sin(D[a]/2)``;
* ``D[atan2(y, x)] = atan2(x D[y] - y D[x], x x' + y y')``: the angle from (x, y) to
  (x', y'), an identity modulo 2 pi: it is the difference where that lies in (-pi, pi],
  and across atan2's branch cut (-pi to pi) the wrapped difference, the angle's change
  (what an angle measurement's spread is: derive.filters.ukf);
* anything else (exp, log, a state-dependent exponent, other functions) falls back to
  ``g(a') - g(a)``, with the cancellation of that one node; :attr:`DifferenceForm.fallbacks`
  names those nodes (the UKF prints them in its header).

Each rule is an identity of real numbers (atan2's modulo 2 pi), so D equals
g(x + δ) - g(x) exactly
(tests/numerics/test_float_ukf.py checks it symbolically and in double against an exact
evaluation); where a rule applies, its rounding errors are relative to D and to the
terms D sums, not to g.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import sympy


@dataclass(frozen=True)
class DifferenceForm:
    """g(x) and D = g(x + δ) - g(x) as straight-line programs.

    ``base``: ``(symbol, expression)`` pairs over the model's symbols and earlier base
    symbols (the nodes of g at x), evaluated once; ``values``: g(x) over those.
    ``steps``: pairs over the base symbols, the model's symbols, ``deltas`` and earlier
    step symbols (the nodes' differences), evaluated once per δ; ``differences``: D.
    ``fallbacks``: the nodes no rule applies to, as text, in the order met. ``turns``: the
    step symbols of atan2's rule, which are 0 where its coordinates do not move (a
    numerator x D[y] - y D[x] of 0 there, over x x' + y y' = x² + y² >= 0: atan2(0, that)
    is 0; :func:`unmoved_turn`).
    """

    deltas: tuple[sympy.Symbol, ...]
    base: tuple[tuple[sympy.Symbol, sympy.Expr], ...]
    values: tuple[sympy.Expr, ...]
    steps: tuple[tuple[sympy.Symbol, sympy.Expr], ...]
    differences: tuple[sympy.Expr, ...]
    fallbacks: tuple[str, ...]
    turns: frozenset[sympy.Symbol] = frozenset()

    def expanded(self) -> tuple[list[sympy.Expr], list[sympy.Expr]]:
        """(g(x), D) with every base and step symbol substituted back (for checks)."""
        subs: dict[sympy.Symbol, sympy.Expr] = {}
        for sym, expr in self.base + self.steps:
            subs[sym] = expr.xreplace(subs)
        return ([v.xreplace(subs) for v in self.values],
                [d.xreplace(subs) for d in self.differences])


class _Builder:
    """The recursion over g's tree; every node's base value and difference computed once."""

    def __init__(self, states: Sequence[sympy.Symbol], deltas: Sequence[sympy.Symbol]):
        self.delta_of = dict(zip(states, deltas))
        self.states = frozenset(states)
        self.base_pairs: list[tuple[sympy.Symbol, sympy.Expr]] = []
        self.step_pairs: list[tuple[sympy.Symbol, sympy.Expr]] = []
        self.fallbacks: list[str] = []
        self.turns: set[sympy.Symbol] = set()
        self._bases: dict[sympy.Expr, sympy.Expr] = {}
        self._diffs: dict[sympy.Expr, sympy.Expr] = {}
        self._base_names = sympy.numbered_symbols("_at_x", real=True)
        self._step_names = sympy.numbered_symbols("_diff", real=True)

    def varies(self, node: sympy.Expr) -> bool:
        return bool(node.free_symbols & self.states)

    def _base_let(self, expr: sympy.Expr) -> sympy.Expr:
        if expr.is_Atom or (expr.could_extract_minus_sign() and (-expr).is_Atom):
            return expr
        sym = next(self._base_names)
        self.base_pairs.append((sym, expr))
        return sym

    def _step_let(self, expr: sympy.Expr) -> sympy.Expr:
        if expr.is_Atom or (expr.could_extract_minus_sign() and (-expr).is_Atom):
            return expr
        sym = next(self._step_names)
        self.step_pairs.append((sym, expr))
        return sym

    # -- the node at x ------------------------------------------------------------------

    def base(self, node: sympy.Expr) -> sympy.Expr:
        """The node at x: itself if it is free of the state, else a base symbol."""
        if not self.varies(node) or node.is_Atom:
            return node
        if node not in self._bases:
            if node.is_Mul:
                constant, factors = self._split_mul(node)
                expr = constant * self.base(factors[0])
                if len(factors) > 1:
                    expr *= self.base(sympy.Mul(*factors[1:]))
            else:
                expr = node.func(*[self.base(a) for a in node.args])
            self._bases[node] = self._base_let(expr)
        return self._bases[node]

    def shifted(self, node: sympy.Expr) -> sympy.Expr:
        """The node at x + δ, as its value at x plus its difference."""
        return self.base(node) + self.diff(node)

    # -- the difference -----------------------------------------------------------------

    def _split_mul(self, node: sympy.Expr) -> tuple[sympy.Expr, tuple[sympy.Expr, ...]]:
        """(the product of the factors free of the state, the other factors)."""
        constant = [a for a in node.args if not self.varies(a)]
        return sympy.Mul(*constant), tuple(a for a in node.args if self.varies(a))

    def diff(self, node: sympy.Expr) -> sympy.Expr:
        """D[node]: 0, ±δ_j or a step symbol."""
        if not self.varies(node):
            return sympy.S.Zero
        if node in self.delta_of:
            return self.delta_of[node]
        if node not in self._diffs:
            self._diffs[node] = self._step_let(self._rule(node))
            if isinstance(node, sympy.atan2):
                self.turns.add(self._diffs[node])
        return self._diffs[node]

    def _rule(self, node: sympy.Expr) -> sympy.Expr:
        if node.is_Add:
            return sympy.Add(*[self.diff(a) for a in node.args])
        if node.is_Mul:
            constant, factors = self._split_mul(node)
            if len(factors) == 1:
                return constant * self.diff(factors[0])
            first, rest = factors[0], sympy.Mul(*factors[1:])
            return constant * (self.diff(first) * self.shifted(rest)
                               + self.base(first) * self.diff(rest))
        if node.is_Pow and not self.varies(node.exp):
            rule = self._power(node.base, node.exp)
            if rule is not None:
                return rule
        if isinstance(node, sympy.sin):
            return self._sin_cos(node.args[0], sympy.cos, 2)
        if isinstance(node, sympy.cos):
            return self._sin_cos(node.args[0], sympy.sin, -2)
        if isinstance(node, sympy.atan2):
            y, x = node.args
            return sympy.atan2(self.base(x) * self.diff(y) - self.base(y) * self.diff(x),
                               self.base(x) * self.shifted(x) + self.base(y) * self.shifted(y))
        return self._fallback(node)

    def _power(self, a: sympy.Expr, k: sympy.Expr) -> sympy.Expr | None:
        Da = self.diff(a)
        if k == 2:
            return Da * (2 * self.base(a) + Da)
        if k == sympy.S.Half:
            return Da / (sympy.sqrt(self.shifted(a)) + self.base(sympy.sqrt(a)))
        if k.is_Integer and k > 2:
            return self.diff(sympy.Mul(a, a ** (k - 1), evaluate=False))
        if k == -1:
            return -Da / (self.base(a) * self.shifted(a))
        if k.is_Integer and k < -1 or k == -sympy.S.Half:
            inner = a ** -k
            Di = self.diff(inner)
            return -Di / (self.base(inner) * self.shifted(inner))
        return None

    def _sin_cos(self, a: sympy.Expr, other, sign: int) -> sympy.Expr:
        """sin(a') - sin(a) = 2 cos(a + Da/2) sin(Da/2); cos: -2 sin(a + Da/2) sin(Da/2)."""
        half = self._step_let(self.diff(a) / 2)
        return sign * other(self.base(a) + half) * sympy.sin(half)

    def _fallback(self, node: sympy.Expr) -> sympy.Expr:
        self.fallbacks.append(str(node))
        return node.func(*[self.shifted(a) for a in node.args]) - self.base(node)


def difference_form(values: Iterable[sympy.Expr], states: Sequence[sympy.Symbol]
                    ) -> DifferenceForm:
    """The :class:`DifferenceForm` of ``values`` (expressions over ``states`` and other
    symbols) with respect to ``states``; the δ symbols are ``d_<state>``."""
    deltas = tuple(sympy.Symbol(f"d_{s.name}", real=True) for s in states)
    builder = _Builder(states, deltas)
    exprs = [sympy.sympify(v) for v in values]
    differences = [builder.diff(e) for e in exprs]
    bases = [builder.base(e) for e in exprs]
    return DifferenceForm(deltas, tuple(builder.base_pairs), tuple(bases),
                          tuple(builder.step_pairs), tuple(differences),
                          tuple(dict.fromkeys(builder.fallbacks)), frozenset(builder.turns))


def unmoved_turn(form: DifferenceForm, symbol: sympy.Symbol, value: sympy.Expr) -> sympy.Expr:
    """``value`` (step ``symbol``'s expression at one δ), or 0 where it is atan2's turn
    with a numerator that δ made 0 (its coordinates do not move: ``DifferenceForm.turns``)."""
    if symbol in form.turns and isinstance(value, sympy.atan2) and value.args[0] == 0:
        return sympy.S.Zero
    return value


__all__ = ["DifferenceForm", "difference_form", "unmoved_turn"]
