"""INS/GNSS, error state: the generated error-state EKF of the catalog model ``ins_eskf``
(15 error states) on the flights of derive.apps.ins.flight — agreement with the error-state
EKF written by hand from Solà's kinematics (derive.apps.ins.error_state) over the whole
flight, and the estimate inside its own 3σ pooled over ten seeds, the total-state EKF of
``ins_gnss`` beside it on the same flights.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from ..ins import constants as c
from ..ins import error_state, flight, symforce_eskf
from .document import DIFFERS, MATCHED, Section, Table, Text, Todo, sci

MODEL = "ins_eskf"
SEEDS = 10
QUICK_SEEDS, QUICK_DURATION = 1, 30.0  # a quick run: one 30 s flight
AGREEMENT = 1e-10
PEER_MODELS = ("ins_eskf", "ins_fc24_eskf")


def section(ctx) -> Section:
    s = Section("ins_eskf", "INS/GNSS, error state: 15 error states on the same flight")
    eskf, ekf = ctx.c_filter(MODEL, "eskf"), ctx.c_filter("ins_gnss", "ekf")
    duration = QUICK_DURATION if ctx.quick else c.DURATION
    fl = flight.simulate(0, duration)
    ref = error_state.run(fl)
    xs, Ps = error_state.generated_run(eskf, fl)
    scale = np.maximum(np.abs(ref.xs).max(axis=0), 1e-2)
    states = float((np.abs(xs - ref.xs).max(axis=0) / scale).max())
    sd = np.sqrt(np.diagonal(ref.Ps, axis1=1, axis2=2))
    covariances = float((np.abs(Ps - ref.Ps) / (sd[:, :, None] * sd[:, None, :])).max())
    seeds = range(QUICK_SEEDS if ctx.quick else SEEDS)
    pooled = error_state.pooled_inside(eskf, ekf, seeds, duration)
    s.add(Text(
        "The ins_gnss model with its quaternion declared a unit quaternion (local error "
        "q_true = q ⊗ δq(δθ)): x keeps 16 numbers, P is 15 × 15 over δθ, δv, δp, δbg, δba. "
        "The error-state Jacobians are derived by sympy from the same first-order f; the "
        "reference is an error-state EKF written by hand from Solà's kinematics. Seed 0 "
        f"for the agreement; seeds 0–{len(seeds) - 1} for the 3σ consistency, the "
        f"total-state ins_gnss EKF on the same flights ({duration:g} s each)."))
    s.add(Table(("run", "states: max |Δx| / max(max_k |x|, 1e-2)",
                 "P: max_k |ΔP_ij| / sqrt(P_ii P_jj)"),
                (("generated C `run` vs the hand-written error-state EKF", sci(states),
                  sci(covariances)),),
                f"Whole-flight agreement (bar {AGREEMENT:g})"))
    rows = tuple((name, f"{pooled['eskf'][name]:.2%}", f"{pooled['ekf'][name]:.2%}")
                 for name, _ in error_state.QUANTITIES)
    s.add(Table(("quantity", "ins_eskf (error state)", "ins_gnss (total state)"), rows,
                f"Steps with the error inside the filter's 3σ on all three axes, pooled over "
                f"{len(seeds)} seeds"))
    worst = max(states, covariances)
    s.outcome("ins_eskf: generated error-state EKF equals the one written from Solà's "
              "kinematics over the whole flight", MATCHED if worst <= AGREEMENT else DIFFERS,
              f"largest relative difference {worst:.1e} (bar {AGREEMENT:g})")
    least = min(pooled["eskf"].values())
    s.outcome(f"ins_eskf: attitude, velocity and position inside 3σ at ≥ "
              f"{error_state.INSIDE_BAR:.0%} of steps over {len(seeds)} "
              + ("seed" if len(seeds) == 1 else "seeds"),
              MATCHED if least >= error_state.INSIDE_BAR else DIFFERS,
              ", ".join(f"{name} {v:.2%}" for name, v in pooled["eskf"].items())
              + " (ins_gnss: " + ", ".join(f"{name} {v:.2%}"
                                           for name, v in pooled["ekf"].items()) + ")")
    if ctx.quick:  # SymForce's code generation takes seconds per model
        s.add(Text("Quick run: the flops of the predict against SymForce's are left out."))
        return s
    peer_flops(ctx, s)
    return s


def peer_flops(ctx, s: Section) -> None:
    """The error-state predict's flops against SymForce's (Rot3 tangent Jacobians), both
    counted by derive's C rules; a note instead where SymForce is not installed."""
    if importlib.util.find_spec("symforce") is None:
        s.add(Todo("SymForce is not installed (`pip install symforce`; the `[report]` extra "
                   "installs it): the error-state predict's flops against SymForce's are "
                   "left out."))
        return
    rows, ratios = [], {}
    for model in PEER_MODELS:
        peer = symforce_eskf.generate(model)
        c_text = (ctx.generated / model / "eskf.c").read_text(encoding="utf-8")
        ours = symforce_eskf.derive_count(c_text, f"{model}_eskf").flops
        ratios[model] = ours / peer.count.flops
        rows.append((model, str(ours), str(peer.count.flops), f"{ratios[model]:.2f}",
                     f"{peer.seconds:.1f} s"))
    s.add(Table(("model", "derive eskf predict flops", "SymForce (Rot3 tangent Jacobians)",
                 "ratio", "SymForce's generation"), tuple(rows),
                "The error-state predict, x and P, both counted by derive's C rules "
                "(derive.apps.ins.symforce_eskf)"))
    worst = max(ratios, key=ratios.get)
    s.outcome(f"error-state predict flops ≤ {symforce_eskf.FLOPS_BAR:g}x SymForce's (Rot3 "
              "tangent-space Jacobians, one counter)",
              MATCHED if ratios[worst] <= symforce_eskf.FLOPS_BAR else DIFFERS,
              ", ".join(f"{m} {r:.2f}x" for m, r in ratios.items()))
