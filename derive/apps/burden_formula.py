"""The burden formula of an algorithm, derived from its generated code by exact interpolation.

A *family* is one filter counted at many sizes:

- ``paper``: derive's paper mode (:mod:`derive.apps.paper`), the dense, unspecialised
  algorithm, at sizes n, m (the FIR also at its order N);
- ``dense``: derive's specialised code on dense random n x m models (:func:`dense_model`,
  one seed; the FIR also at its order N);
- ``blocks``: derive's specialised code on k independent copies of one block model.

:func:`derive_formula` counts the generated ``step`` (:func:`derive.flops.count`, on the
Python lowering and on the C lowering with fused multiply-adds) at sizes of an integer grid,
solves exactly (fractions, no floating point) for the coefficients of the polynomial of total
degree <= d in the family's variables that passes through them, and checks it at further
sizes the fit did not use. The fit sizes are the smallest that determine a polynomial of
degree d (chosen in order of size, each one kept if it is independent of those before it);
where the check fails, d is raised and the polynomial fit again, up to a bound. Each kind of
operation of each lowering, and the flops in the papers' convention (an fma two), gets its
own polynomial, or the sizes where no polynomial of degree <= the bound fits (a count that
depends on the pattern of the numbers, not only on the sizes).

:func:`audit_formula` compares a formula's text (parsed by
:func:`derive.apps.formulas.parse_formula`: nothing executes) with a derived polynomial:
the difference, the terms that differ, and the smallest sizes where they disagree.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from functools import cache

import numpy as np
import sympy

from ..errors import FilterError, ModelError
from ..filters import available, derive_unit
from ..flops import LANGUAGES, count
from ..model import LinearModel
from ..trees import OpCount
from . import formulas, paper

KINDS = ("add", "sub", "mul", "div", "sqrt", "fma", "neg", "cmp", "calls")
#: The series fit: the flops (papers' convention), then every kind of each lowering.
SERIES = ("flops",) + tuple(f"{lang}.{kind}" for lang in LANGUAGES for kind in KINDS)
MODES = ("paper", "dense", "blocks")

DEGREE = 3
MAX_DEGREE = 5
#: How far the smallest fit size is raised, within each degree bound, when a fit fails.
RAISE = 2
#: Default check sizes, none of them a fit size of degree <= 3 (the fits take the smallest
#: sizes); (6, 3) is MPT3D model A's, which the audit counts anyway.
CHECKS = {("n", "m"): ((5, 5), (6, 3), (12, 6)),
          ("N", "n", "m"): ((7, 3, 2), (4, 6, 3), (9, 2, 5)),
          ("k",): ((8,), (11,))}
#: The check sizes of a quick report.
QUICK_CHECKS = {("n", "m"): ((6, 3),), ("N", "n", "m"): ((7, 3, 2),), ("k",): ((8,),)}
#: Significant digits of the entries of a dense random model.
DIGITS = 6
#: Largest size a family is counted at (paper mode's JKLF at n = m = 16 takes seconds).
MAX_SIZE = 16
#: Highest degree bound a fit may try (3 variables at degree 6: 84 sizes to count).
MAX_FIT_DEGREE = 6


Sizes = tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Family:
    """One filter counted at sizes ``variables`` (e.g. ("n", "m")): ``counter(sizes, lang)``
    is the OpCount of its step at ``sizes`` in that lowering (python, or c with fma)."""

    filter: str
    mode: str
    variables: tuple[str, ...]
    description: str
    counter: Callable[[Sizes, str], OpCount]
    cache: dict = field(default_factory=dict, repr=False)

    def count(self, sizes: Sizes, lang: str) -> OpCount:
        if (sizes, lang) not in self.cache:
            self.cache[(sizes, lang)] = self.counter(sizes, lang)
        return self.cache[(sizes, lang)]

    def counts(self, sizes: Sizes, series: Sequence[str] = SERIES) -> dict[str, int]:
        """``{series: value}`` of the step at ``sizes``, counting only the lowerings that
        ``series`` need (the flops are the Python lowering's; C's are the same, since
        fusing never adds or drops an operation, which tests/commands/test_burden.py checks)."""
        out = {}
        for name in series:
            if name == "flops":
                out[name] = self.count(sizes, "python").flops
            else:
                lang, kind = name.split(".")
                out[name] = getattr(self.count(sizes, lang), kind)
        return out

    def label(self, sizes: Sizes) -> str:
        return ", ".join(f"{v} = {s}" for v, s in zip(self.variables, sizes))


# -- families ----------------------------------------------------------------------------


def paper_count(name: str, sizes: Sizes, lang: str = "python") -> OpCount:
    """The count of paper-mode ``name``'s step at (n, m), or (N, n, m) for the FIR, in
    ``lang``'s lowering (cached: the audit and the fits count the same sizes)."""
    return _paper_count(name, tuple(sizes), lang)


@cache
def _paper_count(name: str, sizes: Sizes, lang: str) -> OpCount:
    N, (n, m) = (sizes[0], sizes[1:]) if name == "fir" else (None, sizes)
    return count(paper.step_program(name, n, m, N), lang)


def dense_model(n: int, m: int, seed: int = 0) -> LinearModel:
    """A dense random n x m model: every entry of F, H, Q and R non-zero and none +-1 (so
    nothing folds away), F scaled to spectral radius 0.9, Q and R positive definite, each
    entry to DIGITS significant digits (fewer let two entries coincide, and the optimiser
    share what they have in common: the counts then depend on the seed). The same for the
    same seed."""
    rng = np.random.default_rng([seed, n, m])

    def entries(*shape):
        return rng.uniform(0.1, 0.9, shape) * rng.choice((-1.0, 1.0), shape)

    F = entries(n, n)
    F *= 0.9 / max(np.max(np.abs(np.linalg.eigvals(F))), 1e-3)
    L, Lr = entries(n, n), entries(m, m)
    Q = L @ L.T / n + 0.1 * np.eye(n)
    R = Lr @ Lr.T / m + 0.2 * np.eye(m)

    def short(a):  # DIGITS significant digits, never an exact zero
        a = np.array([[float(f"{v:.{DIGITS}g}") for v in row] for row in a])
        return np.where(a == 0, 0.001, a).tolist()

    return LinearModel(f"dense_n{n}_m{m}", [f"x{i}" for i in range(n)],
                       [f"y{i}" for i in range(m)], short(F), short(entries(m, n)),
                       short((Q + Q.T) / 2), short((R + R.T) / 2))


@cache
def _dense_step(name: str, sizes: Sizes, seed: int, options: tuple):
    opts = dict(options)
    if name == "fir":
        N, (n, m) = sizes[0], sizes[1:]
        opts["order"] = N
    else:
        n, m = sizes
    return _step(derive_unit(dense_model(n, m, seed), name, opts), name)


def dense_count(name: str, sizes: Sizes, seed: int = 0, options: tuple = (),
                lang: str = "python") -> OpCount:
    """The count of derive's specialised ``name`` on :func:`dense_model` at ``sizes``."""
    return _dense_count(name, tuple(sizes), seed, options, lang)


@cache
def _dense_count(name: str, sizes: Sizes, seed: int, options: tuple, lang: str) -> OpCount:
    return count(_dense_step(name, sizes, seed, options), lang)


def _options_key(options: dict | None) -> tuple:
    return tuple(sorted((options or {}).items()))


def _step(unit, name: str):
    if "step" not in unit.programs:
        raise FilterError(f"filter {name!r} has no step program to count")
    return unit.programs["step"]


def _known(name: str, names: Sequence[str], what: str) -> None:
    if name not in names:
        raise FilterError(f"{what} has no filter {name!r}; filters: {', '.join(names)}")


def family(name: str, mode: str = "paper", block=None, options: dict | None = None,
           seed: int = 0) -> Family:
    """The family of filter ``name`` in ``mode`` (paper, dense, blocks; blocks: k copies of
    the LinearModel ``block``; ``options``: derive's filter options, not for paper mode)."""
    if mode not in MODES:
        raise ModelError(f"unknown family {mode!r}; families: {', '.join(MODES)}")
    if mode == "paper":
        _known(name, paper.PAPER_FILTERS, "paper mode")
        if options:
            raise ModelError("paper mode takes no filter options (its algorithm is the "
                             f"papers'); got {', '.join(sorted(options))}")
        variables = ("N", "n", "m") if name == "fir" else ("n", "m")
        return Family(name, mode, variables, f"{name}, paper mode (the dense, unspecialised "
                      "algorithm as the papers count it; every model matrix read at run time)",
                      lambda sizes, lang: paper_count(name, sizes, lang))
    if mode == "dense":
        _known(name, available(dense_model(2, 1, seed)), "a dense linear model")
        key = _options_key(options)
        variables = ("N", "n", "m") if name == "fir" else ("n", "m")
        return Family(name, mode, variables, f"{name}, derive's specialised code on dense "
                      f"random n x m models (seed {seed}: every entry of F, H, Q, R non-zero "
                      "and not +-1)", lambda sizes, lang: dense_count(name, sizes, seed, key, lang))
    if not isinstance(block, LinearModel):
        raise ModelError("family blocks needs a linear model as its block (the model copied "
                         "k times)")
    if getattr(block, "inputs", ()):
        raise ModelError(f"family blocks: model {block.name!r} has per-step inputs, which "
                         "copies do not compose")
    opts = dict(options or {})

    @cache
    def step(k: int):
        model = block if k == 1 else LinearModel.compose(
            f"{block.name}_x{k}", [block] * k, [f"_{i}" for i in range(k)])
        return _step(derive_unit(model, name, opts), name)

    def copies(sizes: Sizes, lang: str) -> OpCount:
        return count(step(sizes[0]), lang)

    return Family(name, mode, ("k",), f"{name}, derive's specialised code on k independent "
                  f"copies of {block.name} (n = {block.n}, m = {block.m} each)", copies)


# -- exact interpolation -----------------------------------------------------------------


def monomials(count_vars: int, degree: int) -> list[Sizes]:
    """Exponent tuples of total degree <= ``degree``, highest degree first."""
    found = [e for e in itertools.product(range(degree + 1), repeat=count_vars)
             if sum(e) <= degree]
    return sorted(found, key=lambda e: (-sum(e), [-x for x in e]))


def _row(sizes: Sizes, mons: Sequence[Sizes]) -> list[Fraction]:
    return [Fraction(math.prod(s**e for s, e in zip(sizes, mon))) for mon in mons]


def _independent(points: Sequence[Sizes], candidates: Sequence[Sizes],
                 mons: Sequence[Sizes]) -> list[Sizes]:
    """``points`` (independent already) plus the first ``candidates`` whose rows of
    monomial values are independent of those before, until they determine the polynomial."""
    basis: list[tuple[int, list[Fraction]]] = []
    chosen: list[Sizes] = []
    for p in list(points) + [c for c in candidates if c not in points]:
        if len(chosen) == len(mons):
            break
        row = _row(p, mons)
        for pivot, base in basis:
            if row[pivot]:
                factor = row[pivot] / base[pivot]
                row = [a - factor * b for a, b in zip(row, base)]
        lead = next((i for i, a in enumerate(row) if a), None)
        if lead is not None:
            basis.append((lead, row))
            chosen.append(p)
    if len(chosen) < len(mons):
        raise ModelError(f"too few sizes to fit {len(mons)} coefficients")
    return chosen


def _solve(matrix: list[list[Fraction]], columns: list[list[Fraction]]) -> list[list[Fraction]]:
    """Exact Gauss-Jordan: the solutions x of ``matrix x = column``, one per column."""
    size = len(matrix)
    rows = [list(r) + [col[i] for col in columns] for i, r in enumerate(matrix)]
    for c in range(size):
        pivot = next(r for r in range(c, size) if rows[r][c])
        rows[c], rows[pivot] = rows[pivot], rows[c]
        lead = rows[c][c]
        rows[c] = [a / lead for a in rows[c]]
        for r in range(size):
            if r != c and rows[r][c]:
                factor = rows[r][c]
                rows[r] = [a - factor * b for a, b in zip(rows[r], rows[c])]
    return [[rows[i][size + j] for i in range(size)] for j in range(len(columns))]


@dataclass(frozen=True)
class Polynomial:
    """Exact rational coefficients by exponent tuple, over ``variables``."""

    variables: tuple[str, ...]
    terms: tuple[tuple[Sizes, Fraction], ...]

    @classmethod
    def of(cls, variables, mapping: dict[Sizes, Fraction]) -> Polynomial:
        kept = [(e, c) for e, c in mapping.items() if c]
        return cls(tuple(variables), tuple(sorted(kept, key=lambda t: (-sum(t[0]),
                                                                       [-x for x in t[0]]))))

    @classmethod
    def from_expr(cls, expr: sympy.Expr, variables) -> Polynomial:
        symbols = [formulas.VARIABLES[v] for v in variables]
        poly = sympy.Poly(expr, *symbols)
        return cls.of(variables, {tuple(e): Fraction(int(c.p), int(c.q))
                                  for e, c in poly.terms()})

    def __call__(self, sizes: Sizes) -> Fraction:
        return sum((c * math.prod(s**e for s, e in zip(sizes, exps))
                    for exps, c in self.terms), Fraction(0))

    def __sub__(self, other: Polynomial) -> Polynomial:
        out = dict(self.terms)
        for e, c in other.terms:
            out[e] = out.get(e, Fraction(0)) - c
        return Polynomial.of(self.variables, out)

    @property
    def degree(self) -> int:
        return max((sum(e) for e, _ in self.terms), default=0)

    def coefficient(self, exps: Sizes) -> Fraction:
        return dict(self.terms).get(exps, Fraction(0))

    def expr(self) -> sympy.Expr:
        symbols = [formulas.VARIABLES[v] for v in self.variables]
        return sympy.Add(*(sympy.Rational(c.numerator, c.denominator)
                           * sympy.Mul(*(s**e for s, e in zip(symbols, exps)))
                           for exps, c in self.terms))

    def monomial(self, exps: Sizes) -> str:
        parts = [v if e == 1 else f"{v}**{e}" for v, e in zip(self.variables, exps) if e]
        return "*".join(parts) or "1"

    def __str__(self) -> str:
        """As a formula derive audit parses back: ``4*n**3 + 7/2*n**2 - 1/6*m``."""
        if not self.terms:
            return "0"
        out = []
        for i, (exps, c) in enumerate(self.terms):
            sign = "-" if c < 0 else "+"
            size = abs(c)
            mono = self.monomial(exps)
            if mono == "1":
                body = str(size)
            elif size == 1:
                body = mono
            else:
                body = f"{size}*{mono}"
            out.append((f"-{body}" if sign == "-" else body) if i == 0 else f" {sign} {body}")
        return "".join(out)


@dataclass(frozen=True)
class Fit:
    """One series' result: its polynomial, the degree bound it was fit under and the smallest
    size it holds from (every variable >= minimum), or (no polynomial) the check sizes where
    the fit of the highest degree on the whole range disagrees with the count."""

    series: str
    polynomial: Polynomial | None
    degree: int
    minimum: int
    failures: tuple[tuple[Sizes, int, Fraction], ...] = ()


@dataclass(frozen=True)
class DerivedFormula:
    family: Family
    fits: dict[str, Fit]
    fit_sizes: tuple[Sizes, ...]
    check_sizes: tuple[Sizes, ...]
    degree: int
    max_degree: int
    minimum: int

    @property
    def variables(self) -> tuple[str, ...]:
        return self.family.variables

    @property
    def flops(self) -> Polynomial | None:
        return self.fits["flops"].polynomial

    def polynomial(self, series: str = "flops") -> Polynomial | None:
        return self.fits[series].polynomial

    @property
    def method(self) -> str:
        return (f"exact interpolation over the integers: a series' counts at the smallest "
                f"sizes >= lo that determine a polynomial of total degree <= d in "
                f"{', '.join(self.variables)} give its coefficients by an exact rational "
                "solve; the polynomial is kept when it equals the counts at every check size "
                f">= lo, none used in a fit; d starts at {self.degree}, lo at {self.minimum}; "
                f"a failed check raises lo up to {self.minimum + RAISE}, then d up to "
                f"{self.max_degree}")

    @property
    def checked(self) -> str:
        """The check sizes, as text."""
        sizes = " ".join(f"({', '.join(map(str, s))})" for s in self.check_sizes)
        return f"check sizes ({', '.join(self.variables)}): {sizes}"

    @property
    def fitted(self) -> str:
        """The sizes counted for the fits, as text."""
        sizes = " ".join(f"({', '.join(map(str, s))})" for s in self.fit_sizes)
        return f"fit sizes counted ({', '.join(self.variables)}): {sizes}"


def _sizes_arg(family: Family, sizes, what: str) -> tuple[Sizes, ...]:
    out = []
    for s in sizes:
        s = tuple(s)
        if len(s) != len(family.variables) or not all(
                isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_SIZE
                for v in s):
            raise ModelError(f"{what} {s!r}: need {len(family.variables)} integers "
                             f"({', '.join(family.variables)}) from 1 to {MAX_SIZE}")
        out.append(s)
    return tuple(dict.fromkeys(out))


def derive_formula(fam: Family, degree: int = DEGREE, max_degree: int = MAX_DEGREE,
                   check: Sequence[Sizes] | None = None, minimum: int = 1,
                   series: Sequence[str] = SERIES) -> DerivedFormula:
    """The polynomial each series of ``fam``'s counts obeys (see the module docstring):
    fit on the smallest sizes >= lo that determine a polynomial of total degree <= d, for d
    from ``degree`` to ``max_degree`` and, within each d, lo from ``minimum`` to
    ``minimum + RAISE`` (a count whose smallest sizes follow another rule, such as a dot
    product of one term that fuses nothing, obeys a polynomial from lo on); each fit
    checked at ``check`` (default CHECKS), where it must equal every count."""
    if not (isinstance(degree, int) and isinstance(max_degree, int)
            and 0 <= degree <= max_degree <= MAX_FIT_DEGREE):
        raise ModelError(f"degree bounds must satisfy 0 <= degree <= max degree <= "
                         f"{MAX_FIT_DEGREE}; got {degree}, {max_degree}")
    if not (isinstance(minimum, int) and 1 <= minimum <= MAX_SIZE // 2):
        raise ModelError(f"the smallest fit size must be an integer from 1 to "
                         f"{MAX_SIZE // 2}; got {minimum!r}")
    checks = _sizes_arg(fam, CHECKS[fam.variables] if check is None else check, "check size")
    if not checks:
        raise ModelError("give at least one check size: a fit checked nowhere proves nothing")
    nvars = len(fam.variables)
    fits: dict[str, Fit] = {}
    pending = list(series)
    chosen: dict[int, list[Sizes]] = {}
    used: set[Sizes] = set()
    for d, lo in itertools.product(range(degree, max_degree + 1),
                                   range(minimum, minimum + RAISE + 1)):
        mons = monomials(nvars, d)
        top = lo + max_degree + 2
        candidates = sorted((s for s in itertools.product(range(lo, top + 1), repeat=nvars)
                             if s not in checks), key=lambda s: (sum(s), s))
        chosen[lo] = _independent(chosen.get(lo, []), candidates, mons)
        used.update(chosen[lo])
        matrix = [_row(s, mons) for s in chosen[lo]]
        values = [fam.counts(s, pending) for s in chosen[lo]]
        solved = _solve(matrix, [[Fraction(v[name]) for v in values] for name in pending])
        checked = [(s, fam.counts(s, pending)) for s in checks if min(s) >= lo]
        for name, coefs in zip(list(pending), solved):
            poly = Polynomial.of(fam.variables, dict(zip(mons, coefs)))
            wrong = tuple((s, v[name], poly(s)) for s, v in checked if poly(s) != v[name])
            if checked and not wrong:
                fits[name] = Fit(name, poly, d, lo)
                pending.remove(name)
            elif (d, lo) == (max_degree, minimum):
                fits[name] = Fit(name, None, d, lo, wrong)
        if not pending:
            break
    return DerivedFormula(fam, {name: fits[name] for name in series},
                          tuple(sorted(used, key=lambda s: (sum(s), s))), checks,
                          degree, max_degree, minimum)


# -- a formula audited -------------------------------------------------------------------


@dataclass(frozen=True)
class FormulaCheck:
    """A formula's text against the derived polynomial of one series."""

    text: str
    claim: Polynomial
    derived: DerivedFormula
    series: str

    @property
    def polynomial(self) -> Polynomial | None:
        return self.derived.polynomial(self.series)

    @property
    def difference(self) -> Polynomial | None:
        """formula - derived (None where the counts obey no polynomial)."""
        return None if self.polynomial is None else self.claim - self.polynomial

    @property
    def equal(self) -> bool:
        return self.difference is not None and not self.difference.terms

    @property
    def terms(self) -> list[tuple[str, Fraction, Fraction]]:
        """(monomial, the formula's coefficient, the derived one) of each term that differs."""
        if self.difference is None:
            return []
        return [(self.claim.monomial(e), self.claim.coefficient(e),
                 self.polynomial.coefficient(e)) for e, _ in self.difference.terms]

    @property
    def first(self) -> tuple[Sizes, Fraction, int] | None:
        """The smallest sizes where formula and counts differ: (sizes, formula, count)."""
        diff = self.difference
        if diff is None or not diff.terms:
            return None
        side = diff.degree + 1  # a non-zero polynomial of this degree is non-zero on the box
        minimum = self.derived.fits[self.series].minimum   # where the derived one holds
        box = sorted(itertools.product(range(minimum, minimum + side + 1),
                                       repeat=len(diff.variables)), key=lambda s: (sum(s), s))
        sizes = next(s for s in box if diff(s))
        return (sizes, self.claim(sizes),
                self.derived.family.counts(sizes, (self.series,))[self.series])


def parse_claim(text: str, fam: Family) -> Polynomial:
    """``text`` as a polynomial in ``fam``'s variables (derive.apps.formulas.parse_formula)."""
    return Polynomial.from_expr(formulas.parse_formula(text, fam.variables), fam.variables)


def audit_formula(text: str, fam: Family, series: str = "flops", derived=None,
                  **fit) -> FormulaCheck:
    """``text`` (a formula in ``fam``'s variables) against the polynomial derived for
    ``series`` of ``fam`` (``derived``: a DerivedFormula already fit, else fit here with
    ``fit``'s arguments to derive_formula)."""
    if series not in SERIES:
        raise ModelError(f"unknown series {series!r}; series: {', '.join(SERIES)}")
    claim = parse_claim(text, fam)
    derived = derived or derive_formula(fam, series=(series,), **fit)
    return FormulaCheck(text, claim, derived, series)


def check_formula(text: str, name: str, mode: str = "paper", block=None,
                  options: dict | None = None, seed: int = 0, series: str = "flops",
                  **fit) -> FormulaCheck:
    """The Python API of `derive audit --formula`: ``text`` against the formula derived for
    filter ``name`` in family ``mode`` (paper, dense, blocks; see :func:`family`), for
    ``series`` (flops, or LANG.KIND), fit with ``fit``'s arguments to derive_formula. The
    text is parsed before anything is counted."""
    fam = family(name, mode, block, options, seed)
    parse_claim(text, fam)
    return audit_formula(text, fam, series, **fit)


def verdict(check: FormulaCheck) -> str:
    """One line: equal, or the terms that differ."""
    if check.polynomial is None:
        return ("the counts obey no polynomial of total degree <= "
                f"{check.derived.max_degree}: nothing to compare symbolically")
    fit = check.derived.fits[check.series]
    where = (f" (the counts obey it for {', '.join(check.derived.variables)} >= {fit.minimum})"
             if fit.minimum > 1 else "")
    if check.equal:
        return "equal: the formula is the derived polynomial, term by term" + where
    terms = "; ".join(f"{mono}: formula {a}, derived {b}"
                      for mono, a, b in check.terms)
    return f"differs in {len(check.terms)} term(s): {terms}{where}"


@dataclass(frozen=True)
class ModelCheck:
    """A formula's value at one model's sizes against the count of derive's code there."""

    text: str
    model: str
    sizes: dict[str, int]
    claim: Fraction
    count: int
    mode: str

    @property
    def equal(self) -> bool:
        return self.claim == self.count


def audit_at_model(text: str, name: str, model, mode: str = "dense",
                   options: dict | None = None, series: str = "flops") -> ModelCheck:
    """``text`` at the sizes of ``model`` (n, m; the FIR also its order N) against the count
    of derive's code for it: paper mode (``mode`` paper) or derive's specialised code."""
    if series not in SERIES:
        raise ModelError(f"unknown series {series!r}; series: {', '.join(SERIES)}")
    if model.kind != "linear" and (mode == "paper" or name == "fir"):
        raise FilterError(f"paper mode needs a linear model; {model.name!r} is {model.kind}")
    variables = ("N", "n", "m") if name == "fir" else ("n", "m")
    if mode == "paper":
        _known(name, paper.PAPER_FILTERS, "paper mode")
        unit = paper.model_unit(model, name, N=(options or {}).get("order"))
    else:
        unit = derive_unit(model, name, options or {})
    sizes = {"n": unit.n, "m": unit.m}
    if name == "fir":
        sizes = {"N": unit.window, **sizes}
    claim = Polynomial.from_expr(formulas.parse_formula(text, variables), variables)
    step = _step(unit, name)
    ops = count(step, "python" if series == "flops" else series.split(".")[0])
    value = ops.flops if series == "flops" else getattr(ops, series.split(".")[1])
    return ModelCheck(text, model.name, sizes, claim(tuple(sizes[v] for v in variables)),
                      value, mode)


# -- text and JSON -------------------------------------------------------------------------


def series_title(name: str) -> str:
    if name == "flops":
        return "flops (the papers' convention: + - * / sqrt one each, an fma two)"
    lang, kind = name.split(".")
    return f"{kind} ({'Python' if lang == 'python' else 'C, products fused into fma'})"


def formula_lines(derived: DerivedFormula) -> list[str]:
    """The derived formula of every series, the method, and each failure."""
    lines = [derived.family.description, f"method: {derived.method}",
             f"{derived.checked}; {derived.fitted}"]
    for name, fit in derived.fits.items():
        if name != "flops" and fit.polynomial is not None and not fit.polynomial.terms:
            continue
        head = "  " + (series_title(name) if name == "flops" else name)
        if fit.polynomial is not None:
            where = (f"  (for {', '.join(derived.variables)} >= {fit.minimum})"
                     if fit.minimum > derived.minimum else "")
            lines.append(f"{head} = {fit.polynomial}{where}")
        else:
            where = "; ".join(f"({derived.family.label(s)}): counted {v}, the fit gives {p}"
                              for s, v, p in fit.failures)
            lines.append(f"{head}: no polynomial of total degree <= {fit.degree} (nor from "
                         f"a smallest size up to {derived.minimum + RAISE}); the fit on sizes "
                         f">= {derived.minimum} fails at {where}")
    zero = [n for n, f in derived.fits.items()
            if n != "flops" and f.polynomial is not None and not f.polynomial.terms]
    if zero:
        lines.append(f"  zero at every size: {', '.join(zero)}")
    return lines


def derived_json(derived: DerivedFormula) -> dict:
    return {"filter": derived.family.filter, "mode": derived.family.mode,
            "family": derived.family.description, "variables": list(derived.variables),
            "method": derived.method,
            "fit_sizes": [list(s) for s in derived.fit_sizes],
            "check_sizes": [list(s) for s in derived.check_sizes],
            "series": {name: {"formula": None if f.polynomial is None else str(f.polynomial),
                              "degree_bound": f.degree, "from": f.minimum,
                              "failures": [{"sizes": list(s), "count": v, "fit": str(p)}
                                           for s, v, p in f.failures]}
                       for name, f in derived.fits.items()}}


def check_lines(check: FormulaCheck) -> list[str]:
    lines = [f"formula ({series_title(check.series)}): {check.text}",
             f"  as a polynomial: {check.claim}",
             f"derived ({check.derived.family.description}):",
             f"  {check.polynomial if check.polynomial is not None else 'none'}",
             f"  method: {check.derived.method}",
             f"  {check.derived.checked}; {check.derived.fitted}",
             f"verdict: {verdict(check)}"]
    if check.difference is not None and check.difference.terms:
        sizes, claimed, counted = check.first
        lines += [f"difference (formula - derived): {check.difference}",
                  f"smallest sizes where they differ: {check.derived.family.label(sizes)}: "
                  f"the formula gives {claimed}, the generated code counts {counted}"]
    return lines


def check_json(check: FormulaCheck) -> dict:
    first = check.first
    return {"formula": check.text, "as_polynomial": str(check.claim), "series": check.series,
            "derived": None if check.polynomial is None else str(check.polynomial),
            "equal": check.equal,
            "difference": None if check.difference is None else str(check.difference),
            "terms": [{"term": t, "formula": str(a), "derived": str(b)}
                      for t, a, b in check.terms],
            "first": None if first is None else {
                "sizes": dict(zip(check.derived.variables, first[0])),
                "formula": str(first[1]), "count": first[2]},
            "verdict": verdict(check), "method": check.derived.method}
