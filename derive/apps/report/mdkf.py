"""MDKF: a stationary object's 3-D position as three random-walk signals (catalog model
``gps_static``), estimated by the generated KF (covariance form) and the generated
information form; Figs. 4–7 and the statistics of Table 1 in the paper's layout.

The paper's data (time-difference signals of a UT+ Oncore receiver against a rubidium
standard) is not available; the signals here are simulated from the model.
"""

from __future__ import annotations

import numpy as np

from ... import catalog, reference
from ..simulate import simulate_linear
from . import figures
from .document import DIFFERS, MATCHED, NOT_COMPARABLE, Section, Table, Text, sci

SEED = 3
EQUAL = 1e-9   # relative: the two forms equal up to rounding
STEPS = 1000
QUICK_STEPS = 200
AXES = ("x (latitude)", "y (altitude)", "z (longitude)")
PAPER_TABLE1 = (  # MDKF Table 1, their signals in ns: (x, y, z)
    ("Mean value of the original signal", (4026.66, 2935.20, 5029.75)),
    ("Mean value of the estimate", (4059.92, 3008.72, 5017.71)),
    ("Mean of the error function", (31.35, 71.77, -14.17)),
    ("Root mean square deviation", (349.35, 285.02, 469.40)),
    ("Root mean square error", (350.76, 293.92, 469.61)),
    ("Maximal value of the error", (1460.30, 1152.73, 1767.88)),
)


def statistics(truth: np.ndarray, estimate: np.ndarray) -> list[np.ndarray]:
    """Per axis, in Table 1's order, with e = λ̂ − λ (eq. 37): mean of λ, mean of λ̂,
    mean of e, RMS deviation sqrt(mean((e − ē)²)), RMSE sqrt(mean(e²)), max |e|."""
    e = estimate - truth
    return [truth.mean(axis=0), estimate.mean(axis=0), e.mean(axis=0), e.std(axis=0),
            np.sqrt(np.mean(e ** 2, axis=0)), np.abs(e).max(axis=0)]


def section(ctx) -> Section:
    steps = QUICK_STEPS if ctx.quick else STEPS
    num = catalog.load("gps_static").numeric()
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, SEED)
    truth, zs = run.xs[1:], run.zs
    x_cov, P_cov = ctx.c_filter("gps_static", "kf").run(zs, num.x0, num.P0)
    x_inf, P_inf = ctx.c_filter("gps_static", "ikf").run(zs, num.x0, num.P0)
    x_ref, P_ref = reference.mdkf_covariance(num.F, num.G, num.H, num.Q, num.R, num.x0,
                                             num.P0, zs)

    def rel(a, b):
        a, b = np.asarray(a).reshape(b.shape), np.asarray(b)
        return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))

    s = Section("mdkf", "MDKF: stationary 3-D position, two algebraic forms of the KF",
                paper="MDKF")
    forms = max(rel(x_inf, x_cov), rel(P_inf, P_cov))
    s.outcome("the information form and the covariance form give the same estimates",
              MATCHED if forms <= EQUAL else DIFFERS,
              f"largest relative difference {forms:.1e} (x and P, generated C)")
    rmse = np.sqrt(np.mean((x_cov - truth) ** 2, axis=0))
    s.outcome("Table 1: statistics of the estimates", NOT_COMPARABLE,
              "the paper's receiver signals are not available; on simulated signals the "
              "RMSE is " + ", ".join(f"{v:.3f}" for v in rmse) + " a.u. (x, y, z)")
    s.add(Text(f"Catalog model `gps_static`: F = H = I3, G = I, Ψ = diag(υ, τ, ζ) = 0.01 I, "
               f"V = 0.1 I, x0 = 0, P0 = V; {steps} steps simulated from the model (seed "
               f"{SEED}). The paper's receiver signals are not available, so its numbers "
               "(in ns, a different scale) are shown for the layout only. Estimates: the "
               "generated C of the covariance form (`kf`) and of the information form "
               "(`ikf`)."))
    fig, axes = figures.new(3, 1, height=2.1)
    t = np.arange(1, steps + 1)
    for i, name in enumerate(AXES):
        ax = axes[i, 0]
        ax.plot(t, zs[:, i], ".", ms=2, color=figures.COLORS["measurement"],
                label="observation ξ")
        ax.plot(t, truth[:, i], color="k", lw=0.9, label="original signal λ")
        ax.plot(t, x_cov[:, i], color=figures.COLORS["kf"], lw=0.9, label="estimate λ̂")
        ax.set_ylabel(f"signal {name.split()[0]} (a.u.)")
    axes[-1, 0].set_xlabel("sample v (count)")
    axes[0, 0].legend(fontsize=8, ncol=3)
    s.add(figures.save(fig, ctx.figures, "mdkf_fig4_6_estimates",
                       "MDKF Figs. 4–6: Kalman estimates of the signals x, y and z with the "
                       "observations and the original signals (a.u.: the simulated model's "
                       "arbitrary unit; the paper's signals are in ns)."))
    fig, axes = figures.new(1, 1, height=3.0)
    err = x_cov - truth
    for i, name in enumerate(AXES):
        axes[0, 0].plot(t, err[:, i], lw=0.8, label=name)
    axes[0, 0].axhline(0, color="k", lw=0.5)
    axes[0, 0].set_xlabel("sample v (count)")
    axes[0, 0].set_ylabel("error e = λ̂ − λ (a.u.)")
    axes[0, 0].legend(fontsize=8)
    s.add(figures.save(fig, ctx.figures, "mdkf_fig7_errors",
                       "MDKF Fig. 7: the error function e = λ̂ − λ for x, y and z."))
    stats = statistics(truth, x_cov)
    rows = tuple((label, *(f"{v:.4f}" for v in ours), *(f"{v:.2f}" for v in paper))
                 for (label, paper), ours in zip(PAPER_TABLE1, stats))
    s.add(Table(("", "signal x", "signal y", "signal z", "paper x (ns)", "paper y (ns)",
                 "paper z (ns)"), rows,
                "MDKF Table 1: statistics of the 3-D Kalman estimates (RMS deviation: "
                "sqrt(mean((e − ē)²)); max: max |e|)"),
          Table(("comparison", "max rel diff x", "max rel diff P"),
                (("information form (ikf) = covariance form (kf), generated C",
                  sci(rel(x_inf, x_cov)), sci(rel(P_inf, P_cov))),
                 ("covariance form, generated C = NumPy MDKF covariance form",
                  sci(rel(x_cov, x_ref)), sci(rel(P_cov, P_ref)))),
                "MDKF: the two algebraic forms agree"))
    return s
