"""Matplotlib figures for the report, drawn with the Agg backend (no display needed)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .document import Figure

COLORS = {"truth": "0.35", "kf": "tab:blue", "lf": "tab:orange", "jklf": "tab:green",
          "steady": "tab:red", "fir": "tab:purple", "ekf": "tab:blue", "ukf": "tab:red",
          "ls": "0.5", "measurement": "0.65"}


def new(rows: int = 1, cols: int = 1, width: float = 10.0, height: float = 3.2,
        **kwargs):
    """A figure and its axes as a 2-D array (axes[row, col]), not tied to pyplot."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure as MplFigure

    fig = MplFigure(figsize=(width, height * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, **kwargs)
    return fig, axes


_UNIT = re.compile(r".*\S \([^()]+\)$")


def missing_units(fig) -> list[str]:
    """The axis labels of ``fig`` that do not end in a unit in parentheses ("x (m)"):
    every y label, and every x label that is set (panels stacked on one time axis label
    only the bottom one; a categorical axis has no label)."""
    bad = []
    for ax in fig.axes:
        if not ax.has_data():
            continue
        for label in (ax.get_ylabel(), ax.get_xlabel() or None):
            if label is not None and not _UNIT.fullmatch(label):
                bad.append(repr(label))
    return bad


def save(fig, folder: Path, name: str, caption: str) -> Figure:
    """Write ``name.png`` into ``folder`` (the report's figures/) and describe it; a
    figure with an axis label lacking its unit is refused (a bug in the report)."""
    bad = missing_units(fig)
    if bad:
        raise ValueError(f"figure {name}: axis label(s) without a unit: {', '.join(bad)}")
    path = folder / f"{name}.png"
    fig.savefig(path, dpi=100)
    return Figure(f"{folder.name}/{path.name}", caption)


LINESTYLES = ("-", "--", ":", "-.")
COINCIDE = 1e-3   # curves closer than this fraction of the panel's range are drawn as one


@dataclass(frozen=True)
class Drawn:
    """The curves of a panel as drawn: ``groups`` lists the labels drawn as one curve
    (they coincide), ``gap`` the largest difference within a group (0 if none merged)."""

    groups: tuple[tuple[str, ...], ...]
    gap: float

    @property
    def merged(self) -> bool:
        return any(len(g) > 1 for g in self.groups)


def plot_curves(ax, t, curves: dict[str, np.ndarray], colors: dict[str, str] | None = None,
                lw: float = 0.9) -> Drawn:
    """Plot several curves so each stays visible: a curve within ``COINCIDE`` of the
    panel's range of an earlier one is not drawn again but joins its label ("EKF = UKF");
    the curves drawn get distinct line styles (solid, dashed, dotted, ...)."""
    values = [np.asarray(y, dtype=float) for y in curves.values()]
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.zeros(1)
    span = float(np.ptp(finite)) if finite.size else 0.0
    groups: list[list[str]] = []
    reps: list[np.ndarray] = []
    gap = 0.0
    for label, y in zip(curves, values):
        for group, rep in zip(groups, reps):
            diff = float(np.nanmax(np.abs(y - rep))) if y.size else 0.0
            if diff <= COINCIDE * span:
                group.append(label)
                gap = max(gap, diff)
                break
        else:
            groups.append([label])
            reps.append(y)
    for i, (group, y) in enumerate(zip(groups, reps)):
        color = (colors or COLORS).get(group[0].lower())
        ax.plot(t, y, LINESTYLES[i % len(LINESTYLES)], color=color, lw=lw,
                label=" = ".join(group))
    return Drawn(tuple(tuple(g) for g in groups), gap)


def coincidence_note(drawn: list[Drawn], unit: str) -> str:
    """A caption sentence for panels drawn with :func:`plot_curves`."""
    merged = sorted({" and ".join(g) for d in drawn for g in d.groups if len(g) > 1})
    if not merged:
        return "Line styles tell the curves apart."
    gap = max(d.gap for d in drawn)
    return (f"{'; '.join(merged)} coincide (largest difference {gap:.1e} {unit}, under "
            f"{COINCIDE:g} of each panel's range) and are drawn as one curve.")
