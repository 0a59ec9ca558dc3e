"""MPT3D and GSM2D: the twelve (eight) implementations, their equivalence, Fig. 1 (time-
varying vs steady-state estimates) and GSM2D's Fig. 2 (FIR vs SSKF).

Every estimate comes from the generated C. Model B runs once per independent block of
model A (``model.blocks()``) and the outputs are merged into model A's state order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ... import catalog
from ...filters.fir import order
from ...options import FirOptions
from ..simulate import simulate_linear
from . import figures
from .document import DIFFERS, MATCHED, Section, Table, Text, sci

TIME_VARYING = ("kf", "lf", "jklf")
STEADY = ("sskf", "sslf", "jssklf")
EQUAL = 1e-9  # relative to max(1, |reference|): equal up to rounding
CONVERGED = 1e-3  # KF against SSKF over the second half of the run: "converged"
FIR_CLOSE = 1e-5  # FIR against SSKF after N steps, relative to the largest |x|
SEED = 1
UNITS = {"position": "m", "velocity": "m/s"}   # the papers' example: Δt = 1 s
STEP_AXIS = "time step k (Δt = 1 s)"


@dataclass(frozen=True)
class Paper:
    key: str
    label: str
    model_a: str
    model_b: str
    axes: tuple[str, ...]


PAPERS = (Paper("mpt3d", "MPT3D", "mpt3d_a", "mpt3d_b", ("x", "y", "z")),
          Paper("gsm2d", "GSM2D", "gsm2d_a", "gsm2d_b", ("x", "y")))


def _run(ctx, model: str, f: str, zs, x0, P0):
    module = ctx.c_filter(model, f)
    if f in TIME_VARYING:
        xs, Ps = module.run(zs, x0, P0)
        return np.asarray(xs), np.asarray(Ps).reshape(len(zs), len(x0), len(x0))
    return np.asarray(module.run(zs, x0)), None


def rel(a, b) -> float:
    """max |a - b| / max(1, |b|) (0 for absent arrays)."""
    if a is None or b is None:
        return float("nan")
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


def implementations(ctx, paper: Paper, zs):
    """{('A' | 'B', filter): (xs, Ps or None)} and the block models of model A."""
    a, b = catalog.load(paper.model_a), catalog.load(paper.model_b)
    na, nb = a.numeric(), b.numeric()
    blocks = a.blocks()
    out = {}
    steps, n = len(zs), a.n
    for f in TIME_VARYING + STEADY:
        out[("A", f)] = _run(ctx, paper.model_a, f, zs, na.x0, na.P0)
        xs, Ps = np.zeros((steps, n)), np.zeros((steps, n, n))
        for blk in blocks:
            s, k = list(blk.states), list(blk.measurements)
            xb, Pb = _run(ctx, paper.model_b, f, zs[:, k], nb.x0, nb.P0)
            xs[:, s] = xb
            if Pb is not None:
                Ps[np.ix_(range(steps), s, s)] = Pb
        out[("B", f)] = (xs, Ps if f in TIME_VARYING else None)
    return out, blocks, nb


def equivalence_rows(paper: Paper, impl, blocks, nb, steps: int) -> list[tuple[str, ...]]:
    k = len(blocks)
    rows = []

    def add(what: str, one, two, close_only: bool = False):
        dx, dP = rel(one[0], two[0]), rel(one[1], two[1])
        worst = np.nanmax([dx, dP])
        verdict = ("close (not an identity)" if close_only else
                   "equal to rounding" if worst <= EQUAL else "**DIFFERENT**")
        rows.append((what, sci(dx), sci(dP), verdict))

    for label, name in (("A", "model A"), ("B", f"model B ×{k}")):
        add(f"KF = LF, {name}", impl[(label, "kf")], impl[(label, "lf")])
        add(f"KF = JKLF, {name}", impl[(label, "kf")], impl[(label, "jklf")])
        add(f"SSKF = SSLF, {name}", impl[(label, "sskf")], impl[(label, "sslf")])
        add(f"SSKF = JSSKLF, {name}", impl[(label, "sskf")], impl[(label, "jssklf")])
    for f in TIME_VARYING + STEADY:
        add(f"{f.upper()}: model A = model B ×{k}", impl[("A", f)], impl[("B", f)])
    worst_block = 0.0
    for blk in blocks:
        bn = blk.model.numeric()
        for key in ("F", "G", "H", "Q", "R", "x0", "P0"):
            worst_block = max(worst_block, rel(np.asarray(getattr(bn, key)),
                                               np.asarray(getattr(nb, key))))
    rows.append((f"each of the {k} blocks of model A = model B (F, G, H, Q, R, x0, P0)",
                 sci(worst_block), "–",
                 "equal" if worst_block == 0 else "**DIFFERENT**"))
    kf, ss = impl[("A", "kf")], impl[("A", "sskf")]
    add(f"KF vs SSKF, model A, all {steps} steps", kf, (ss[0], None), close_only=True)
    late = steps // 2
    add(f"KF vs SSKF, model A, steps {late + 1}..{steps}", (kf[0][late:], None),
        (ss[0][late:], None), close_only=True)
    return rows


def estimates_figure(ctx, paper: Paper, impl, truth) -> figures.Figure:
    fig, axes = figures.new(len(paper.axes), 2, height=2.2)
    t = np.arange(1, len(truth) + 1)
    for i, axis in enumerate(paper.axes):
        for j, (what, col) in enumerate((("position", 2 * i), ("velocity", 2 * i + 1))):
            ax = axes[i, j]
            ax.plot(t, truth[:, col], color=figures.COLORS["truth"], lw=0.8, label="true")
            for f in TIME_VARYING:
                ax.plot(t, impl[("A", f)][0][:, col], color=figures.COLORS["kf"], lw=1.2,
                        label="KF/LF/JKLF" if f == "kf" else None)
            for f in STEADY:
                ax.plot(t, impl[("A", f)][0][:, col], "--", color=figures.COLORS["steady"],
                        lw=1.2, label="SSKF/SSLF/JSSKLF" if f == "sskf" else None)
            ax.set_ylabel(f"{what} {axis} ({UNITS[what]})")
            if i == len(paper.axes) - 1:
                ax.set_xlabel(STEP_AXIS)
    axes[0, 0].legend(fontsize=8)
    name = f"{paper.key}_fig1_estimates"
    caption = (f"{paper.label} Fig. 1: position and velocity estimates x(k/k) of model A; "
               "solid: KF/LF/JKLF, dashed: SSKF/SSLF/JSSKLF (the three of each group "
               "coincide, see the table); grey: the simulated truth.")
    return figures.save(fig, ctx.figures, name, caption)


def fir_part(ctx, paper: Paper, zs, impl, section: Section) -> list:
    """GSM2D §7 Fig. 2: FIR vs SSKF on model A, and the FIR burden table."""
    model = catalog.load(paper.model_a)
    N = order(model, FirOptions())
    fir = np.asarray(ctx.c_filter(paper.model_a, "fir").run(zs))
    sskf = impl[("A", "sskf")][0]
    diff = np.max(np.abs(fir - sskf), axis=1)
    fig, axes = figures.new(len(paper.axes) + 1, 1, height=2.0)
    t = np.arange(1, len(zs) + 1)
    for i, axis in enumerate(paper.axes):
        ax = axes[i, 0]
        ax.plot(t, sskf[:, 2 * i], color=figures.COLORS["steady"], lw=1.2, label="SSKF")
        ax.plot(t, fir[:, 2 * i], "--", color=figures.COLORS["fir"], lw=1.2,
                label=f"FIR, N = {N}")
        ax.set_ylabel(f"position {axis} (m)")
    axes[0, 0].legend(fontsize=8)
    ax = axes[-1, 0]
    ax.semilogy(t, np.maximum(diff, 1e-18), color="k", lw=0.8)
    ax.axvline(N, color="0.5", ls=":", lw=0.8)
    ax.set_ylabel("max |FIR − SSKF| (m)")
    ax.set_xlabel(STEP_AXIS)
    fig_block = figures.save(
        fig, ctx.figures, f"{paper.key}_fig2_fir_vs_sskf",
        f"{paper.label} Fig. 2: FIR steady-state filter of order N = {N} (least N with "
        "‖A^N‖₂ < 1e-6) against the SSKF, model A, generated C; bottom: their largest "
        "difference per step (zero up to rounding for k ≤ N, where the dropped term "
        "A^N x(k−N) is A^N x0 = 0).")
    scale = max(1.0, float(np.max(np.abs(sskf))))
    after = float(diff[N:].max()) if len(zs) > N else 0.0
    section.outcome(f"§7 Fig. 2: the FIR filter of order N = {N} follows the SSKF",
                    MATCHED if after <= FIR_CLOSE * scale else DIFFERS,
                    f"max |FIR − SSKF| {float(diff[:N].max()):.1e} m for k ≤ N, "
                    f"{after:.1e} m after (largest |x| {scale:.3g} m)")
    rows = [("order N (least N with ‖A^N‖₂ < 1e-6)", str(N)),
            (f"max |FIR − SSKF|, steps 1..{min(N, len(zs))}", sci(float(diff[:N].max()))),
            (f"max |FIR − SSKF|, steps {N + 1}..{len(zs)}",
             sci(float(diff[N:].max())) if len(zs) > N else "–"),
            ("largest |x| (for scale)", f"{scale:.3g}")]
    return [fig_block, Table(("FIR vs SSKF, model A", "value"), tuple(rows),
                             f"{paper.label} §7: FIR steady-state filter (its burden and "
                             "break-even interval L are in the burden section)")]


def section(ctx, paper: Paper) -> Section:
    steps = 40 if ctx.quick else 100
    a = catalog.load(paper.model_a)
    na = a.numeric()
    run = simulate_linear(na.F, na.G, na.H, na.Q, na.R, na.x0, steps, SEED)
    impl, blocks, nb = implementations(ctx, paper, run.zs)
    s = Section(paper.key, f"{paper.label}: mobile position tracking, model A and model B",
                paper=paper.label)
    k = len(blocks)
    rows = equivalence_rows(paper, impl, blocks, nb, steps)
    exact = [r for r in rows if r[3] != "close (not an identity)"]
    worst = max(float(v) for r in exact for v in r[1:3] if v != "–")
    s.outcome(f"the {2 * len(TIME_VARYING + STEADY)} implementations give the same "
              "estimates (KF = LF = JKLF, SSKF = SSLF = JSSKLF, model A = model B per axis)",
              DIFFERS if any("DIFFERENT" in r[3] for r in exact) else MATCHED,
              f"{len(exact)} comparisons, largest relative difference {worst:.1e}")
    kf, ss = impl[("A", "kf")][0], impl[("A", "sskf")][0]
    late = rel(kf[steps // 2:], ss[steps // 2:])
    s.outcome("Fig. 1: the time-varying filters converge to the steady-state ones",
              MATCHED if late <= CONVERGED else DIFFERS,
              f"KF − SSKF, steps {steps // 2 + 1}..{steps}: {late:.1e} relative "
              f"(all steps {rel(kf, ss):.1e})")
    s.add(Text(f"Model A (`{paper.model_a}`, n = {a.n}, m = {a.m}) and model B "
               f"(`{paper.model_b}`, one axis, run ×{k}) with the papers' example values "
               f"(Δt = 1, σq² = 0.01, σr² = 0.1, x0 = 0, P0 = 0), {steps} steps simulated "
               f"from the model (seed {SEED}). The {2 * len(TIME_VARYING + STEADY)} "
               "implementations (KF, LF, JKLF, SSKF, SSLF, JSSKLF on model A and on model B) "
               "are derive's generated C."),
          estimates_figure(ctx, paper, impl, run.xs[1:]),
          Table(("comparison", "max rel diff x", "max rel diff P", "verdict"),
                tuple(rows),
                f"{paper.label}: equivalence of the implementations (generated C; "
                "differences relative to max(1, |second|))"))
    if paper.key == "gsm2d":
        s.add(*fir_part(ctx, paper, run.zs, impl, s))
    return s
