"""Calculation burden: the audit of the papers' numbers (derive.apps.audit) as tables, with a
bar chart of the papers' formula against derive's specialised count per implementation.

The audit counts derive's specialised programs; the report also counts the generated C
files it wrote (:func:`derive.flops.count_c_function` on ``MODEL_FILTER_step``, an fma two
flops), an independent check that the audit's numbers are those of the emitted code.
"""

from __future__ import annotations

import numpy as np

from ... import catalog
from ...flops import count_c_function
from ..audit import run_audit
from . import figures
from .document import DIFFERS, MATCHED, Section, Table, Text, Todo


def written_count(ctx, model: str, name: str) -> int:
    """Flops of one call of ``step`` in the written generated C of ``model``/``name``."""
    prefix = catalog.load(model).name
    return count_c_function(ctx.sources[(model, name)].read_text(),
                            f"{prefix}_{name}_step").flops


def _label(row) -> str:
    axes = f" ×{row.axes}" if row.axes > 1 else ""
    return f"{row.paper} {row.system}{axes} {row.implementation}"


def chart(ctx, rows) -> figures.Figure:
    fig, axes = figures.new(1, 1, width=12.0, height=4.8)
    ax = axes[0, 0]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r.formula for r in rows], 0.4, label="papers' formula",
           color="tab:gray")
    ax.bar(x + 0.2, [r.specialised for r in rows], 0.4,
           label="derive, specialised generated code", color="tab:blue")
    ax.set_yscale("log")
    ax.set_xticks(x, [_label(r) for r in rows], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("burden (flops per step)")
    ax.legend(fontsize=8)
    return figures.save(fig, ctx.figures, "burden_bars",
                        "Per-step burden per implementation: the papers' formula against "
                        "the exact count of derive's specialised generated code (log scale).")


def audit_table(ctx, rows) -> Table:
    body = []
    for r in rows:
        c_file = r.axes * written_count(ctx, r.model, r.filter)
        body.append((
            r.paper, r.system + (f" (×{r.axes})" if r.axes > 1 else ""), r.implementation,
            f"{r.n}, {r.m}", "–" if r.printed is None else str(r.printed), str(r.formula),
            str(r.paper_mode), str(r.specialised),
            str(c_file) if c_file == r.specialised else f"**{c_file}**",
            f"{r.ratio:.3f}", r.flag or ""))
    return Table(("paper", "system", "filter", "n, m", "printed", "formula", "paper mode",
                  "specialised", "written C", "specialised / paper mode", "flag"),
                 tuple(body), "Burden audit: flops per step (+ − × ÷ one each, an fma two)")


def compute_audit(quick: bool = False):
    """derive.apps.audit.run_audit(quick) (run in a background process by the job)."""
    return run_audit(quick)


def formula_table(audit) -> Table:
    """Each printed formula beside the one derived from paper-mode code."""
    body = []
    for f in audit.formulas:
        body.append((f.filter.upper(), f.citation, f.printed, f.claim,
                     f.derived if f.derived is not None else "none fits",
                     "equal" if f.equal else f.verdict))
        if f.join is not None:
            body.append((f"{f.filter.upper()} join", "the join", f.join, f.join,
                         f.derived_join or "–",
                         "equal" if f.derived_join == f.join else "differs"))
    return Table(("filter", "printed in", "printed formula", "as a polynomial",
                  "derived from paper-mode code", "verdict"), tuple(body),
                 "The papers' burden formulas beside the formulas derived from paper-mode "
                 "code (flops per step)")


def outcomes(s: Section, audit) -> None:
    """The summary's lines: printed counts and speedups reproduced, and each flag."""
    printed = [r for r in audit.rows if r.printed is not None]
    flagged = [r for r in printed if r.flag]
    same = [r for r in printed if r.printed == r.formula == r.paper_mode]
    s.outcome("the printed flop counts per step (MPT3D Table 3)"
              + (", but for the flagged ones below" if flagged else ""),
              MATCHED if len(same) == len(printed) - len(flagged) else DIFFERS,
              f"{len(same)} of {len(printed)} printed counts equal both the formulas and "
              "the counted paper-mode code")
    for r in printed:
        if r.flag:
            s.outcome(f"{r.paper} {r.system} {r.implementation}: printed {r.printed}",
                      DIFFERS, f"formula {r.formula}, paper mode {r.paper_mode}: {r.flag}")
    same = [f for f in audit.formulas if f.equal]
    s.outcome("the papers' burden formulas (MPT3D Table 2, SSPRED Table 2)",
              MATCHED if len(same) == len(audit.formulas) else DIFFERS,
              f"{len(same)} of {len(audit.formulas)} equal, term by term, the polynomial "
              "derived from the counts of paper-mode code")
    good = [sp for sp in audit.speedups if not sp.flag]
    s.outcome("the papers' speedups (ratios of flop counts)",
              MATCHED if len(good) == len(audit.speedups) else DIFFERS,
              f"{len(good)} of {len(audit.speedups)} recomputed from the formulas and the "
              "paper-mode code to the printed digits")
    for sp in audit.speedups:
        if sp.flag:
            s.outcome(f"{sp.paper} speedup {sp.what}: printed {sp.printed}", DIFFERS, sp.flag)


def section(ctx) -> Section:
    s = Section("burden", "Calculation burden: the papers' counts against derive's",
                paper="MPT3D, GSM2D")
    try:
        audit = ctx.result_of("audit", lambda: compute_audit(ctx.quick))
    except ImportError:
        s.add(Todo("derive.apps.audit is missing: no burden audit."))
        return s
    outcomes(s, audit)
    s.add(Text("For each implementation the papers compare: the number they print, their "
               "formula (MPT3D Tables 2-3), the exact count of derive's paper-mode code (the dense "
               "algorithm the formulas describe, generated and counted), and the count of "
               "derive's specialised code for the catalog model — also counted in the C file "
               "this run wrote ('written C'; in bold if it differed). Systems of independent "
               "axes count one axis times the axes."),
          audit_table(ctx, audit.rows), chart(ctx, audit.rows))
    if audit.formulas:
        s.add(Text("Each formula the papers print is parsed as a polynomial in n and m (N: "
                   "the FIR's order) and set beside the polynomial derive derives from the "
                   "counts of its paper-mode code: " + audit.formulas[0].method + "."),
              formula_table(audit))
    s.add(Table(("paper", "speedup", "printed", "from printed", "from formulas",
                 "from paper mode", "from specialised", "verdict"),
                tuple((sp.paper, sp.what, sp.printed,
                       "–" if sp.from_printed is None else f"{sp.from_printed:.{sp.decimals}f}",
                       f"{sp.from_formula:.{sp.decimals}f}",
                       f"{sp.from_paper_mode:.{sp.decimals}f}", f"{sp.from_specialised:.3f}",
                       sp.flag or "reproduced") for sp in audit.speedups),
                "The papers' speedups, recomputed from each column"),
          Table(("paper", "system", "eps", "N", "‖A^N‖₂", "FIR formula", "SSKF formula", "L",
                 "FIR paper mode", "FIR specialised", "SSKF specialised", "L specialised"),
                tuple((f.paper, f.system + (f" (×{f.axes})" if f.axes > 1 else ""),
                       f"{f.eps:g}", str(f.N), f"{f.norm_of_A_N:.2e}", str(f.fir_formula),
                       str(f.sskf_formula), str(f.L_formula), str(f.fir_paper_mode),
                       str(f.fir_specialised), str(f.sskf_specialised), str(f.L_specialised))
                      for f in audit.fir),
                "FIR steady-state filter: order N (least N with ‖A^N‖₂ < eps) and the "
                "break-even output interval L = ⌈FIR burden / SSKF burden⌉"))
    s.add(*(Text(f"Note: {note}") for note in audit.notes))
    return s
