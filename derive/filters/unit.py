"""Wrap a filter's programs into the renderer's Unit, with the header facts it states.

The command that regenerates the files is the renderer's (derive.generation), not the
derivation's."""

from __future__ import annotations

import numpy as np

from ..emit.unit import Unit
from ..options import SharedOptions


def _fmt(value) -> str:
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    arr = np.asarray(value, dtype=float)
    return np.array2string(arr, precision=17, separator=", ", max_line_width=88,
                           floatmode="unique").replace("\n", "")


def make_unit(model, name: str, programs: dict, options: SharedOptions,
              constants: dict | None = None, step_inputs: tuple[str, ...] = ("z",),
              window: int | None = None, horizon: int | None = None) -> Unit:
    """The Unit for ``model`` and filter ``name`` with its validated ``options``;
    ``constants`` become header facts; ``window`` (fir) and ``horizon`` (pred): N."""
    facts = []
    if model.kind == "linear" and any(p.name == "P" for p in programs["step"].inputs):
        facts.append(f"P0 pattern declared: {options.get('P0_pattern') or model.P0_pattern}")
    for key, value in (constants or {}).items():
        text = _fmt(value)
        facts.append(f"{key} = {text}" if len(text) <= 300 else
                     f"{key}: {np.asarray(value).shape} constants baked into the code")
    unit_options = {}
    if window is not None:
        unit_options["window"] = window
    if horizon is not None:
        unit_options["horizon"] = horizon
    if not options.run_tracks:
        unit_options["run_tracks"] = False
    return Unit(
        model=model.name,
        filter=name,
        family=name,
        n=model.n,
        m=model.m,
        programs=programs,
        parameters=tuple(p.name for p in model.parameters),
        step_inputs=step_inputs,
        facts=tuple(f for f in facts if f),
        options=unit_options,
    )
