"""The audit of the papers' burden numbers: printed, formula, generated code.

For every implementation the papers compare (MPT3D models A and B, GSM2D models A
and B, SSPRED's two models) one :class:`Row` sets side by side

- the number the paper prints (data, cited; :data:`PRINTED`),
- the papers' formula (:mod:`derive.apps.formulas`: their printed text, parsed),
- the exact count of derive's paper-mode code (:mod:`derive.apps.paper`): the dense
  algorithm the formulas describe, generated and counted by :mod:`derive.flops`,
- the exact count of derive's specialised code for the catalog model,

and flags every printed number the formula does not reproduce, with the reason
found by testing known explanations. Each printed formula is itself audited
(:class:`FormulaRow`): set beside the polynomial derived from paper-mode code by exact
interpolation (:mod:`derive.apps.burden_formula`), with the terms where they differ. The
papers' speedups are recomputed from each column, and the FIR section gives the order N
for several epsilons and the break-even output interval L against the SSKF. Nothing here
is typed in but the printed values and formulas and their citations.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass, field
from functools import cache

import numpy as np
import sympy

from .. import catalog, horizon, riccati
from ..filters import derive_unit
from ..flops import count
from ..statements import Assign
from . import burden_formula, formulas

#: Flops are counted on the Python lowering; the C lowering (with fma, 2 flops each)
#: has the same flops by construction, which tests/commands/test_burden.py checks.
LANG = "python"
FIR_EPSILONS = (1e-3, 1e-6, 1e-9)
FIR_NORM = "spectral norm ||A^N||_2 (largest singular value)"

SOURCE = "the papers' burden sections"
MPT3D_TABLE3 = f"MPT3D Table 3 ({SOURCE})"
MPT3D_TEXT = f"MPT3D speedups ({SOURCE})"
GSM2D_TEXT = f"GSM2D speedups ({SOURCE})"
SSPRED_CB = f"SSPRED calculation burden CB ({SOURCE})"


@dataclass(frozen=True)
class System:
    """One system a paper counts: a catalog model run on ``axes`` independent copies."""

    paper: str
    label: str
    model: str
    axes: int
    implementations: tuple[tuple[str, str], ...]  # (paper's name, derive's filter)


_SIX = (("KF", "kf"), ("LF", "lf"), ("JKLF", "jklf"), ("SSKF", "sskf"), ("SSLF", "sslf"),
        ("JSSKLF", "jssklf"))
_SSPRED = (("SSKF", "sskf"), ("SS prediction", "pred"))

SYSTEMS = (
    System("MPT3D", "model A", "mpt3d_a", 1, _SIX),
    System("MPT3D", "model B", "mpt3d_b", 3, _SIX),
    System("GSM2D", "model A", "gsm2d_a", 1, _SIX),
    System("GSM2D", "model B", "gsm2d_b", 2, _SIX),
    System("SSPRED", "constant velocity", "cv", 1, _SSPRED),
    System("SSPRED", "constant acceleration", "ca", 1, _SSPRED),
)

#: The printed burden numbers: (paper, system, implementation) -> (value, citation).
PRINTED: dict[tuple[str, str, str], tuple[int, str]] = {
    **{("MPT3D", "model A", k): (v, MPT3D_TABLE3) for k, v in
       (("KF", 1660), ("LF", 2207), ("JKLF", 3921), ("SSKF", 102), ("SSLF", 102),
        ("JSSKLF", 216))},
    **{("MPT3D", "model B", k): (v, MPT3D_TABLE3) for k, v in
       (("KF", 207), ("LF", 267), ("JKLF", 484), ("SSKF", 30), ("SSLF", 30), ("JSSKLF", 64))},
    **{("SSPRED", label, k): (v, SSPRED_CB + ", the same for estimation and prediction")
       for label, v in (("constant velocity", 10), ("constant acceleration", 21))
       for k in ("SSKF", "SS prediction")},
}

#: The printed speedups: (paper, what, printed text, numerator, denominator), each a
#: (system label, implementation) of the same paper.
SPEEDUPS = (
    ("MPT3D", "LF/KF, model A", "1.330", ("model A", "LF"), ("model A", "KF"), MPT3D_TEXT),
    ("MPT3D", "LF/KF, model B", "1.290", ("model B", "LF"), ("model B", "KF"), MPT3D_TEXT),
    ("MPT3D", "KF model A / SSKF model B", "55.333", ("model A", "KF"), ("model B", "SSKF"),
     MPT3D_TEXT),
    ("MPT3D", "LF model A / SSLF model B", "73.567", ("model A", "LF"), ("model B", "SSLF"),
     MPT3D_TEXT),
    ("GSM2D", "LF/KF, model A", "1.316", ("model A", "LF"), ("model A", "KF"), GSM2D_TEXT),
    ("GSM2D", "LF/KF, model B", "1.290", ("model B", "LF"), ("model B", "KF"), GSM2D_TEXT),
    ("GSM2D", "KF model A / SSKF model B", "25.450", ("model A", "KF"), ("model B", "SSKF"),
     GSM2D_TEXT),
    ("GSM2D", "LF model A / SSLF model B", "33.500", ("model A", "LF"), ("model B", "SSLF"),
     GSM2D_TEXT),
)

@dataclass(frozen=True)
class Row:
    paper: str
    system: str
    model: str
    axes: int
    n: int
    m: int
    implementation: str
    filter: str
    printed: int | None
    citation: str
    formula: int
    paper_mode: int
    specialised: int
    flag: str | None = None

    @property
    def ratio(self) -> float:
        """Specialised over paper-mode flops."""
        return self.specialised / self.paper_mode


@dataclass(frozen=True)
class Speedup:
    paper: str
    what: str
    printed: str
    citation: str
    from_printed: float | None
    from_formula: float
    from_paper_mode: float
    from_specialised: float
    flag: str | None = None

    @property
    def decimals(self) -> int:
        return len(self.printed.split(".")[1]) if "." in self.printed else 0


@dataclass(frozen=True)
class FirRow:
    paper: str
    system: str
    model: str
    axes: int
    eps: float
    N: int
    norm_of_A_N: float
    fir_formula: int
    sskf_formula: int
    L_formula: int
    fir_paper_mode: int
    fir_specialised: int
    sskf_specialised: int
    L_specialised: int


@dataclass(frozen=True)
class FormulaRow:
    """A printed formula against the one derived from paper-mode code."""

    filter: str
    printed: str             # as the paper prints it (derive.apps.formulas.PRINTED)
    citation: str
    claim: str               # the printed formula as a polynomial
    derived: str | None      # the polynomial the paper-mode counts obey (None: none fits)
    equal: bool
    verdict: str
    difference: str | None   # claim - derived
    first: dict | None       # the smallest sizes where they differ, and both values there
    method: str
    fit_sizes: tuple[tuple[int, ...], ...]
    check_sizes: tuple[tuple[int, ...], ...]
    join: str | None = None          # JKLF, JSSKLF: the join the papers add
    derived_join: str | None = None  # derived(join) - derived(its two filters)


@dataclass(frozen=True)
class Audit:
    rows: tuple[Row, ...]
    speedups: tuple[Speedup, ...]
    fir: tuple[FirRow, ...]
    notes: tuple[str, ...] = field(default=())
    formulas: tuple[FormulaRow, ...] = field(default=())
    lang: str = LANG
    fir_norm: str = FIR_NORM


# -- counting ---------------------------------------------------------------------------


@cache
def _model(name: str):
    return catalog.load(name)


@cache
def specialised_count(model: str, name: str, N: int | None = None):
    """OpCount of ``step`` of derive's specialised filter ``name`` for a catalog model."""
    options = {} if N is None else {"order": N} if name == "fir" else {"horizon": N}
    return count(derive_unit(_model(model), name, options).programs["step"], LANG)


def paper_count(name: str, n: int, m: int, N: int | None = None):
    """OpCount of ``step`` of derive's paper-mode ``name`` for sizes n, m (FIR order N)."""
    return burden_formula.paper_count(name, (n, m) if N is None else (N, n, m), LANG)


def _formula(name: str, n: int, m: int, axes: int) -> int:
    return axes * formulas.burden(name, n, m)


def _parts(name: str) -> list[tuple[str, str, object]]:
    """The named parts of a printed formula, (what, as a term, its polynomial): a join's two
    filters and its join term, or the whole formula."""
    if name in formulas.JOINS:
        (a, b), join = formulas.JOINS[name]
        return [(a.upper(), a.upper(), formulas.claim(a)),
                (b.upper(), b.upper(), formulas.claim(b)),
                (f"the join term {join}", f"({join})", formulas.join_claim(name))]
    return [(name.upper(), name.upper(), formulas.claim(name))]


def _as_formulas(name: str, once: tuple[int, ...], quick: bool) -> str:
    """The explanation as polynomials in the number of axes k: the printed number's
    formula (the parts ``once`` counted once) less the derived one, k times paper mode's."""
    derived = derived_flops(name, quick).flops
    if derived is None:
        return ""
    k = formulas.VARIABLES["k"]
    parts = _parts(name)
    implied = sum((expr if i in once else k * expr for i, (_, _, expr) in enumerate(parts)),
                  sympy.S.Zero)
    difference = sympy.factor(implied - k * derived.expr())
    counted = " + ".join(term if i in once else f"k*{term}"
                         for i, (_, term, _) in enumerate(parts))
    return (f". As formulas in the axes k, the printed number is {counted}, derived from "
            f"paper-mode code k*({derived}): they differ by {difference}")


def explain(name: str, printed: int, n: int, m: int, axes: int, quick: bool = False) -> str:
    """Why a printed number differs from the formula: which parts of the printed formula
    (a join's KF, LF and join term; or the whole), counted for one axis instead of
    ``axes``, give the printed number (each such explanation is tested); and the same as
    polynomials against the derived formula (``quick``: derived_flops(name, quick))."""
    formula = _formula(name, n, m, axes)
    parts = [(label, formulas.value(expr, n=n, m=m)) for label, _, expr in _parts(name)]
    whole = " + ".join(str(v) for _, v in parts)
    for size in range(1, len(parts) + 1) if axes > 1 else ():
        for once in itertools.combinations(range(len(parts)), size):
            rest = [v for i, (_, v) in enumerate(parts) if i not in once]
            single = sum(parts[i][1] for i in once)
            if printed != axes * sum(rest) + single:
                continue
            if not rest:
                return (f"printed {printed} is one axis of {axes}: the formula gives "
                        f"{axes}*({whole}) = {formula}")
            labels = " and ".join(parts[i][0] for i in once)
            return (f"{labels} is counted for one axis, not {axes}: printed {printed} = "
                    f"{axes}*({' + '.join(map(str, rest))}) + {single}; the formula gives "
                    f"{axes}*({whole}) = {formula}" + _as_formulas(name, once, quick))
    return f"printed {printed} differs from the formula's {formula} by {printed - formula}; " \
           "no known explanation"


def rows(quick: bool = False) -> list[Row]:
    out = []
    for s in SYSTEMS:
        model = _model(s.model)
        n, m = model.n, model.m
        for label, name in s.implementations:
            printed, citation = PRINTED.get((s.paper, s.label, label), (None, ""))
            if printed is None and s.paper == "GSM2D":
                citation = f"GSM2D Table 3 was lost in extraction ({SOURCE})"
            formula = _formula(name, n, m, s.axes)
            flag = None
            if printed is not None and printed != formula:
                flag = explain(name, printed, n, m, s.axes, quick)
            out.append(Row(s.paper, s.label, s.model, s.axes, n, m, label, name, printed,
                           citation, formula, s.axes * paper_count(name, n, m).flops,
                           s.axes * specialised_count(s.model, name).flops, flag))
    return out


def speedups(table: list[Row]) -> list[Speedup]:
    index = {(r.paper, r.system, r.implementation): r for r in table}
    out = []
    for paper_name, what, printed, num, den, citation in SPEEDUPS:
        a, b = index[(paper_name, *num)], index[(paper_name, *den)]
        from_printed = (a.printed / b.printed if a.printed is not None and b.printed is not None
                        else None)
        from_formula = a.formula / b.formula
        decimals = len(printed.split(".")[1])
        flag = None
        if f"{from_formula:.{decimals}f}" != printed:
            flag = (f"the formulas give {from_formula:.{decimals + 3}f}, printed {printed}")
        out.append(Speedup(paper_name, what, printed, citation, from_printed, from_formula,
                           a.paper_mode / b.paper_mode, a.specialised / b.specialised, flag))
    return out


def fir_rows() -> list[FirRow]:
    out = []
    for s in SYSTEMS:
        if s.paper == "SSPRED":
            continue
        model = _model(s.model)
        n, m = model.n, model.m
        num = model.numeric()
        A = riccati.kf_steady(num.F, num.G, num.H, num.Q, num.R).A
        sskf_formula = _formula("sskf", n, m, s.axes)
        sskf_spec = s.axes * specialised_count(s.model, "sskf").flops
        for eps in FIR_EPSILONS:
            N = horizon.fir_order(A, eps, norm=2)
            fir_formula = s.axes * formulas.fir(N, n, m)
            fir_spec = s.axes * specialised_count(s.model, "fir", N).flops
            out.append(FirRow(
                s.paper, s.label, s.model, s.axes, eps, N,
                float(np.linalg.norm(np.linalg.matrix_power(A, N), 2)), fir_formula,
                sskf_formula, formulas.break_even(fir_formula, sskf_formula),
                s.axes * paper_count("fir", n, m, N).flops, fir_spec, sskf_spec,
                formulas.break_even(fir_spec, sskf_spec)))
    return out


def reciprocal_savings(program) -> int:
    """Reciprocals ``t = 1/d`` used only as factors of products: dividing by ``d`` at each of
    the k uses instead would cost k divisions rather than one division and k
    multiplications, one flop less each (a division for a multiplication on hardware)."""
    recips = {st.target for st in program.body
              if isinstance(st, Assign) and st.expr.is_Pow and st.expr.exp == -1}
    uses = dict.fromkeys(recips, 0)
    blocked: set = set()

    def visit(expr, in_product: bool) -> None:
        if expr in recips:
            uses[expr] += 1
            if not in_product:
                blocked.add(expr)
            return
        for arg in expr.args:
            visit(arg, expr.is_Mul)

    for st in program.body:
        visit(st.expr if isinstance(st, Assign) else st.value, False)
    for values in program.results.values():
        for v in values:
            visit(v, False)
    return sum(1 for r in recips if uses[r] and r not in blocked)


def _kf_note() -> str:
    """The specialised KF of MPT3D model A, per axis, by kind of operation."""
    whole = specialised_count("mpt3d_a", "kf")
    blocks = len(_model("mpt3d_a").blocks())
    axis = specialised_count("mpt3d_b", "kf")
    kinds = ", ".join(f"{k} {v}" for k, v in axis.as_dict().items() if v)
    saving = reciprocal_savings(derive_unit(_model("mpt3d_a"), "kf", {}).programs["step"])
    head = (f"Specialised KF on mpt3d_a: {whole.flops} flops, {blocks} independent axes found "
            f"by derive, each as mpt3d_b's KF: {axis.flops} flops ({kinds}).")
    if not saving:
        return (head + " Each pivot of S divides its two gain entries directly (two divisions "
                "cost fewer flops than 1/S and two products, with no more latency; a reciprocal "
                "is shared from three entries on: derive.staging.DIRECT_DIVISIONS).")
    return (head + f" {saving} reciprocal(s) 1/S feed only multiplications; dividing at each "
            f"use instead would count {whole.flops - saving} flops under the papers' "
            "one-operation-one-flop rule, by turning multiplications into divisions.")


def notes(table: list[Row]) -> list[str]:
    out = []
    mismatched = [r for r in table if r.paper_mode != r.formula]
    if mismatched:
        out.append("paper-mode counts that differ from the formula: "
                   + "; ".join(f"{r.paper} {r.system} {r.implementation}: {r.paper_mode} vs "
                               f"{r.formula}" for r in mismatched))
    else:
        out.append("Every paper-mode count equals the formula: the formulas are exactly the "
                   "operation counts of the dense algorithms they describe, generated and "
                   "counted by derive (paper mode).")
    out.append("Paper mode charges the inverse as the papers do, (16n^3 - 3n^2 - n)/6: "
               "Doolittle LU plus a forward and a backward solve of n^2 operations per column "
               "of the identity. n^2 of those operations divide by L's unit diagonal; one "
               "division would do for a 1 x 1 inverse, which the papers charge 2.")
    axes = "; ".join(f"{s.paper} {s.label}: {s.axes} x {s.model} (n = {_model(s.model).n}, "
                     f"m = {_model(s.model).m})" for s in SYSTEMS if s.axes > 1)
    out.append(f"Systems run as independent axes ({axes}): their formula, paper-mode and "
               "specialised values are one axis's times the axes.")
    out.append("GSM2D's Table 3 was lost in extraction: it has no printed burdens, only the "
               "speedups.")
    out.append(_kf_note())
    return out


#: The printed formulas audited, by derive's names.
FORMULA_FILTERS = ("kf", "lf", "jklf", "sskf", "sslf", "jssklf", "pred", "fir")


@cache
def derived_flops(name: str, quick: bool = False) -> burden_formula.DerivedFormula:
    """The flops formula of paper-mode ``name``, derived (check sizes up to n = 12, m = 6;
    ``quick``: n = 6, m = 3 only)."""
    fam = burden_formula.family(name, "paper")
    checks = (burden_formula.QUICK_CHECKS if quick else burden_formula.CHECKS)[fam.variables]
    return burden_formula.derive_formula(fam, check=checks, series=("flops",))


def formula_rows(quick: bool = False) -> list[FormulaRow]:
    """Each printed formula, parsed as any audited formula is, against the one derived from
    paper-mode code; a join's derived join is its formula less its two filters'."""
    derived = {name: derived_flops(name, quick) for name in FORMULA_FILTERS}
    out = []
    for name in FORMULA_FILTERS:
        fam = derived[name].family
        check = burden_formula.FormulaCheck(
            formulas.PRINTED[name],
            burden_formula.Polynomial.from_expr(formulas.claim(name), fam.variables),
            derived[name], "flops")
        first = check.first
        join = derived_join = None
        if name in formulas.JOINS:
            (a, b), join = formulas.JOINS[name]
            parts = [derived[x].flops for x in (name, a, b)]
            if None not in parts:
                derived_join = str(parts[0] - parts[1] - parts[2])
        out.append(FormulaRow(
            name, formulas.PRINTED[name], formulas.CITATIONS[name], str(check.claim),
            None if check.polynomial is None else str(check.polynomial), check.equal,
            burden_formula.verdict(check),
            None if check.difference is None else str(check.difference),
            None if first is None else {"sizes": dict(zip(fam.variables, first[0])),
                                        "formula": str(first[1]), "count": first[2]},
            check.derived.method, check.derived.fit_sizes, check.derived.check_sizes,
            join, derived_join))
    return out


@cache
def run_audit(quick: bool = False) -> Audit:
    """The whole audit (cached: it derives every filter it counts); ``quick``: the derived
    formulas checked at n = 6, m = 3 only, rather than at sizes up to n = 12, m = 6."""
    table = rows(quick)
    return Audit(tuple(table), tuple(speedups(table)), tuple(fir_rows()), tuple(notes(table)),
                 tuple(formula_rows(quick)))


# -- output -----------------------------------------------------------------------------


def as_json(audit: Audit) -> dict:
    """A JSON-ready dict (ratios as floats)."""
    data = asdict(audit)
    for row, obj in zip(data["rows"], audit.rows):
        row["ratio"] = obj.ratio
    return data


def _table(head: list[str], body: list[list[str]], left: int) -> list[str]:
    """Columns: the first ``left`` aligned left, the others right."""
    widths = [max(len(r[i]) for r in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i < left else '>'}{w}}}" for i, w in enumerate(widths))
    return [fmt.format(*head).rstrip(), fmt.format(*("-" * w for w in widths))] + \
        [fmt.format(*r).rstrip() for r in body]


def text(audit: Audit) -> str:
    """The audit as plain text tables, flags and notes."""
    lines = ["Burden audit: flops per step (+ - * / each 1, fma 2); counts of generated "
             f"code ({audit.lang})", ""]
    body = [[r.paper, r.system + (f" ({r.axes} axes)" if r.axes > 1 else ""),
             r.implementation, f"{r.n},{r.m}", "-" if r.printed is None else str(r.printed),
             str(r.formula), str(r.paper_mode), str(r.specialised), f"{r.ratio:.3f}",
             "FLAG" if r.flag else ""] for r in audit.rows]
    lines += _table(["paper", "system", "filter", "n,m", "printed", "formula", "paper-mode",
                     "specialised", "spec/paper", "flag"], body, 3)
    lines += ["", "Printed values: " + "; ".join(sorted({r.citation for r in audit.rows
                                                         if r.citation}))]
    flagged = [r for r in audit.rows if r.flag]
    lines += ["", f"Flags ({len(flagged)}):"]
    lines += [f"  {r.paper} {r.system} {r.implementation}: {r.flag}" for r in flagged] or \
        ["  none"]
    lines += ["", "Speedups (printed; recomputed from printed burdens, formulas, paper-mode "
                  "code, specialised code):"]
    body = [[s.paper, s.what, s.printed,
             "-" if s.from_printed is None else f"{s.from_printed:.{s.decimals}f}",
             f"{s.from_formula:.{s.decimals}f}", f"{s.from_paper_mode:.{s.decimals}f}",
             f"{s.from_specialised:.3f}", "FLAG: " + s.flag if s.flag else "reproduced"]
            for s in audit.speedups]
    lines += _table(["paper", "speedup", "printed", "printed burdens", "formula",
                     "paper-mode", "specialised", "check"], body, 2)
    lines += ["", f"FIR order N (smallest with ||A_KF^N|| < eps, {audit.fir_norm}) and "
                  "break-even output interval L = ceil(FIR burden / SSKF burden):"]
    body = [[f.paper, f.system + (f" ({f.axes} axes)" if f.axes > 1 else ""),
             f"{f.eps:g}", str(f.N), f"{f.norm_of_A_N:.2e}", str(f.fir_formula),
             str(f.sskf_formula), str(f.L_formula), str(f.fir_paper_mode),
             str(f.fir_specialised), str(f.sskf_specialised), str(f.L_specialised)]
            for f in audit.fir]
    lines += _table(["paper", "system", "eps", "N", "||A^N||", "FIR formula", "SSKF formula",
                     "L", "FIR paper-mode", "FIR spec.", "SSKF spec.", "L spec."], body, 2)
    lines += ["", "The printed formulas against the formulas derived from paper-mode code "
                  "(flops per step):"]
    for f in audit.formulas:
        lines += [f"  {f.filter}: printed ({f.citation}): {f.printed}",
                  f"    as a polynomial: {f.claim}",
                  f"    derived:         {f.derived if f.derived is not None else 'none'}",
                  f"    {f.verdict}"]
        if f.join is not None:
            lines.append(f"    join: printed {f.join}; derived ({f.filter} less its two "
                         f"filters) {f.derived_join}")
        if f.first is not None:
            lines.append(f"    first differs at {f.first['sizes']}: formula {f.first['formula']}"
                         f", count {f.first['count']}")
        lines.append("    checked at " + " ".join(f"({', '.join(map(str, c))})"
                                                  for c in f.check_sizes))
    if audit.formulas:
        lines.append(f"  method: {audit.formulas[0].method}")
    lines += ["", "Notes:"] + [f"  - {note}" for note in audit.notes]
    return "\n".join(lines) + "\n"
