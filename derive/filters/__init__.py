"""The filters derive can generate: a registry of names, families and applicability.

Each filter is data (a :class:`FilterKind`) plus one derivation function in its own
module, ``derive/filters/<module>.py``, with the signature
``derive_unit(model, options: dict) -> derive.program.Unit``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from ..errors import FilterError


@dataclass(frozen=True)
class FilterKind:
    name: str
    title: str
    model_kind: str  # "linear" or "nonlinear"
    steady: bool  # needs the Riccati solution offline (numbers only, no free symbols)
    module: str


FILTERS: dict[str, FilterKind] = {
    f.name: f
    for f in (
        FilterKind("kf", "Kalman filter", "linear", False, "kf"),
        FilterKind("lf", "Lainiotis filter", "linear", False, "lf"),
        FilterKind("jklf", "join Kalman-Lainiotis filter", "linear", False, "jklf"),
        FilterKind("ikf", "information-form Kalman filter (MDKF)", "linear", False, "ikf"),
        FilterKind("sskf", "steady-state Kalman filter", "linear", True, "steady"),
        FilterKind("sslf", "steady-state Lainiotis filter", "linear", True, "steady"),
        FilterKind("jssklf", "join steady-state Kalman-Lainiotis filter", "linear", True,
                   "steady"),
        FilterKind("fir", "FIR steady-state filter", "linear", True, "fir"),
        FilterKind("pred", "steady-state N-step prediction", "linear", True, "pred"),
        FilterKind("ekf", "extended Kalman filter", "nonlinear", False, "ekf"),
        FilterKind("ukf", "unscented Kalman filter", "nonlinear", False, "ukf"),
    )
}


def available(model) -> list[str]:
    """Filter names that apply to ``model`` (steady-state ones need all values given)."""
    out = []
    for f in FILTERS.values():
        if f.model_kind != model.kind:
            continue
        if f.steady and model.parameters:
            continue
        out.append(f.name)
    return out


def kind(name: str) -> FilterKind:
    try:
        return FILTERS[name]
    except KeyError:
        import difflib

        close = difflib.get_close_matches(name, list(FILTERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise FilterError(f"unknown filter {name!r}{hint}; filters: {', '.join(FILTERS)}") \
            from None


def derive_unit(model, name: str, options: dict | None = None):
    """Derive one filter for one model: the straight-line programs and layout facts."""
    f = kind(name)
    if f.model_kind != model.kind:
        raise FilterError(f"filter {name!r} needs a {f.model_kind} model; "
                          f"{model.name!r} is {model.kind}")
    if f.steady and model.parameters:
        from ..errors import SteadyStateError

        raise SteadyStateError(
            f"steady-state filter {name!r} needs every symbol to have a value; model "
            f"{model.name!r} has free symbols {[p.name for p in model.parameters]}")
    mod = importlib.import_module(f"{__name__}.{f.module}")
    return mod.derive_unit(model, name, dict(options or {}))
