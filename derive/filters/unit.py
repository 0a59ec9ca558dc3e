"""Wrap a filter's programs into the renderer's Unit, with the header facts it states."""

from __future__ import annotations

import numpy as np

from ..discretize import METHODS
from ..emit.unit import Unit


def _fmt(value) -> str:
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    arr = np.asarray(value, dtype=float)
    return np.array2string(arr, precision=17, separator=", ", max_line_width=88,
                           floatmode="unique").replace("\n", "")


def make_unit(model, name: str, programs: dict, options: dict, constants: dict | None = None,
              step_inputs: tuple[str, ...] = ("z",)) -> Unit:
    """The Unit for ``model`` and filter ``name``; ``constants`` become header facts."""
    facts = []
    if model.kind == "linear" and any(p.name == "P" for p in programs["step"].inputs):
        facts.append(f"P0 pattern declared: {options.get('P0_pattern') or model.P0_pattern}")
    if getattr(model, "continuous", None):
        facts.append(f"discretisation: {METHODS[model.continuous['method']]}")
    if options.get("joseph"):
        facts.append("covariance update: Joseph form")
    for key, value in (constants or {}).items():
        text = _fmt(value)
        facts.append(f"{key} = {text}" if len(text) <= 300 else
                     f"{key}: {np.asarray(value).shape} constants baked into the code")
    unit_options = {}
    if name == "fir":
        unit_options["window"] = int(options["N"])
    if name == "pred":
        unit_options["horizon"] = int(options["N"])
    if options.get("run_tracks") is False:
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
        command=options.get("command", ""),
        options=unit_options,
    )
