"""The filters derive can generate: a registry built from the families' specs.

Each family is one module, ``derive/filters/<family>.py``, holding ``SPECS`` (a tuple of
:class:`~derive.filters.spec.FilterSpec`, one per filter it derives) beside its
derivation ``derive_unit(model, spec, options) -> derive.runs.unit.Unit`` and its
reference adapter; ``options`` are the filter's typed options (derive.options), validated
before the derivation starts.  The registry finds the family modules by their ``SPECS``:
adding a family adds a module here and nothing else.
"""

from __future__ import annotations

import difflib
import importlib
import pkgutil
from collections.abc import Iterable, Mapping

from .. import progress, system_checks
from ..collection import few_collections
from ..errors import FilterError, ModelError, SteadyStateError
from ..options import use_filters, validate
from ..precision import DOUBLE, Precision, PrecisionError, precision
from ..schedule import latency_scheduled_unit
from .spec import FilterSpec
from .unit import checked_measurements, update_first_unit


def _family_specs() -> list[FilterSpec]:
    specs = []
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        specs += getattr(module, "SPECS", ())
    return sorted(specs, key=lambda s: (s.listing, s.name))


FILTERS: dict[str, FilterSpec] = {spec.name: spec for spec in _family_specs()}
"""Every filter by name, in listing order."""
use_filters(FILTERS)  # which filters take an option follows their specs (derive.options)

MISSING_FILTERS = tuple(name for name, spec in FILTERS.items() if spec.missing)
"""The filters that take the option ``missing``."""
"""The filters whose C may have ``MODEL_FILTER_run_tracks``."""


def names(model_kind: str | None = None) -> list[str]:
    """Filter names (of one model kind, when given), in listing order."""
    return [name for name, spec in FILTERS.items()
            if model_kind is None or spec.model_kind == model_kind]


def _inputs_refusal(model, spec: FilterSpec) -> str | None:
    """Why a filter without input support refuses a model that declares inputs."""
    if getattr(model, "inputs", ()) and not spec.inputs:
        return (f"filter {spec.name!r} takes no per-step inputs; model {model.name!r} "
                f"declares inputs {[u.name for u in model.inputs]}")
    return None


def _manifolds_refusal(model, spec: FilterSpec) -> str | None:
    """Why a filter that keeps P over the stored state refuses a model with manifold
    states (a quaternion's P lives in its tangent space), and why a filter of manifold
    states refuses a model without any."""
    manifolds = getattr(model, "manifolds", ())
    takers = ", ".join(name for name, s in FILTERS.items() if s.manifolds)
    if manifolds and not spec.manifolds:
        return (f"filter {spec.name!r} does not handle manifold states; model "
                f"{model.name!r} declares {manifolds[0].describe()} (the filters that do: "
                f"{takers})")
    if spec.manifolds and not manifolds:
        return (f"filter {spec.name!r} is for models with manifold states (a quaternion, "
                f"an angle); model {model.name!r} declares none")
    return None


def _sensors_refusal(model, spec: FilterSpec) -> str | None:
    """Why a filter without sensor support refuses a model with several sensors or with
    unit-norm groups."""
    if spec.sensors:
        return None
    manifolds = bool(getattr(model, "manifolds", ()))  # the takers that take this model
    takers = ", ".join(name for name, s in FILTERS.items()
                       if s.sensors and s.manifolds == manifolds)
    if any(g.R_argument for g in getattr(model, "sensors", ())):
        return (f"filter {spec.name!r} takes no R given per call; model {model.name!r} "
                f"declares sensor R = 'argument' (the filters that do: {takers})")
    if len(getattr(model, "sensors", ())) >= 2:
        return (f"filter {spec.name!r} takes no model with several sensors; model "
                f"{model.name!r} declares sensors {[s.name for s in model.sensors]} (the "
                f"filters that do: {takers})")
    if getattr(model, "unit_norm", ()):
        return (f"filter {spec.name!r} does not renormalise unit-norm groups; model "
                f"{model.name!r} declares unit_norm (the filters that do: {takers})")
    return None


def why_not(model, name: str) -> str | None:
    """Why filter ``name`` does not apply to ``model`` (None when it does)."""
    spec = kind(name)
    if spec.model_kind != model.kind:
        return f"filter {name!r} needs a {spec.model_kind} model; {model.name!r} is {model.kind}"
    refusal = (_manifolds_refusal(model, spec) or _inputs_refusal(model, spec)
               or _sensors_refusal(model, spec))
    if refusal is not None:
        return refusal
    if spec.steady and model.parameters:
        return (f"steady-state filter {name!r} needs every symbol to have a value; model "
                f"{model.name!r} has free symbols {[p.name for p in model.parameters]}")
    if spec.applies is not None:
        reason = spec.applies(model)
        if reason is not None:
            return reason
    if spec.steady:
        num = model.numeric()
        try:
            system_checks.check_steady_state(num.F, num.G, num.H, num.Q, num.R)
        except SteadyStateError as exc:  # the message names the property
            return str(exc)
    return None


def available(model) -> list[str]:
    """Filter names that apply to ``model``."""
    return [name for name in FILTERS if why_not(model, name) is None]


def check_before_deriving(model, names: Iterable[str], typed: Mapping, named: bool) -> None:
    """Refuse each of ``names`` (``typed``: filter name -> its options) as
    :func:`derive_unit` would, for what can be checked cheaply (whether the filter applies,
    its :attr:`FilterSpec.check`), before any of them is derived, so that a refusal comes
    first, not after the others' derivations; for filters not ``named`` (all that apply)
    the message says so."""
    for name in names:
        try:
            _refuse_if_not_applying(model, name)
            check = kind(name).check
            if check is not None:
                check(model, typed[name])
        except ModelError as exc:
            if named:
                raise
            raise type(exc)(f"{exc} (filter {name!r} is among all that apply to "
                            f"{model.name!r}; name the filters to derive with --filter)"
                            ) from None


def _refuse_if_not_applying(model, name: str) -> None:
    f = kind(name)
    reason = why_not(model, name)
    if reason is not None:
        raise (SteadyStateError if f.steady and f.model_kind == model.kind
               and _inputs_refusal(model, f) is None and _sensors_refusal(model, f) is None
               else
               FilterError)(reason)


def kind(name: str) -> FilterSpec:
    """The spec of filter ``name`` (FilterError naming a close match when unknown)."""
    try:
        return FILTERS[name]
    except (KeyError, TypeError):  # TypeError: not a hashable name
        text = name.lower() if isinstance(name, str) else ""
        close = ([text] if text in FILTERS
                 else difflib.get_close_matches(text, list(FILTERS), n=1))
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise FilterError(f"unknown filter {name!r}{hint}; filters: {', '.join(FILTERS)}") \
            from None


spec = kind


@few_collections()
def derive_unit(model, name: str, options=None):
    """Derive one filter for one model: the straight-line programs and layout facts.

    ``options``: a dict of options ``name`` takes (each is checked: derive.options.validate)
    or its typed options."""
    f = kind(name)
    typed = validate(name, options)
    _refuse_if_not_applying(model, name)
    if model.n >= progress.LARGE_MODEL_STATES:
        progress.report(f"deriving {name} for {model.name} ({model.n} states, "
                        f"{model.m} measurements)...")
    if typed.precision != DOUBLE.name:
        _check_constants(model, precision(typed.precision))
    unit = f.derive(model, f, typed)
    if typed.get("start", "predict") == "update" and unit.run_kind != "sensors":
        unit = update_first_unit(unit, model, f, typed)
    unit = checked_measurements(unit, model, f, typed)
    if typed.get("latency_schedule"):
        unit = latency_scheduled_unit(unit)
    return unit


__all__ = ["FILTERS", "MISSING_FILTERS", "FilterSpec", "available",
           "check_before_deriving", "derive_unit", "kind", "names", "spec", "why_not"]


def _check_constants(model, real: Precision) -> None:
    """Refuse, before deriving, a parameter value or a matrix entry at the given values
    (G Q G^T too) that ``real`` cannot hold, naming it: the refusal of a derived
    constant alone (2.5e-41, from sq2 = 1e-40) named neither."""
    named = [(f"parameter {name}", value) for name, value in model.values.items()]
    matrices = (("F", "G", "H", "Q", "R", "B", "D", "GQGt") if model.kind == "linear"
                else ("Q", "R", "Qu"))
    for which in matrices:
        mat = model.matrix(which) if model.kind == "linear" else getattr(model, which, None)
        if mat is None:
            continue
        mat = model.subs(mat)
        label = "G Q G^T" if which == "GQGt" else which
        named += [(f"matrix {label}[{i}][{j}]", mat[i, j])
                  for i in range(mat.rows) for j in range(mat.cols)
                  if mat[i, j].is_number and mat[i, j] != 0]
    for what, value in named:
        try:
            number = float(value)
        except (TypeError, ValueError):
            continue           # not a real number: the model's own checks say so
        try:
            real.literal(number)
        except PrecisionError as exc:
            raise PrecisionError(f"model {model.name!r}: {what} = {number!r}: {exc}") from None
