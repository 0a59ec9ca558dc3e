"""The latency schedule of a step: a shorter carried chain, at the price of some flops.

A run loop feeds each step's new state back into the next step, so a step cannot finish
sooner than the longest chain of dependent operations from the carried inputs (x, P) to
the carried outputs (x_new, P_new) allows (:mod:`derive.apps.latency` computes that
bound).  The optimiser (:mod:`derive.optimise`) minimises operations; this module
rewrites an optimised step so that the chain gets shorter, by three rewrites, each kept
only where it shortens the chain as the lowering (:mod:`derive.lowering`, with fma)
emits it:

* **direct sums**: a temporary that is an affine function of the inputs (in a KF, the
  predicted covariance, P H^T and the innovation variance S) is computed straight from
  the inputs as a balanced tree (terms grouped by coefficient, a group summed pairwise,
  each group joined by an fma), instead of through the chain of shared partial sums the
  optimiser built: S(k+1) comes from P(k/k) in two operations.
* **fused updates**: a product used once, in a sum, moves into it, so the lowering fuses
  it into an fma (``c - a*b`` into the negative one, ``fnma(a, b, c)``: one instruction,
  the latency of an fma).
* **the late factor last**: in a fused product whose second factor is itself a product or
  a quotient (``a * (x / d)``, the gain in ``P - PH K``), the early factors are
  multiplied first and the late one, ``1/d`` (one division by ``d`` shared by every
  such product), enters last: ``fma(a*x, 1/d, c)``, so the chain through ``d`` is one
  division and one fma.

Then the statements are ordered by when their operands are ready (independent blocks,
such as the three axes of ``mpt3d_a``, interleave), checks keeping their order and
every statement that reads a checked value staying after its check. The scheduled step is
kept only when its carried chain is shorter than the default step's (some rewrites apply
whole; the default, with the fused negative multiply-add, can be the shorter; and a step
whose chain is only as long gains nothing for its flops, while its paths between other
pairs of carried elements may be longer: a longer run-loop bound).

The search is greedy: each round tries every candidate and keeps each rewrite that lowers
the score (the latest carried output, then their sum), until none does.  A direct sum is
built (sympy) and scored only when it could be kept.  Its arrival is bounded below from
its affine form alone (:meth:`_Work._direct_bound`: the coefficient groups joined in one
chain of adds and fmas, the latest last, each group of two or more a tree of adds at
least as deep as a balanced one over its carried keys); when that bound is no sooner than
the temporary's arrival now, or the step's score with the temporary at the bound
(:meth:`Arrivals.lowers_score`) is not lower, the direct sum is refused unbuilt.  The
score is monotone in each arrival, so this refuses exactly what scoring the built sum
would; the new temporaries' names it would have taken are spent all the same (names
order sympy's terms, so every later rewrite is as before): the programs are bitwise
those of building every candidate.  A late-factor rewrite is refused the same way:
first on a bound (each leaf of the rewritten sum reaches it through at least one
operation), then on the sum's exact arrival, lowered from its terms without building the
sympy sum (:meth:`derive.lowering.RememberingLowerer.lower_sum`); only a rewrite that
lowers the score is built.  On a dense step a direct sum is a chain of hundreds
of terms (distinct coefficients) that never wins, and the search spends its time on the
affine forms (exact: integer numerators over a common denominator, each statement's
kept across passes while it and its operands' forms stay the same) and on lowering.

Decisions use :data:`REFERENCE_CYCLES`, never a measurement, so generation stays
deterministic.  The rewrites change rounding (a direct sum, a reciprocal), not the
mathematics; the added flops are what :func:`derive.flops.count` counts on the result.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from fractions import Fraction

import sympy
from sympy import default_sort_key

from derive import monomials
from derive.arrivals import Arrivals, Form, arrival_times, statement_form
from derive.expression_lowering import CARRIED, expression_lowerer
from derive.program import Program
from derive.runs.unit import Unit
from derive.single_use import is_product, read_counts
from derive.statements import (
    Assign,
    Check,
    InputElement,
    Statement,
    Temporary,
    live_statements,
    rename,
)
from derive.trees import count_trees

#: A reference latency model in cycles (a Skylake-class x86-64 core: its documented
#: latencies for double add, multiply, fma, divide and square root; a call of a math
#: function taken as 40). The schedule decides with it; ``derive burden`` reports chains
#: in it; ``derive bench`` and ``derive burden --measure`` use latencies measured on the
#: machine instead.
REFERENCE_CYCLES = {"add": 4.0, "mul": 4.0, "fma": 4.0, "div": 14.0, "sqrt": 18.0,
                    "call": 40.0}

#: Floating-point operations issued a cycle by the widest cores today (four pipes: AMD's
#: Zen 2 to 5, Apple's M series, Arm's Neoverse V2; the reference core, like Intel's, has
#: two), so a step's arithmetic at this rate is a lower bound on its time on any of them.
WIDEST_ISSUE = 4
#: Cycles the reference core's divider is busy per double division and square root.
REFERENCE_DIVIDER = {"div": 4.0, "sqrt": 4.5}

_ONE = sympy.S.One
_ROUNDS = 3


def latency_schedule(program: Program,
                     carried: Sequence[tuple[str, str]] = CARRIED) -> Program:
    """``program`` (a step; optimised first) rewritten for a short carried chain; the
    same program when it carries nothing (``carried``: (input port, output port) pairs,
    as :data:`derive.expression_lowering.CARRIED`)."""
    work = _Work.of(program, carried)
    return program.optimize() if work is None else work.scheduled()


def _carried_pairs(program: Program, carried: Sequence[tuple[str, str]]
                   ) -> list[tuple[str, str]]:
    """The pairs of ``carried`` whose input and output ``program`` has."""
    inputs = {p.name for p in program.inputs}
    return [(port, out) for port, out in carried
            if port in inputs and out in program.results]


def _chain(program: Program, pairs: list[tuple[str, str]]) -> float:
    """The longest chain from a carried input to a carried output of ``program``, in
    :data:`REFERENCE_CYCLES` as the lowering (with fma) emits it."""
    return _Work(program, pairs).arrivals(list(program.body)).score()[0]


def one_step_chain(program: Program,
                   carried: Sequence[tuple[str, str]] = CARRIED) -> float:
    """The score of the search: the longest chain through one step (optimised) from a
    carried input to a carried output, in :data:`REFERENCE_CYCLES` (0 when none
    carries)."""
    program = program.optimize()
    pairs = _carried_pairs(program, carried)
    return _chain(program, pairs) if pairs else 0.0


def _merge(body: Sequence[Statement]) -> tuple[list[Statement], dict]:
    """Each right-hand side computed once: a later temporary with the same expression as
    an earlier one reads the earlier one (the second item: ``{dropped: kept}``)."""
    seen: dict[sympy.Expr, Temporary] = {}
    names: dict[sympy.Symbol, sympy.Symbol] = {}
    out: list[Statement] = []
    for st in body:
        if isinstance(st, Check):
            out.append(replace(st, value=st.value.xreplace(names)))
            continue
        expr = st.expr.xreplace(names)
        if expr in seen:
            names[st.target] = seen[expr]
            continue
        seen[expr] = st.target
        out.append(Assign(st.target, expr))
    return out, names


def _coefficient(number: sympy.Expr):
    """A number of a form: a rational as a :class:`~fractions.Fraction` (plain Python
    arithmetic, exact), any other number as it is."""
    return Fraction(int(number.p), int(number.q)) if number.is_Rational else number


def _number(coefficient) -> sympy.Expr:
    """A form's number as sympy builds it (a Fraction as the Rational it is)."""
    if isinstance(coefficient, Fraction):
        return sympy.Rational(coefficient.numerator, coefficient.denominator)
    return sympy.sympify(coefficient)


class _Affine(Mapping):
    """An affine form: ``{input element or 1: coefficient}`` (the constant under key 1).

    Held as integers over one denominator (``den``; ``nums`` the numerators, reduced to
    lowest terms) so that the sums and products of forms are plain integer arithmetic;
    read as a mapping, a coefficient is the :class:`~fractions.Fraction` it is.  When a
    coefficient is not rational (``den`` None), ``nums`` holds the coefficients
    themselves (sympy numbers and Fractions).  Never changed once made."""

    __slots__ = ("den", "nums", "_groups")

    def __init__(self, den: int | None, nums: dict) -> None:
        self.den = den
        self.nums = nums
        self._groups: dict | None = None

    @classmethod
    def reduced(cls, den: int, nums: dict) -> _Affine:
        common = math.gcd(den, *nums.values())
        if common > 1:
            return cls(den // common, {k: v // common for k, v in nums.items()})
        return cls(den, nums)

    def __getitem__(self, key):
        value = self.nums[key]
        return value if self.den is None else Fraction(value, self.den)

    def __iter__(self):
        return iter(self.nums)

    def __len__(self) -> int:
        return len(self.nums)

    def __contains__(self, key) -> bool:
        return key in self.nums

    def __eq__(self, other: object) -> bool:
        if isinstance(other, _Affine):
            return self.den == other.den and self.nums == other.nums
        return NotImplemented

    __hash__ = None

    def groups(self) -> dict:
        """The keys (not the constant) by coefficient, each group in the form's order."""
        if self._groups is None:
            groups: dict = {}
            for key, value in self.nums.items():
                if key is not _ONE:
                    groups.setdefault(value, []).append(key)
            self._groups = groups
        return self._groups


def _affine(expr: sympy.Expr, forms: Mapping) -> _Affine | None:
    """The :class:`_Affine` form of an affine ``expr`` (temporaries by their ``forms``),
    None otherwise.  A temporary's form is shared, not copied."""
    if expr.is_number:
        if expr.is_Rational:
            return _Affine(int(expr.q), {_ONE: int(expr.p)})
        return _Affine(None, {_ONE: expr})
    if isinstance(expr, InputElement):
        return _Affine(1, {expr: 1})
    if isinstance(expr, Temporary):
        return forms.get(expr)
    if expr.is_Add:
        parts = []
        for arg in expr.args:
            form = _affine(arg, forms)
            if form is None:
                return None
            parts.append(form)
        total: dict = {}
        if any(part.den is None for part in parts):
            for part in parts:
                for key, value in part.items():
                    total[key] = total.get(key, 0) + value
            return _Affine(None, {k: v for k, v in total.items() if v != 0})
        den = math.lcm(*(part.den for part in parts))
        for part in parts:
            scale = den // part.den
            for key, num in part.nums.items():
                total[key] = total.get(key, 0) + num * scale
        return _Affine.reduced(den, {k: v for k, v in total.items() if v})
    if expr.is_Mul:
        coeff, rest = expr.as_coeff_Mul()
        if coeff == 1 or rest.is_Mul:
            return None
        form = _affine(rest, forms)
        if form is None:
            return None
        if form.den is None or not coeff.is_Rational:
            factor = _coefficient(coeff)
            return _Affine(None, {k: factor * v for k, v in form.items()})
        p = int(coeff.p)
        return _Affine.reduced(form.den * int(coeff.q), {k: v * p for k, v in form.nums.items()})
    return None


def _late_key(key: sympy.Expr, carried_ports: set[str]) -> bool:
    """An input element of a carried port (it arrives at 0; any other never does)."""
    return isinstance(key, InputElement) and key.name.split("[")[0] in carried_ports


class _Unbuilt:
    """A direct sum that was not built (its bound showed it could not be kept): equal to
    an expression only where the direct sum would have been, so :meth:`_Work.prune`
    decides as if it had been built.  ``fresh``: it would have read new temporaries,
    which no statement reads."""

    def __init__(self, form: _Affine, fresh: bool) -> None:
        self.form = form
        self.fresh = fresh

    def __eq__(self, expr: object) -> bool:
        return not self.fresh and isinstance(expr, sympy.Basic) and \
            _is_flat_direct_sum(expr, self.form) is True

    def __ne__(self, expr: object) -> bool:
        return not self.__eq__(expr)

    __hash__ = None


def _is_flat_direct_sum(expr: sympy.Expr, form: _Affine) -> bool | None:
    """Whether ``expr`` is the direct sum of ``form`` when no two of its keys share a
    coefficient (``const + c1*k1 + c2*k2 + ...``), read off its terms; None when a
    coefficient is not rational (then only building it tells)."""
    if form.den is None:
        return None
    const = form.get(_ONE, 0)
    terms = sympy.Add.make_args(expr)
    if len(terms) != len(form) - (_ONE in form) + (const != 0):
        return False
    for term in terms:
        if term.is_number:
            if not term.is_Rational or _coefficient(term) != const or const == 0:
                return False
            continue
        coeff, rest = term.as_coeff_Mul()
        if not (coeff.is_Rational and isinstance(rest, InputElement)) or \
                form.get(rest) != _coefficient(coeff):
            return False
    return True


class _Work:
    """The rewrites of one step, scored on the lowered step in reference cycles.

    A rewrite takes the step under edit (:class:`_Slots`) and its arrivals
    (:class:`~derive.arrivals.Arrivals`) and returns the statements it adds or changes,
    in the step's order, and where they go (None if it does not apply); the search
    scores only what the edit changes (:meth:`Arrivals.trial`)."""

    def __init__(self, program: Program, pairs: list[tuple[str, str]]) -> None:
        self.program = program
        self.pairs = pairs
        self.results = program.results
        self.carried_ports = {port for port, _ in pairs}
        self.leaves = [leaf for _, out in pairs for leaf in self.results[out]]
        self.original = {st.target: st.expr for st in program.body if isinstance(st, Assign)}
        self.counter = 0
        self.reciprocals: dict[sympy.Expr, Temporary] = {}
        self.directs: dict[Temporary, sympy.Expr | _Unbuilt] = {}
        self.affine_memo: dict[Temporary, tuple] = {}
        self.lower = expression_lowerer(use_fma=True, state_ports=tuple(self.carried_ports))
        self.forms: dict[sympy.Expr, Form] = {}
        self.leaves_of: dict[sympy.Expr, tuple[tuple[str, ...], bool]] = {}
        self.term_sets: dict[sympy.Expr, frozenset[sympy.Expr]] = {}
        self.latest_terms: dict[sympy.Expr, tuple] = {}

    @classmethod
    def of(cls, program: Program, carried: Sequence[tuple[str, str]]) -> _Work | None:
        """The work of scheduling step ``program`` (optimised first); None when it
        carries nothing."""
        program = program.optimize()
        pairs = _carried_pairs(program, carried)
        return cls(program, pairs) if pairs else None

    def scheduled(self) -> Program:
        """The step in the latency schedule (the greedy rounds, then the order), or the
        step as it is when the schedule's chain would be longer."""
        program = self.program
        body = list(program.body)
        default_chain = self.arrivals(body).score()[0]
        for _ in range(_ROUNDS):
            before = body
            body = self.fuse(body)
            body = self.greedy(body, self.direct_candidates)
            body = self.fuse(body)
            body = self.greedy(body, self.late_candidates)
            body = self.share_reciprocals(body)
            if body == before:
                break
        body = self.prune(body)
        body, merged = _merge(live_statements(body, program.results))
        self.results = {name: tuple(v.xreplace(merged) for v in values)
                        for name, values in self.results.items()}
        scheduled = self.build(self.order(body))
        # the rounds apply some rewrites whole (fusing, shared reciprocals): the step as
        # scheduled is kept only when its carried chain is shorter than the default's
        if _chain(scheduled, self.pairs) >= default_chain:
            return program
        return scheduled

    def issue_limit(self) -> str | None:
        """:func:`issue_limited` of the step."""
        body = list(self.program.body)
        chain = self.arrivals(body).score()[0]
        counts = count_trees(self.lower(st.expr) for st in body if isinstance(st, Assign))
        issue = counts.flops / 2 / WIDEST_ISSUE
        divider = sum(REFERENCE_DIVIDER[kind] * getattr(counts, kind)
                      for kind in REFERENCE_DIVIDER)
        if issue < max(chain, divider):
            return None
        return (f"the step's {counts.flops} flops are at least {counts.flops / 2:g} "
                f"arithmetic instructions (an fma does two), {issue:g} cycles or more to "
                f"issue at {WIDEST_ISSUE} a cycle (the widest cores' rate): at least its "
                f"carried chain ({chain:g} reference cycles) and its divider's {divider:g} "
                "cycles, so a shorter chain cannot make the run loop faster and the "
                "schedule's extra flops would slow it; the default schedule is kept")

    def fresh(self) -> Temporary:
        self.counter += 1
        return Temporary(f"s{self.counter}")

    # -- building and scoring ------------------------------------------------------------

    def build(self, body: Sequence[Statement]) -> Program:
        """The final program: temporaries renumbered t0, t1, ... in order."""
        names: dict[sympy.Symbol, sympy.Symbol] = {}
        for st in body:
            if isinstance(st, Assign):
                names[st.target] = Temporary(f"t{len(names)}")
        out: list[Statement] = [
            Assign(names[st.target], rename(st.expr, names)) if isinstance(st, Assign)
            else replace(st, value=rename(st.value, names)) for st in body]
        results = {name: tuple(rename(v, names) for v in values)
                   for name, values in self.results.items()}
        return self.program._final(out, results)   # an optimised program, final as is

    def form(self, expr: sympy.Expr) -> Form:
        """The arrival form of ``expr`` as the lowering (with fma) emits it."""
        form = self.forms.get(expr)
        if form is None:
            form = self.forms[expr] = statement_form(self.lower(expr), self.carried_ports,
                                                     REFERENCE_CYCLES)
        return form

    def arrivals(self, body: Sequence[Statement]) -> Arrivals:
        """Per temporary of ``body``: the latest a carried input reaches it (reference
        cycles), and the score of the carried outputs: (longest chain, their sum)."""
        return Arrivals(body, self.form, self._carried_leaf_names())

    def _carried_leaf_names(self) -> list[str]:
        return [leaf.name for leaf in self.leaves if isinstance(leaf, Temporary)]

    def greedy(self, body: list[Statement],
               candidates: Callable[[list[Statement], Arrivals], list[Callable]]
               ) -> list[Statement]:
        """Apply each candidate rewrite that lowers the score, until none does."""
        state = self.arrivals(body)
        slots = _Slots(body)
        improved = True
        while improved:
            improved = False
            for rewrite in candidates(body, state):
                edit = rewrite(slots, state)
                if edit is None:
                    continue
                changed, placements = edit
                trial = state.trial(changed)
                if trial.score() < state.score():
                    state.accept(trial)
                    slots.place(placements)
                    improved = True
            body = slots.body()
        return body

    def prune(self, body: list[Statement]) -> list[Statement]:
        """Undo each direct sum whose undoing leaves the longest chain as it is."""
        state = self.arrivals(body)
        best = state.score()[0]
        first = {}
        for k, st in enumerate(body):
            if isinstance(st, Assign):
                first.setdefault(st.target, k)
        for k in reversed(range(len(body))):
            st = body[k]
            if not isinstance(st, Assign) or self.directs.get(st.target) != st.expr or \
                    st.target not in self.original:
                continue
            original = self.original[st.target]
            if any(isinstance(s, Temporary) and first.get(s, k) >= k
                   for s in original.free_symbols):
                continue
            undone = Assign(st.target, original)
            trial = state.trial([undone])
            if trial.score()[0] <= best:
                state.accept(trial)
                body = body[:k] + [undone] + body[k + 1:]
        return body

    # -- the rewrites --------------------------------------------------------------------

    def direct_candidates(self, body: list[Statement], state: Arrivals) -> list[Callable]:
        """Direct sums of the affine temporaries, the latest first."""
        forms = self._affine_forms(body)
        ready = state.ready
        found = [(target, form) for target, form in forms.items()
                 if sum(1 for key in form if key is not _ONE) >= 2]
        found.sort(key=lambda tf: (-ready.get(tf[0].name, -math.inf),
                                   default_sort_key(tf[0])))
        return [lambda slots, s, t=target, f=form: self._direct(slots, s, t, f)
                for target, form in found]

    def _affine_forms(self, body: list[Statement]) -> dict:
        """The affine form of each affine temporary of ``body``.  A statement whose
        expression and whose operands' forms are those of an earlier call keeps its form
        (the same object); a form computed again that equals the target's earlier one is
        that one, so what reads it keeps its own too."""
        forms: dict = {}
        for st in body:
            if not isinstance(st, Assign):
                continue
            seen = self.affine_memo.get(st.target)
            if seen is not None and seen[0] is st.expr and \
                    all(forms.get(t) is f for t, f in seen[1]):
                form = seen[2]
            else:
                operands = seen[3] if seen is not None and seen[0] is st.expr else \
                    tuple(s for s in st.expr.free_symbols if isinstance(s, Temporary))
                form = _affine(st.expr, forms)
                if seen is not None and form is not None and seen[2] == form:
                    form = seen[2]
                self.affine_memo[st.target] = (
                    st.expr, tuple((t, forms.get(t)) for t in operands), form, operands)
            if form is not None:
                forms[st.target] = form
        return forms

    def _direct(self, slots: _Slots, state: Arrivals, target: Temporary, form: _Affine):
        groups = form.groups()
        fresh = sum(len(keys) - 1 for keys in groups.values())
        bound = self._direct_bound(groups, _ONE in form)
        # no sooner than now: nothing downstream gets sooner (the trial would show it)
        if state.lowers_score(target.name, bound):
            return self._build_direct(slots, target, form)
        # it cannot lower the score: not built, as if built and refused (its new
        # temporaries' names spent: the names order sympy's terms, so later ones stay)
        if fresh:
            self.counter += fresh
            self.directs[target] = _Unbuilt(form, True)
            return None
        built = _is_flat_direct_sum(slots.statement(target).expr, form)
        if built is None:
            return self._build_direct(slots, target, form)
        if not built:
            self.directs[target] = _Unbuilt(form, False)
        return None

    def _direct_bound(self, groups: Mapping, constant: bool) -> float:
        """A lower bound of the arrival of a direct sum (its coefficient groups), however
        sympy orders its terms: the lowering joins the groups (and the constant) in one
        chain of adds and fmas; each group of two or more is a tree of adds, at least as
        deep as a balanced one over its carried keys.  A chain of k terms arrives no
        sooner than with the latest term last (the first two pass k - 1 operations, the
        j-th k - j + 1)."""
        add = REFERENCE_CYCLES["add"]
        step = min(add, REFERENCE_CYCLES["fma"])
        times = []
        for keys in groups.values():
            carried = sum(1 for key in keys if _late_key(key, self.carried_ports))
            if not carried:
                times.append(-math.inf)
            elif len(keys) == 1:
                times.append(0.0)
            else:
                times.append(add * max(1, math.ceil(math.log2(carried))))
        if constant:
            times.append(-math.inf)
        times.sort()
        k = len(times)
        return max(t + step * (k - 1 if j == 0 else k - j) for j, t in enumerate(times))

    def _build_direct(self, slots: _Slots, target: Temporary, form: _Affine):
        const = _number(form.get(_ONE, 0))
        groups: dict = {}
        for key in sorted((key for key in form if key is not _ONE), key=default_sort_key):
            groups.setdefault(form[key], []).append(key)
        new: list[Statement] = []
        terms = []
        for coeff in sorted(groups, key=lambda c: default_sort_key(_number(c))):
            level = groups[coeff]
            while len(level) > 1:
                paired = []
                for a, b in zip(level[0::2], level[1::2], strict=False):
                    t = self.fresh()
                    new.append(Assign(t, a + b))
                    paired.append(t)
                if len(level) % 2:
                    paired.append(level[-1])
                level = paired
            terms.append(_number(coeff) * level[0])
        expr = sympy.Add(const, *terms)
        if expr == slots.statement(target).expr:
            return None
        self.directs[target] = expr
        changed = new + [Assign(target, expr)]
        return changed, [(target, changed)]

    def fuse(self, body: list[Statement]) -> list[Statement]:
        """Move each product used once, in a sum, into that sum (an fma when lowered)."""
        uses = read_counts(live_statements(body, self.results), self.results)
        define = {st.target: st.expr for st in body if isinstance(st, Assign)}
        out: list[Statement] = []
        done: set[sympy.Symbol] = set()
        for st in body:
            if not (isinstance(st, Assign) and st.expr.is_Add):
                _append(out, done, st)
                continue
            terms = []
            fused = False
            for term in sympy.Add.make_args(st.expr):
                coeff, rest = term.as_coeff_Mul()
                product = define.get(rest)
                if not (isinstance(rest, Temporary) and uses.get(rest) == 1 and
                        product is not None and is_product(product)):
                    terms.append(term)
                    continue
                p_coeff, factors = product.as_coeff_Mul()
                terms.append(coeff * p_coeff * factors)
                fused = True
            if not fused:       # its own terms: the sum as it is
                _append(out, done, st)
                continue
            expr = sympy.Add(*terms)
            _append(out, done, st if expr == st.expr else Assign(st.target, expr))
        return out if out != body else body

    def late_candidates(self, body: list[Statement], state: Arrivals) -> list[Callable]:
        """For each product ``a * q`` in a sum, ``q`` a product or quotient: the early
        factors first, the late one (a reciprocal for a quotient) last."""
        define = {st.target: st.expr for st in body if isinstance(st, Assign)}
        found = []
        for st in body:
            if not (isinstance(st, Assign) and st.expr.is_Add):
                continue
            for term in sympy.Add.make_args(st.expr):
                if not term.is_Mul:
                    continue
                for factor in term.args:
                    inner = define.get(factor)
                    if isinstance(factor, Temporary) and inner is not None and inner.is_Mul:
                        found.append(lambda slots, s, t=st.target, m=term, f=factor:
                                     self._late(slots, s, t, m, f))
        return found

    def _late(self, slots: _Slots, state: Arrivals, target: Temporary, term: sympy.Expr,
              factor: Temporary):
        current = slots.statement(target)
        if current is None or term not in self._terms(current.expr):
            return None
        inner = slots.statement(factor).expr
        ready = state.ready

        def when(a: sympy.Expr) -> float:
            base = a.base if a.is_Pow else a
            extra = REFERENCE_CYCLES["div"] if a.is_Pow else 0.0
            return ready.get(getattr(base, "name", ""), -math.inf) + extra

        coeff, rest = inner.as_coeff_Mul()
        args = sorted(sympy.Mul.make_args(rest), key=lambda a: (when(a), self.lower.order(a)))
        last = args[-1]
        reciprocal = None
        if last.is_Pow:
            if last.exp != -1:
                return None
            late = self.reciprocals.get(last.base)
            if late is None:
                late = self.reciprocals[last.base] = self.fresh()
            if slots.statement(late) is None:
                reciprocal = Assign(late, 1 / last.base)
        else:
            late = last
        early = [a for a in sympy.Mul.make_args(term) if a != factor]
        w = self.fresh()
        if not self._late_may_win(state, target, current.expr, term, [*early, *args[:-1]],
                                  late, reciprocal):
            return None   # refused unbuilt, its names spent as if built and refused
        product = Assign(w, sympy.Mul(coeff, *early, *args[:-1]))
        key = hash(term)
        terms = [monomials.product(w, late) if hash(t) == key and t == term else t
                 for t in sympy.Add.make_args(current.expr)]
        if not self._late_wins(state, target, terms, product, reciprocal):
            return None
        changed = [product, Assign(target, sympy.Add(*terms))]
        placements = [(target, changed)]
        if reciprocal is not None:
            before = slots.statement(last.base)
            placements.append((last.base, [before, reciprocal]) if before is not None
                              else (None, [reciprocal]))
            changed = [reciprocal, *changed]
        return changed, placements

    def _terms(self, expr: sympy.Expr) -> frozenset[sympy.Expr]:
        """The terms of the sum ``expr``, as a set (a sum of hundreds of terms is asked
        whether it holds one for each rewrite tried on it)."""
        terms = self.term_sets.get(expr)
        if terms is None:
            terms = self.term_sets[expr] = frozenset(sympy.Add.make_args(expr))
        return terms

    def _late_may_win(self, state: Arrivals, target: Temporary, current: sympy.Expr,
                      term: sympy.Expr, early: list[sympy.Expr], late: sympy.Expr,
                      reciprocal: Assign | None) -> bool:
        """Whether the rewrite of :meth:`_late` could lower the score, from a lower bound
        of the rewritten sum's arrival: the sum (two terms or more) is a tree whose root
        is an operation, so each of its leaves (the other terms' operands, those of the
        early product ``w``, the late factor) reaches it through at least the quickest
        operation, and a new reciprocal arrives a division after its base.  The score is
        monotone in each arrival, so refusing on the bound refuses exactly what scoring
        the built rewrite would, without building the sum (hundreds of terms in a
        Joseph-form P) or lowering it."""
        ready = state.ready
        step = min(REFERENCE_CYCLES[kind] for kind in ("add", "mul", "fma"))
        if reciprocal is not None:
            late_ready = self._leaf_ready(reciprocal.expr, ready) + REFERENCE_CYCLES["div"]
        else:
            late_ready = self._leaf_ready(late, ready)
        bound = max([late_ready, *(self._leaf_ready(a, ready) for a in early),
                     self._others_ready(state, current, term)]) + step
        return state.lowers_score(target.name, bound)

    def _others_ready(self, state: Arrivals, current: sympy.Expr, term: sympy.Expr) -> float:
        """The latest leaf arrival of the terms of the sum ``current`` other than ``term``
        (``-inf`` when none arrives): from the sum's two latest terms, remembered until
        the state accepts an edit (each of a sum's terms is tried in turn)."""
        known = self.latest_terms.get(current)
        if known is None or known[0] is not state or known[1] != state.version:
            first = second = -math.inf
            first_term = None
            for t in sympy.Add.make_args(current):
                at = self._leaf_ready(t, state.ready)
                if at > first:
                    first, second, first_term = at, first, t
                elif at > second:
                    second = at
            known = self.latest_terms[current] = (state, state.version, first, first_term,
                                                  second)
        _, _, first, first_term, second = known
        return second if first_term is not None and first_term == term else first

    def _late_wins(self, state: Arrivals, target: Temporary, terms: list[sympy.Expr],
                   product: Assign, reciprocal: Assign | None) -> bool:
        """Whether the rewrite of :meth:`_late` lowers the score: the arrival of the
        rewritten sum exactly as :meth:`Arrivals.trial` takes it, lowered from its terms
        (no sympy sum built); its new temporaries are read by it alone."""
        moved = {}

        def ready(name: str) -> float:
            value = moved.get(name)
            return state.ready.get(name, -math.inf) if value is None else value

        for st in (reciprocal, product):
            if st is not None:
                moved[st.target.name] = self.form(st.expr).arrival(ready)
        form = statement_form(self.lower.lower_sum(terms), self.carried_ports,
                              REFERENCE_CYCLES)
        return state.lowers_score(target.name, form.arrival(ready))

    def _leaf_ready(self, expr: sympy.Expr, ready: Mapping[str, float]) -> float:
        """The latest arrival of ``expr``'s leaves: its temporaries as ``ready``, a carried
        input element at 0 (``-inf`` when none arrives)."""
        leaves = self.leaves_of.get(expr)
        if leaves is None:
            leaves = self.leaves_of[expr] = (
                tuple(s.name for s in expr.free_symbols if isinstance(s, Temporary)),
                any(_late_key(s, self.carried_ports) for s in expr.free_symbols))
        names, carried = leaves
        latest = 0.0 if carried else -math.inf
        for name in names:
            at = ready.get(name, -math.inf)
            if at > latest:
                latest = at
        return latest

    def share_reciprocals(self, body: list[Statement]) -> list[Statement]:
        """Every other division by a value whose reciprocal the step computes becomes a
        multiplication by it (one division for all)."""
        present = {st.target for st in body if isinstance(st, Assign)}
        swap = {sympy.Pow(d, -1): r for d, r in self.reciprocals.items() if r in present}
        if not swap:
            return body
        reciprocals = set(swap.values())
        out = [st if not isinstance(st, Assign) or st.target in reciprocals
               else Assign(st.target, st.expr.xreplace(swap)) for st in body]
        return out if out != body else body

    # -- the order -----------------------------------------------------------------------

    def order(self, body: list[Statement]) -> list[Statement]:
        """Statements by when their operands are ready (ties: as they were); checks in
        their order, and what reads a checked value after its check."""
        ready = arrival_times(body, self.form)
        defined = {st.target: k for k, st in enumerate(body) if isinstance(st, Assign)}
        checks = [k for k, st in enumerate(body) if isinstance(st, Check)]
        checked: dict[sympy.Symbol, int] = {}
        for k in checks:
            for s in body[k].value.free_symbols:
                checked.setdefault(s, k)
        after: dict[int, set[int]] = {k: set() for k in range(len(body))}
        for k, st in enumerate(body):
            expr = st.expr if isinstance(st, Assign) else st.value
            for s in expr.free_symbols:
                if s in defined:
                    after[k].add(defined[s])
                if isinstance(st, Assign) and s in checked:
                    after[k].add(checked[s])
        for earlier, later in zip(checks, checks[1:]):
            after[later].add(earlier)

        def key(k: int) -> tuple[float, int]:
            st = body[k]
            name = st.target.name if isinstance(st, Assign) else None
            value = ready.get(name, -math.inf) if name else -math.inf
            return (value if value > -math.inf else -1.0, k)

        # the statement of least key among those whose predecessors are all placed
        waiting = {k: len(before) for k, before in after.items()}
        followers: dict[int, list[int]] = {}
        for k, before in after.items():
            for j in before:
                followers.setdefault(j, []).append(k)
        free = [key(k) for k, count in waiting.items() if count == 0]
        heapq.heapify(free)
        out: list[Statement] = []
        while free:
            _, k = heapq.heappop(free)
            out.append(body[k])
            for j in followers.get(k, ()):
                waiting[j] -= 1
                if waiting[j] == 0:
                    heapq.heappush(free, key(j))
        if len(out) != len(body):
            raise ValueError("the step's statements depend on each other in a cycle")
        return out


class _Slots:
    """A step under edit: each statement of the step as given holds a slot, and an edit
    puts statements in the place of one (so a temporary's slot never moves however many
    are inserted before it); the step is the slots in order."""

    def __init__(self, body: Sequence[Statement]) -> None:
        self.slots = [[st] for st in body]
        self.slot: dict[sympy.Symbol, int] = {}
        for k, st in enumerate(body):
            if isinstance(st, Assign):
                self.slot.setdefault(st.target, k)

    def statement(self, target: sympy.Symbol) -> Assign | None:
        """The first statement that defines ``target`` (None if none does)."""
        k = self.slot.get(target)
        if k is None:
            return None
        return next(st for st in self.slots[k]
                    if isinstance(st, Assign) and st.target == target)

    def place(self, placements: Sequence[tuple[sympy.Symbol | None, list[Statement]]]
              ) -> None:
        """Each ``(target, statements)``: ``statements`` in the place of ``target``'s
        first definition (``target`` None: before the whole step)."""
        for target, statements in placements:
            k = 0 if target is None else self.slot[target]
            slot = self.slots[k]
            at = 0 if target is None else next(
                i for i, st in enumerate(slot) if isinstance(st, Assign) and st.target == target)
            slot[at:at + (target is not None)] = statements
            for st in statements:
                if isinstance(st, Assign):
                    self.slot.setdefault(st.target, k)

    def body(self) -> list[Statement]:
        return [st for slot in self.slots for st in slot]


def _append(out: list[Statement], done: set[sympy.Symbol], st: Statement) -> None:
    out.append(st)
    if isinstance(st, Assign):
        done.add(st.target)


def scheduled_unit(unit: Unit) -> Unit:
    """``unit`` with its step in the latency schedule (its carried state as the unit
    declares it)."""
    step = latency_schedule(unit.programs["step"], unit.carried)
    return replace(unit, programs={**unit.programs, "step": step})


def latency_scheduled_unit(unit: Unit) -> Unit:
    """What the option ``latency_schedule`` makes of ``unit``: :func:`scheduled_unit`
    where the carried chain or the divider can limit the run loop, else ``unit`` as it
    is, with a header line that says why (:func:`issue_limited`)."""
    work = _Work.of(unit.programs["step"], unit.carried)
    why = None if work is None else work.issue_limit()
    if why is not None:
        return replace(unit, facts=(*unit.facts, f"latency schedule: not applied: {why}"))
    step = unit.programs["step"].optimize() if work is None else work.scheduled()
    return replace(unit, programs={**unit.programs, "step": step})


def issue_limited(program: Program, carried: Sequence[tuple[str, str]] = CARRIED
                  ) -> str | None:
    """Why the latency schedule cannot make a run loop of step ``program`` faster, or None
    when it can.  A loop step takes at least as long as its carried chain, as its
    divisions and square roots keep the divider busy, and as its arithmetic takes to
    issue.  The schedule shortens the chain and shares divisions, at the price of flops.
    A step of F flops issues at least F/2 arithmetic instructions (an fma does two), so
    at :data:`WIDEST_ISSUE` a cycle it takes at least F/8 cycles on today's cores; when
    that is as long as the default step's chain (:data:`REFERENCE_CYCLES`) and its
    divider time (:data:`REFERENCE_DIVIDER`), issue is the limit, and the schedule's
    extra flops can only add to it (a 32-state Joseph-form KF: a chain of a few hundred
    cycles, thousands of cycles of arithmetic)."""
    work = _Work.of(program, carried)
    return None if work is None else work.issue_limit()
