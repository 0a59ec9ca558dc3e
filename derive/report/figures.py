"""Matplotlib figures for the report, drawn with the Agg backend (no display needed)."""

from __future__ import annotations

from pathlib import Path

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


def save(fig, folder: Path, name: str, caption: str) -> Figure:
    """Write ``name.png`` into ``folder`` (the report's figures/) and describe it."""
    path = folder / f"{name}.png"
    fig.savefig(path, dpi=100)
    return Figure(f"{folder.name}/{path.name}", caption)
