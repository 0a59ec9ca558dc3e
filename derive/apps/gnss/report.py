"""The text table of a real-data run (RealRunResult.table)."""

from __future__ import annotations

import numpy as np

from derive.apps.gnss.constants import SECONDS_PER_WEEK


def _applied(result) -> str:
    parts = ["broadcast satellite clock (af0..af2, relativistic term, −TGD)",
             "Sagnac rotation"]
    if result.corrections.troposphere:
        parts.append(f"Saastamoinen troposphere (mean {result.troposphere_mean:.2f} m)")
    if result.corrections.ionosphere:
        parts.append(f"Klobuchar ionosphere (mean {result.ionosphere_mean:.2f} m)")
    return ", ".join(parts)


def format_table(result) -> str:
    """Errors (m) of LS and each filter at the report times: 3-D, east, north, up."""
    s, names = result.settings, ["LS", *result.tracks]
    counts = result.satellite_counts
    week = int(result.start_gps_seconds // SECONDS_PER_WEEK)
    sow = result.start_gps_seconds % SECONDS_PER_WEEK
    q = f"diag({s.q_position:g}, {s.q_position:g}, {s.q_position:g}, {s.q_clock:g}) m²"
    kappa = -1.0 if s.kappa is None else s.kappa   # 3 − n, n = 4
    lines = [
        f"GPS C1C pseudoranges of {result.data_name}, GPS week {week} s {sow:.0f}, "
        f"{len(result.times)} epochs over {result.times[-1]:.0f} s, "
        f"{counts.min()}–{counts.max()} satellites above "
        f"{result.corrections.elevation_mask_deg:g}°",
        f"applied: {_applied(result)}",
        f"filters: sequential scalar updates in PRN order, σ = {s.sigma:g} m, Q = {q} per "
        f"epoch, P0 = {s.p0_std:g}² I, X0 = LS fix of epoch 0; UKF alpha = {s.alpha:g}, "
        f"beta = {s.beta:g}, kappa = {kappa:g}",
        "error vs the header's position (m): 3-D, east, north, up",
    ]
    head = f"{'t [s]':>6} " + " ".join(f"| {n + ' 3-D':>8} {'E':>6} {'N':>6} {'U':>6} "
                                         for n in names)
    lines += [head, "-" * len(head)]
    errors = {n: result.errors_enu(n) for n in names}
    for r in result.report_rows():
        cells = []
        for n in names:
            e = errors[n][r]
            cells.append(f"| {np.linalg.norm(e):8.2f} {e[0]:6.2f} {e[1]:6.2f} {e[2]:6.2f} ")
        lines.append(f"{result.times[r]:6.0f} " + " ".join(cells))
    rms = result.lsq_rms_3d
    lines.append(f"LS fixes' RMS 3-D error over {np.isfinite(result.lsq_states[:, 0]).sum()} "
                 f"epochs: {rms:.2f} m")
    for n in result.tracks:
        final = result.final_3d(n)
        verdict = "meets" if final <= rms else "MISSES"
        lines.append(f"{n}: final 3-D error {final:.2f} m {verdict} the bar "
                     f"(<= LS RMS {rms:.2f} m)")
    for n in result.tracks:
        summary = result.innovation_summary(n)
        lines.append(f"{n} normalised innovations per satellite (count, mean, RMS): " +
                     "; ".join(f"{p} {c} {m:+.2f} {r:.2f}" for p, (c, m, r) in summary.items()))
    return "\n".join(lines)
