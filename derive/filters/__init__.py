"""The filters derive can generate: a registry of names, families and applicability.

Each filter is data (a :class:`FilterKind`) plus one derivation function in its own
module, ``derive/filters/<module>.py``, with the signature
``derive_unit(model, name, options) -> derive.emit.unit.Unit``; ``options`` are the
filter's typed options (derive.options), validated before the derivation starts.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from .. import progress
from ..errors import FilterError, SteadyStateError
from ..options import validate


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


def why_not(model, name: str) -> str | None:
    """Why filter ``name`` does not apply to ``model`` (None when it does)."""
    import numpy as np

    f = kind(name)
    if f.model_kind != model.kind:
        return f"filter {name!r} needs a {f.model_kind} model; {model.name!r} is {model.kind}"
    if f.steady and model.parameters:
        return (f"steady-state filter {name!r} needs every symbol to have a value; model "
                f"{model.name!r} has free symbols {[p.name for p in model.parameters]}")
    if name == "ikf" and not model.parameters:
        W = np.array(model.matrix("GQGt").evalf(17).tolist(), dtype=float)
        if np.linalg.eigvalsh(W).min() <= 1e-12 * max(1.0, np.abs(W).max()):
            return (f"the information form needs G Q G^T positive definite (P(k+1/k) is "
                    f"inverted); model {model.name!r} has a singular G Q G^T")
    if f.steady:
        from .. import system_checks

        num = model.numeric()
        try:
            system_checks.check_steady_state(num.F, num.G, num.H, num.Q, num.R)
        except SteadyStateError as exc:  # the message names the property
            return str(exc)
    return None


def available(model) -> list[str]:
    """Filter names that apply to ``model``."""
    return [name for name in FILTERS if why_not(model, name) is None]


def kind(name: str) -> FilterKind:
    try:
        return FILTERS[name]
    except KeyError:
        import difflib

        close = difflib.get_close_matches(name, list(FILTERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise FilterError(f"unknown filter {name!r}{hint}; filters: {', '.join(FILTERS)}") \
            from None


def derive_unit(model, name: str, options=None):
    """Derive one filter for one model: the straight-line programs and layout facts.

    ``options``: a dict of options ``name`` takes (each is checked: derive.options.validate)
    or its typed options."""
    f = kind(name)
    typed = validate(name, options)
    reason = why_not(model, name)
    if reason is not None:
        raise (SteadyStateError if f.steady and f.model_kind == model.kind else
               FilterError)(reason)
    mod = importlib.import_module(f"{__name__}.{f.module}")
    if model.n >= progress.LARGE_MODEL_STATES:
        progress.report(f"deriving {name} for {model.name} ({model.n} states, "
                        f"{model.m} measurements)...")
    return mod.derive_unit(model, name, typed)
