"""INS/GNSS: the generated EKF of the catalog model ``ins_gnss`` (docs/navigation.md) on the
simulated flight of derive.apps.ins.flight — agreement with the hand-written NumPy reference
over the whole flight, position, velocity and attitude errors against the truth with the filter's
3σ bounds, NIS per sensor against its chi-square band, bias estimates.
"""

from __future__ import annotations

import numpy as np

from ..ins import compare, flight, reference
from ..ins import constants as c
from ..ins.run import AGREEMENT, generated_run, stepwise_run
from . import figures
from .document import DIFFERS, MATCHED, Section, Table, Text, fmt, sci

SEED = 0
MODEL = "ins_gnss"
AXES = ("north", "east", "down")
NIS_BAND = 0.95
ZOOM_AFTER = 2.0   # s: the error panels' vertical scale is set by what follows


def _bounded(ax, t, error, sigma, unit_scale, label):
    ax.plot(t, error * unit_scale, lw=0.7, color=figures.COLORS["ekf"], label=f"{label} error")
    ax.plot(t, 3 * sigma * unit_scale, lw=0.7, color="0.4", ls="--", label="±3σ")
    ax.plot(t, -3 * sigma * unit_scale, lw=0.7, color="0.4", ls="--")
    # the first seconds (P0's wide bounds) would flatten the rest: scale to what follows
    later = t >= ZOOM_AFTER
    top = 1.15 * max(np.abs(error[later]).max(), 3 * sigma[later].max()) * unit_scale
    ax.set_ylim(-top, top)


def _error_figure(ctx, fl, err: compare.Errors):
    t = fl.t[1:]
    fig, axes = figures.new(3, 3, height=2.0)
    rows = (("position", err.position, err.position_sigma, 1.0, "m"),
            ("velocity", err.velocity, err.velocity_sigma, 1.0, "m/s"),
            ("attitude", err.attitude, err.attitude_sigma, np.degrees(1.0), "deg"))
    for r, (name, error, sigma, scale, unit) in enumerate(rows):
        for i, axis in enumerate(AXES):
            ax = axes[r, i]
            _bounded(ax, t, error[:, i], sigma[:, i], scale, name)
            ax.set_ylabel(f"{name} {axis} ({unit})")
            if r == 2:
                ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7)
    return figures.save(
        fig, ctx.figures, "ins_errors",
        "INS/GNSS (catalog model `ins_gnss`, generated C EKF, seed "
        f"{fl.seed}): estimate minus truth after each 100 Hz step with the filter's own ±3σ "
        "(dashed); the vertical scale is set by the flight after its first "
        f"{ZOOM_AFTER:g} s. Attitude: the rotation vector of q̂ ⊗ q⁻¹ about the NED axes, its σ "
        "from P's quaternion block mapped to first order. Heading is unobservable at rest "
        "(0–10 s) and becomes observable once the aircraft accelerates.")


def _nis_figure(ctx, nis):
    from scipy.stats import chi2

    fig, axes = figures.new(1, 2, height=3.0)
    for ax, (name, m) in zip(axes[0], (("gnss", 6), ("baro", 1))):
        rows, values = nis[name]
        low, high = chi2.ppf([(1 - NIS_BAND) / 2, (1 + NIS_BAND) / 2], m)
        ax.semilogy((rows + 1) * c.IMU_DT, values, ".", ms=2, color=figures.COLORS["ekf"],
                    label="NIS")
        ax.axhline(low, color="0.4", ls="--", lw=0.8, label=f"{NIS_BAND:.0%} χ²({m}) band")
        ax.axhline(high, color="0.4", ls="--", lw=0.8)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"{name} NIS (1)")
        ax.legend(fontsize=7)
    return figures.save(
        fig, ctx.figures, "ins_nis",
        "Normalised innovation squared ν' S⁻¹ ν of each update (S from the generated "
        "filter's predicted P), GNSS (6 dof) and barometer (1 dof), with the two-sided "
        f"{NIS_BAND:.0%} chi-square band.")


def _bias_figure(ctx, fl, err: compare.Errors):
    t = fl.t[1:]
    truth = np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS])
    fig, axes = figures.new(2, 3, height=2.0)
    for j in range(6):
        ax = axes[j // 3, j % 3]
        ax.plot(t, err.biases[:, j], lw=0.8, color=figures.COLORS["ekf"], label="estimate")
        ax.plot(t, err.biases[:, j] + 3 * err.bias_sigma[:, j], lw=0.6, ls="--", color="0.4",
                label="±3σ")
        ax.plot(t, err.biases[:, j] - 3 * err.bias_sigma[:, j], lw=0.6, ls="--", color="0.4")
        ax.axhline(truth[j], color=figures.COLORS["truth"], lw=0.8, ls=":", label="truth")
        axis = "xyz"[j % 3]
        ax.set_ylabel(f"gyro b{axis} (rad/s)" if j < 3 else f"accel b{axis} (m/s²)")
        if j >= 3:
            ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7)
    return figures.save(fig, ctx.figures, "ins_biases",
                        "Gyro and accelerometer bias estimates of the generated EKF with "
                        "their ±3σ, against the true constant biases.")


def section(ctx) -> Section:
    from scipy.stats import chi2

    s = Section("ins", "INS/GNSS: a strapdown EKF with IMU inputs and two sensors")
    fl = flight.simulate(SEED)
    ref_run = reference.run(fl)
    agreement = {}
    for lang, module in (("C", ctx.c_filter(MODEL, "ekf")),
                         ("Python", ctx.py_filter(MODEL, "ekf"))):
        xs, Ps = generated_run(module, fl)
        agreement[lang] = (float(compare.state_agreement(xs, ref_run.xs).max()),
                           compare.covariance_agreement(Ps, ref_run.Ps))
    steps = stepwise_run(ctx.c_filter(MODEL, "ekf"), fl)
    err = compare.errors(fl, steps.xs, steps.Ps)
    inside = compare.inside_fraction(fl, err)
    s.add(Text(
        "The model of docs/navigation.md (16 states: quaternion, NED velocity and position, "
        "gyro and accelerometer biases; the IMU's rate and specific force as inputs of f with "
        "input noise Qu mapped through ∂f/∂u; bias random walks σ² dt with dt a per-step "
        "parameter; sensors `gnss` (position and velocity, 6) and `baro` (altitude, 1); q "
        "renormalised after each update) on its simulated flight: 10 s at rest level heading "
        "north, 10 s accelerating north at 1.5 m/s² to 15 m/s, then a coordinated turn at "
        "0.15 rad/s climbing at 1 m/s to 120 s (yaw rate and climb rate rising over 2 s), the "
        "truth integrated at 1 kHz (exact attitude exponential per 1 ms, Simpson's rule for "
        "position); IMU at 100 Hz with the true biases and white noise σg, σa per sample, "
        "GNSS at 5 Hz and barometer at 20 Hz with R's noise; seed "
        f"{fl.seed}. One `run` call takes the 12,000 IMU rows with NaN rows where a sensor "
        "has no measurement."))
    s.add(_error_figure(ctx, fl, err), _nis_figure(ctx, steps.nis), _bias_figure(ctx, fl, err))
    rows = []
    for lang, (states, covariances) in agreement.items():
        rows.append((f"generated {lang} `run` vs NumPy reference", sci(states),
                     sci(covariances)))
    s.add(Table(("run", "states: max over states of max_k |Δx| / max(max_k |x|, σ0)",
                 "P: max_k |ΔP_ij| / sqrt(P_ii P_jj)"), tuple(rows),
                f"Whole-flight agreement with the hand-written NumPy EKF (bar {AGREEMENT:g})"))
    worst = max(max(v) for v in agreement.values())
    s.outcome("ins_gnss: generated EKF (Python and C) equals a NumPy EKF written from its "
              "equations over the whole 120 s flight", MATCHED if worst <= AGREEMENT else DIFFERS,
              f"largest relative difference {worst:.1e} (bar {AGREEMENT:g})")
    s.outcome(f"ins_gnss: position error inside the filter's 3σ at ≥ "
              f"{compare.INSIDE_BAR:.0%} of GNSS epochs",
              MATCHED if inside >= compare.INSIDE_BAR else DIFFERS,
              f"{inside:.1%} of {len(fl.gnss_rows)} epochs (all three axes inside)")
    nis_rows = []
    for name, m in (("gnss", 6), ("baro", 1)):
        _, values = steps.nis[name]
        low, high = chi2.ppf([(1 - NIS_BAND) / 2, (1 + NIS_BAND) / 2], m)
        share = float(np.mean((values >= low) & (values <= high)))
        nis_rows.append((name, str(m), str(len(values)), fmt(values.mean()),
                         f"{low:.3g}–{high:.3g}", f"{share:.1%}"))
    rms = np.sqrt((err.position ** 2).mean(axis=0))
    end = err.biases[-1]
    truth = np.concatenate([c.TRUE_GYRO_BIAS, c.TRUE_ACCEL_BIAS])
    s.add(Table(("sensor", "m", "updates", "mean NIS", f"{NIS_BAND:.0%} band",
                 "inside the band"), tuple(nis_rows), "NIS per sensor"),
          Table(("quantity", "value"),
                (("position RMS error n, e, d (m)", ", ".join(fmt(v) for v in rms)),
                 ("GNSS epochs with |position error| ≤ 3σ on all axes", f"{inside:.1%}"),
                 ("final gyro bias estimate (rad/s) / truth",
                  ", ".join(f"{a:.2e}/{b:.2e}" for a, b in zip(end[:3], truth[:3]))),
                 ("final accel bias estimate (m/s²) / truth",
                  ", ".join(f"{a:.3f}/{b:.3f}" for a, b in zip(end[3:], truth[3:])))),
                "The generated EKF against the truth"))
    return s
