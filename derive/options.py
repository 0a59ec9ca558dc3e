"""Filter options, declared once: one typed options class per family, each field with its
CLI flag, help, type, default and range.

``SharedOptions`` holds what several families share (P0 pattern, missing measurements,
the function ``run_tracks``); ``KalmanOptions`` (kf), ``FirOptions``,
``PredictionOptions`` and ``UnscentedOptions`` add their own. Plain dicts from the API
and the parsed arguments of the CLI are validated here, once, into these types
(:func:`validate`, :func:`per_filter`); the `derive generate` / `burden` / `verify` flags
(:func:`add_arguments`) and the command that regenerates a filter's files
(:func:`regenerate_command`) are built from the same declarations.

Which filters take an option follows their specs (derive.filters.spec.FilterSpec): a
filter takes the options of its options class (``FilterSpec.options``), a shared one only
when the spec has the flag the option ``needs`` (``covariance``, ``missing``, ``run_tracks``,
``loglik``).
The registry hands its specs over once it is built (:func:`use_filters`, called by
derive.filters), so this module names no filter and imports nothing from derive.filters.

Every refusal is an :class:`derive.errors.OptionError` naming the option: an unknown
name (with a close match), a wrong type (the string ``"False"`` for a bool), a value out
of range (naming the bound), an option given for one filter that does not take it.
Numbers in messages are printed as short decimals (``repr`` of the double).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from numbers import Integral, Real

import numpy as np

from .errors import OptionError
from .forms import ROW_FORMS, UPDATE_FORMS
from .horizon import MAX_FIR_TAPS, MAX_FIR_WINDOW, MAX_HORIZON
from .precision import NAMES as PRECISIONS

PATTERNS = ("dense", "zero", "diagonal", "block")

START_CHOICES = ("predict", "update")
"""run's first step (option ``start``): predict-first (the papers'), or update-first."""
C_PREFIX = r"(?:[A-Za-z][A-Za-z0-9_]*)?"
"""What ``--prefix`` may be: empty, or a letter then letters, digits and underscores (so
PREFIX + MODEL_FILTER is a C identifier, and never one C reserves: ``_X``, ``__x``)."""
"""Declared sparsity patterns of P0 (derive.filters.pattern.declared)."""

DEFAULT_EPS = 1e-6
"""The FIR order is the least N with ||A^N||_2 < eps, by default this eps."""
MAX_EKF_ITERATIONS = 8
"""Most relinearisations of the iterated EKF's update (each one unrolls h, H, S and K
again)."""
UKF_ALPHA_RANGE = (1e-4, 1.0)
"""alpha as Wan and van der Merwe (2000) bound it: below 1e-4 the sigma points coincide
with the mean in double precision, and the weights grow past what doubles carry."""


@dataclass(frozen=True)
class Spec:
    """What an option is, besides its name and default: see :func:`option`.

    ``needs``: the flag of a filter's spec (derive.filters.spec.FilterSpec) without which
    the filter does not take this option even when its options class has it (a shared
    option); None: every filter whose options class has it takes it."""

    flag: str
    help: str
    kind: type
    needs: str | None = None
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    choices: tuple[str, ...] = ()
    formerly: tuple[str, ...] = ()
    metavar: str | None = None
    pattern: str | None = None
    pattern_words: str = ""

    def bounds(self) -> str:
        """``(0, 1)``, ``[1, 256]``, ``>= 1``: the range in words (empty: any value)."""
        low, high = (None if v is None else f"{v:g}" for v in (self.low, self.high))
        if self.low is not None and self.high is not None:
            return (f"{'(' if self.open_low else '['}{low}, {high}"
                    f"{')' if self.open_high else ']'}")
        if self.low is not None:
            return f"{'>' if self.open_low else '>='} {low}"
        if self.high is not None:
            return f"{'<' if self.open_high else '<='} {high}"
        return ""

    def in_range(self, value) -> bool:
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.open_low else value < self.low):
            return False
        return self.high is None or (value < self.high if self.open_high else
                                     value <= self.high)


def option(default, **spec) -> dataclasses.Field:
    """A dataclass field declaring one option (``spec``: the fields of :class:`Spec`)."""
    return field(default=default, metadata={"option": Spec(**spec)})


@dataclass(frozen=True, kw_only=True)
class SharedOptions:
    """Options several families share; the base of every family's options."""

    P0_pattern: str | None = option(
        None, flag="--P0-pattern", kind=str, choices=PATTERNS, needs="covariance",
        help="declared sparsity of P0 (default: the model's)")
    missing: bool = option(
        False, flag="--missing", kind=bool, needs="missing",
        help="a NaN in z skips that measurement")
    loglik: bool = option(
        False, flag="--loglik", kind=bool, needs="loglik",
        help="run also returns each step's Gaussian log-likelihood of the innovation "
             "(lls; C: may be NULL, run_tracks too), from the factors of S the update "
             "solves with")
    gradient: bool = option(
        False, flag="--gradient", kind=bool, needs="loglik",
        help="with --loglik: run also returns each step's exact gradient of the "
             "log-likelihood with respect to the free parameters p (dlls; C: may be NULL), "
             "by the sensitivity recursion (run_tracks too)")
    run_tracks: bool = option(
        True, flag="--no-run-tracks", kind=bool, needs="run_tracks",
        help="C: leave out MODEL_FILTER_run_tracks (smaller files)")
    gate: float | None = option(
        None, flag="--gate", kind=float, low=0.0, high=1.0, open_low=True, open_high=True,
        needs="sensors", metavar="PROB",
        help="innovation gating: skip an update whose NIS exceeds the chi-square quantile "
             "at PROB (its measurements' count of degrees of freedom); report NIS and "
             "whether it was applied")
    gate_sensors: str | None = option(
        None, flag="--gate-sensors", kind=str, needs="sensors", metavar="NAME=PROB,...",
        pattern=r"[A-Za-z][A-Za-z0-9_]*=[0-9.eE+-]+(,[A-Za-z][A-Za-z0-9_]*=[0-9.eE+-]+)*",
        pattern_words="sensor=probability pairs separated by commas, e.g. gnss=0.999,baro=0.99",
        help="innovation gating per sensor (overrides --gate for the sensors named)")
    start: str = option(
        "predict", flag="--start", kind=str, choices=START_CHOICES, needs="start",
        help="run's first step: predict then update (predict, the default), or update x0 "
             "with the first measurement without a prediction (update: pykalman's "
             "convention)")
    update: str | None = option(
        None, flag="--update", kind=str, choices=UPDATE_FORMS, needs="sensors",
        help="how each sensor's update fuses its measurements: batch (one LDL^T solve of "
             "S) or sequential (one scalar update per measurement; R diagonal, or constant: "
             "decorrelated at generation); default: as each sensor declares (batch unless "
             "its model says sequential)")
    rows: str | None = option(
        None, flag="--rows", kind=str, choices=ROW_FORMS, needs="vector_rows",
        help="how the dense covariance work (F P F^T + Q, a sequential update's rank-m "
             "pass) is derived: scalar (entry by entry) or vector (rows of four lanes, "
             "printed in C as GCC/Clang vector statements with the scalar lanes as the "
             "fallback; P read whole); default: as the model declares (scalar unless it "
             "says vector)")
    prefix: str = option(
        "", flag="--prefix", kind=str, metavar="PREFIX", pattern=C_PREFIX,
        pattern_words="empty or a letter followed by letters, digits and underscores",
        help="C: put PREFIX in front of every name the files export (functions, macros, "
             "the status enum and the include guard)")
    precision: str = option(
        "double", flag="--precision", kind=str, choices=PRECISIONS,
        help="C: the floating-point type of the generated C, double or float (float32; "
             "the Python stays double)")
    run: bool = option(
        True, flag="--no-run", kind=bool,
        help="C: leave out MODEL_FILTER_run (run_tracks, when kept, keeps it as a static "
             "function for its last tracks); --lang c leaves out the Python file")

    def __post_init__(self) -> None:
        for key, spec in self.specs().items():
            object.__setattr__(self, key, _checked(key, spec, getattr(self, key),
                                                   _default(type(self), key)))

    @classmethod
    def specs(cls) -> dict[str, Spec]:
        """``{option name: Spec}`` of this family, in declaration order."""
        return {f.name: f.metadata["option"] for f in dataclasses.fields(cls)}

    def get(self, name: str, default=None):
        """The value of option ``name`` (``default`` when this family has none)."""
        return getattr(self, name) if name in self.specs() else default

    def changed(self) -> dict[str, object]:
        """The options whose values differ from the defaults."""
        return {key: getattr(self, key) for key in self.specs()
                if getattr(self, key) != _default(type(self), key)}


@dataclass(frozen=True, kw_only=True)
class KalmanOptions(SharedOptions):
    joseph: bool = option(
        False, flag="--joseph", kind=bool,
        help="Joseph-form covariance update")
    latency_schedule: bool = option(
        False, flag="--latency-schedule", kind=bool,
        help="a shorter carried chain for the run loop at the price of some flops "
             "(derive burden prints both chains and the flops added)")


@dataclass(frozen=True, kw_only=True)
class FirOptions(SharedOptions):
    eps: float = option(
        DEFAULT_EPS, flag="--eps", kind=float, low=0.0, high=1.0,
        open_low=True, open_high=True, metavar="EPS",
        help=f"order N is the least with ||A^N||_2 < eps ({DEFAULT_EPS:g})")
    order: int | None = option(
        None, flag="--order", kind=int, low=1, high=MAX_FIR_WINDOW,
        formerly=("N", "window"), metavar="N",
        help=f"order N directly (N m <= {MAX_FIR_WINDOW} and N n m <= {MAX_FIR_TAPS})")


@dataclass(frozen=True, kw_only=True)
class PredictionOptions(SharedOptions):
    horizon: int = option(
        1, flag="--horizon", kind=int, low=1, high=MAX_HORIZON,
        formerly=("N",), metavar="N", help="steps ahead N (1)")


@dataclass(frozen=True, kw_only=True)
class ExtendedOptions(SharedOptions):
    iterations: int = option(
        0, flag="--iterations", kind=int, low=0, high=MAX_EKF_ITERATIONS,
        help="iterated EKF update: relinearise h this many times at the updated estimate "
             "(0: the plain EKF)")


@dataclass(frozen=True, kw_only=True)
class UnscentedOptions(SharedOptions):
    alpha: float = option(
        1.0, flag="--alpha", kind=float, low=UKF_ALPHA_RANGE[0],
        high=UKF_ALPHA_RANGE[1], help="sigma-point spread alpha (1)")
    beta: float = option(
        0.0, flag="--beta", kind=float, help="sigma-point beta (0)")
    kappa: float | None = option(
        None, flag="--kappa", kind=float,
        help="sigma-point kappa (3 - n: the paper's n + kappa = 3)")


# -- the filters that take them: their specs, handed over by the registry ----------------------

_filters: dict[str, object] = {}
"""``{filter name: its spec}`` in listing order (:func:`use_filters`)."""


def use_filters(filters: Mapping[str, object]) -> None:
    """Take the filters' specs (``{name: spec}``, each with ``options``, the options class,
    and the flags options need): derive.filters calls this once its registry is built, so
    that which filters take an option follows the specs without this module importing
    the registry (which imports the options classes from here)."""
    _filters.clear()
    _filters.update(filters)


def _filter(name: str):
    if not _filters:
        raise RuntimeError("no filters registered with derive.options (derive.filters "
                           "calls use_filters when it is imported)")
    return _filters.get(name)


def options_type(name: str) -> type[SharedOptions]:
    """The options class of filter ``name`` (its spec's; SharedOptions when unknown)."""
    spec = _filter(name)
    return SharedOptions if spec is None else spec.options


def families() -> list[type[SharedOptions]]:
    """SharedOptions, then the options class of each filter (listing order), each once."""
    _filter("")
    return list(dict.fromkeys([SharedOptions] + [s.options for s in _filters.values()]))


def all_specs() -> dict[str, Spec]:
    """Every option of every family, shared ones first, each once."""
    out: dict[str, Spec] = {}
    for cls in families():
        out.update(cls.specs())
    return out


def taken_by(name: str) -> list[str]:
    """The names of the options filter ``name`` takes: those of its options class, a
    shared one only when its spec has the flag the option needs."""
    spec = _filter(name)
    if spec is None:
        return []
    return [key for key, option_spec in spec.options.specs().items()
            if option_spec.needs is None or getattr(spec, option_spec.needs)]


def takers(key: str) -> list[str]:
    """The filters (listing order) that take option ``key``."""
    _filter("")
    return [name for name in _filters if key in taken_by(name)]


def validate(name: str, values: Mapping | SharedOptions | None = None) -> SharedOptions:
    """The typed options of filter ``name`` from ``values`` (every key must be an option
    ``name`` takes, of the right type and in range)."""
    if isinstance(values, SharedOptions):
        values = values.changed()
    values = _mapping(values, f"options of {name}")
    takes = taken_by(name)
    for key in values:
        if key not in takes:
            raise OptionError(_not_taken(key, name, takes))
    return options_type(name)(**{key: check(key, value) for key, value in values.items()})


def per_filter(names: Iterable[str], options: Mapping | None = None,
               per_filter_options: Mapping[str, Mapping] | None = None,
               named: bool = True) -> dict[str, SharedOptions]:
    """``{filter: typed options}`` for one call generating ``names``.

    ``options`` apply to the call: each filter is given those it takes (and no other).
    ``per_filter_options`` name one filter; every key must be one that filter takes.
    ``named``: the filters were named by the caller (not "all that apply"), so an option
    of the call that none of them takes is refused rather than ignored."""
    names = list(names)
    common = _mapping(options, "options")
    per = _mapping(per_filter_options, "per-filter options")
    specs = all_specs()
    for key, value in common.items():
        if key not in specs:
            raise OptionError(_unknown(key, list(specs), "options", names))
        check(key, value)
        if named and names and not any(n in takers(key) for n in names):
            raise OptionError(f"option {key!r} is taken by {', '.join(takers(key))}; "
                              f"none of the filters of this call ({', '.join(names)}) "
                              "takes it")
    for filter_name in per:
        if filter_name not in names:
            raise OptionError(f"per-filter options for {filter_name!r}, which this call "
                              f"does not generate (filters: {', '.join(names)})")
    out = {}
    for filter_name in names:
        takes = taken_by(filter_name)
        mine = {k: v for k, v in common.items() if k in takes}
        mine.update(_mapping(per.get(filter_name), f"options of {filter_name}"))
        out[filter_name] = validate(filter_name, mine)
    return out


def check(key: str, value):
    """``value`` of option ``key`` as its type (an int stays an int for a float option),
    refused when of the wrong type or out of range."""
    return _checked(key, all_specs()[key], value, _default_anywhere(key))


def _checked(key: str, spec: Spec, value, default):
    if value is None:
        if default is None:
            return None
        raise OptionError(f"option {_label(key, spec)} must be {_kind_words(spec)}, "
                          "got None")
    if spec.kind is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise OptionError(_wrong_type(key, spec, value))
        return bool(value)
    if spec.kind is str:
        if not isinstance(value, str):
            raise OptionError(_wrong_type(key, spec, value))
        if spec.choices and value not in spec.choices:
            close = difflib.get_close_matches(value, spec.choices, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise OptionError(f"option {_label(key, spec)} must be one of "
                              f"{', '.join(spec.choices)}, got {value!r}{hint}")
        if spec.pattern is not None and not re.fullmatch(spec.pattern, value):
            raise OptionError(f"option {_label(key, spec)} must be {spec.pattern_words}, "
                              f"got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, Real):
        raise OptionError(_wrong_type(key, spec, value))
    if spec.kind is int:
        if not isinstance(value, Integral):
            raise OptionError(_wrong_type(key, spec, value))
        value = int(value)
    else:
        value = float(value)
    if not spec.in_range(value):
        bounds = spec.bounds()
        where = f" in {bounds}" if bounds[:1] in "([" else f" {bounds}"
        raise OptionError(f"option {_label(key, spec)} must be "
                          f"{'an integer' if spec.kind is int else 'a finite number'}"
                          f"{where if bounds else ''}, got {_short(value)}")
    return value


# -- the command line -------------------------------------------------------------------------


def add_arguments(parser) -> None:
    """The flag of every option (one argument group), from the declarations."""
    group = parser.add_argument_group(
        "filter options", "each is given to the filters in brackets (and no other)")
    for key, spec in all_specs().items():
        bounds = f"; {spec.bounds()}" if spec.bounds() else ""
        text = f"{spec.help}{bounds} [{', '.join(takers(key))}]"
        if spec.kind is bool:
            default = _default_anywhere(key)
            group.add_argument(spec.flag, dest=key, default=None,
                               action="store_const", const=not default, help=text)
        elif spec.kind is str:
            group.add_argument(spec.flag, dest=key, default=None,
                               choices=spec.choices or None, metavar=spec.metavar,
                               help=text)
        else:
            group.add_argument(spec.flag, dest=key, default=None, type=spec.kind,
                               metavar=spec.metavar or key.upper(), help=text)


def from_arguments(args) -> dict[str, object]:
    """The options given on the command line (parsed by :func:`add_arguments`)."""
    return {key: getattr(args, key) for key in all_specs()
            if getattr(args, key, None) is not None}


def regenerate_command(model_ref: str, name: str, options: SharedOptions, out: str,
                       lang: str = "all") -> str:
    """The command line that regenerates filter ``name``'s files (those of ``lang``) with
    ``options``."""
    parts = ["derive generate", model_ref, f"--filter {name}", f"--lang {lang}",
             f"--out {out}"]
    specs = options.specs()
    for key, value in options.changed().items():
        spec = specs[key]
        parts.append(spec.flag if spec.kind is bool else
                     f"{spec.flag} {value if spec.kind is str else _short(value)}")
    return " ".join(parts)


def python_command(model, name: str, options: SharedOptions, out: str,
                   lang: str = "all") -> str:
    """The Python call that regenerates filter ``name``'s files for ``model``, a model
    object built in Python (no catalog name or file names it, so no command line does)."""
    changed = options.changed()
    extra = f", options={changed!r}" if changed else ""
    return (f"derive.generate(model, {name!r}, lang={lang!r}, out={out!r}{extra}), model "
            f"the {type(model).__name__} {model.name!r} built in Python")


# -- messages ---------------------------------------------------------------------------------


def _short(value) -> str:
    """A number as a short decimal (the double's repr; integers as integers)."""
    if value is None:
        return "None"
    if isinstance(value, Integral) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, Real) and not isinstance(value, bool):
        return repr(float(value))
    return repr(value)


def _label(key: str, spec: Spec) -> str:
    return f"{key!r} ({spec.flag})"


def _kind_words(spec: Spec) -> str:
    return {bool: "a bool (True or False)", int: "an integer", float: "a real number",
            str: "a string"}[spec.kind]


def _wrong_type(key: str, spec: Spec, value) -> str:
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return (f"option {_label(key, spec)} must be {_kind_words(spec)}, got the "
            f"{type(value).__name__} {shown}")


def _unknown(key, known: list[str], what: str, filters: Sequence[str] = ()) -> str:
    hint = _close(key, known, filters)
    return (f"unknown option {key!r}{hint}; {what}: {', '.join(known) or 'none'}")


def _close(key, known: list[str], filters: Sequence[str] = ()) -> str:
    """`` (did you mean 'order'?)``: the option ``key`` was formerly called, one that
    ``filters`` (the call's) take first (``N`` was FIR's order and the predictor's
    horizon), else the closest spelling."""
    if not isinstance(key, str):
        return ""
    formerly = [new for new in known if key in all_specs()[new].formerly]
    if formerly:
        mine = [new for new in formerly if any(f in takers(new) for f in filters)]
        if len(mine) == 1 or (len(formerly) == 1 and not mine):
            return f" (did you mean {(mine or formerly)[0]!r}?)"
        return " (did you mean " + " or ".join(
            f"{new!r} ({', '.join(takers(new))})" for new in mine or formerly) + "?)"
    close = difflib.get_close_matches(key, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _not_taken(key, name: str, takes: list[str]) -> str:
    specs = all_specs()
    if key in specs:
        return (f"option {key!r} is taken by {', '.join(takers(key))}, not by {name}; "
                f"options of {name}: {', '.join(takes) or 'none'}")
    return _unknown(key, takes, f"options of {name}")


def _mapping(values, what: str) -> dict:
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise OptionError(f"{what} must be a mapping of option names to values, got the "
                          f"{type(values).__name__} {values!r}")
    return dict(values)


def _default(cls: type[SharedOptions], key: str):
    return next(f.default for f in dataclasses.fields(cls) if f.name == key)


def _default_anywhere(key: str):
    for cls in families():
        if key in cls.specs():
            return _default(cls, key)
    raise KeyError(key)


__all__ = ["DEFAULT_EPS", "FirOptions", "KalmanOptions", "PATTERNS", "PredictionOptions",
           "SharedOptions", "Spec", "UnscentedOptions", "add_arguments",
           "all_specs", "check",
           "families", "from_arguments", "option", "options_type", "per_filter",
           "regenerate_command", "taken_by", "takers", "use_filters", "validate"]
