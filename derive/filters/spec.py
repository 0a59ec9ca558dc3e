"""What a filter family declares beside its derivation: :class:`FilterSpec`.

Each ``derive/filters/<family>.py`` holds ``SPECS``, a tuple of the filters it derives
(one spec per filter name), next to ``derive_unit`` and its reference adapter; the
registry (:mod:`derive.filters`) is built from those tuples and nothing outside
``derive/filters/`` names a filter.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from ..flops import LANGUAGES
from ..options import SharedOptions

#: What a filter's step factorises, solves with, inverts or cancels (its
#: :attr:`FilterSpec.conditioning`); derive.apps.float_tolerance reads each one's
#: conditioning from a reference run.
INNOVATION = "S"
"""The innovation covariance S = H P(k/k-1) H^T + R (the gain K = P H^T S^-1)."""
PRIOR = "P(k/k-1)"
"""The predicted covariance."""
NEXT_PRIOR = "P(k+1/k)"
"""The next step's predicted covariance (the RTS smoother's backward gain solves with it
at output k)."""
POSTERIOR = "P(k/k)^-1"
"""The information, the filtered covariance's inverse (the information form inverts it)."""
NOISE = "R"
"""The measurement noise covariance (the information form's H^T R^-1)."""
LAINIOTIS = "I + P On"
"""The Lainiotis filter's I + P(k-1/k-1) On, On = F^T H^T A H F (its unpivoted LU)."""
NOMINAL = "H GQG^T H^T + R"
"""The Lainiotis filter's A^-1: the innovation covariance from P(k/k-1) = G Q G^T."""
UPDATE = "P(k/k-1) -> P(k/k)"
"""The update from P(k/k-1) to P(k/k): the standard form's subtraction P(k/k-1) - K (H
P(k/k-1)), whose result may be far smaller than its operands (the information form's
inverse of P(k/k-1) reaches P(k/k) as (I - K H) E (I - K H)^T, E of P(k/k-1)'s size)."""
MATRICES = (INNOVATION, PRIOR, NEXT_PRIOR, POSTERIOR, NOISE, LAINIOTIS, NOMINAL, UPDATE)

#: How: ``ldl``, an LDL^T solve with (or inverse of: one solve per column) a symmetric
#: positive-definite matrix, whose backward error is componentwise bounded by the
#: diagonal (so the condition of the diagonally scaled matrix bounds its effect); ``lu``,
#: an unpivoted LU inverse of a general matrix (the condition of the matrix itself);
#: ``cancel``, a subtraction (the ratio of its operands to its result).
METHODS = ("ldl", "lu", "cancel")


@dataclass(frozen=True)
class Conditioned:
    """One thing a filter's step factorises, solves with, inverts or cancels: ``matrix``
    (one of :data:`MATRICES`) and ``method`` (one of :data:`METHODS`)."""

    matrix: str
    method: str

    def __post_init__(self) -> None:
        if self.matrix not in MATRICES or self.method not in METHODS:
            raise ValueError(f"unknown conditioning: {self.matrix!r} by {self.method!r}")


@dataclass(frozen=True)
class FilterSpec:
    """One filter: its names, what it needs, how it runs, and where its code comes from.

    ``run_kind``: the run loop (a key of :data:`derive.emit.kinds.RUN_KINDS`).
    ``steady``: needs the Riccati solution offline (numbers only, no free symbols).
    ``options``: its options class (derive.options); it takes that class's options, the
    shared ones only with the flag each needs:
    ``covariance``: it carries P, so P0's declared pattern shapes its code (takes the
    option ``P0_pattern``).
    ``missing``: takes the option ``missing`` (NaN-marked absent measurements).
    ``loglik``: ``loglik(model, data, options) -> (lls, scales)``, the NumPy reference of
    each step's log-likelihood of the innovation and the scale its error is relative to
    (derive.reference.likelihood.loglik_scale; ``data`` as ``reference`` takes it); a
    filter with one takes the option ``loglik`` (run stores lls).
    ``run_tracks``: its C has ``MODEL_FILTER_run_tracks`` (unless ``--no-run-tracks``, the
    option ``run_tracks``).
    ``inputs``: it takes a model's per-step inputs u (a model that declares inputs is
    refused by every filter without this flag, never filtered with u ignored).
    ``sensors``: it takes a model with several sensors (``predict`` and one
    ``update_<sensor>`` per sensor, the run kind ``sensors``) and the options ``gate``
    and ``gate_sensors`` (a model with sensors is refused by every filter without this
    flag).
    ``start``: it takes the option ``start`` (update-first): through the run kind
    ``sensors`` with ``sensors``, else its run calls the program ``update`` (its step of
    the model without a prediction, derive.filters.unit.update_first_unit) at step 0.
    ``blockwise``: its derivation's work grows with the model's independent blocks, not
    with n as a whole (time-varying steps through derive.filters.blockwise unless P0's
    pattern is dense; steady maps from their non-zero constants): what bounds the model
    files it takes (derive.filters.blockwise.whole_states).
    ``vector_rows``: takes the option ``rows`` (its dense covariance work as vector rows,
    derive.filters.vector_rows).
    ``manifolds``: it takes (and needs) a model with manifold states, P in their tangent
    space (derive.manifolds); every other filter refuses such a model.
    ``sensors_reference``: the NumPy reference of its run kind sensors,
    ``(model, options, zs, us, ps, x0, P0, Rs, trace) -> SensorsResult`` (None: the
    EKF's and KF's, derive.filters.sensors.reference_run).
    ``conditioning``: what its step factorises, solves with, inverts or cancels at run
    time (:class:`Conditioned` s; empty for a filter whose constants are all computed
    offline in double): the conditioning its float32 tolerance takes
    (derive.apps.float_tolerance).
    ``extra_programs``: programs besides those of its run kind (ekf/ukf: predict, update1).
    ``derive``: ``derive(model, name, options) -> Unit``.
    ``applies``: ``applies(model) -> None`` or why the filter does not apply (checked after
    the model kind and, for a steady filter, free symbols and the Riccati conditions).
    ``check``: ``check(model, options)``, raising the error its derivation would raise for
    these options, cheaply: run for every filter of a generation before any is derived.
    ``reference``: ``reference(model, data, options) -> (xs, Ps or None)``, the NumPy
    reference on ``data`` (derive.apps.verify: measurements, or a nonlinear scenario).
    ``about``: the run function's one-line description per language (``{window}`` is
    replaced by the FIR window).
    ``listing``: position in listings (``derive list``, "all that apply").
    """

    name: str
    title: str
    model_kind: str
    run_kind: str
    derive: Callable
    reference: Callable
    options: type[SharedOptions] = SharedOptions
    steady: bool = False
    covariance: bool = False
    missing: bool = False
    loglik: Callable | None = None
    run_tracks: bool = False
    inputs: bool = False
    sensors: bool = False
    start: bool = False
    blockwise: bool = False
    vector_rows: bool = False
    manifolds: bool = False
    sensors_reference: Callable | None = None
    conditioning: tuple[Conditioned, ...] = ()
    extra_programs: tuple[str, ...] = ()
    applies: Callable | None = None
    check: Callable | None = None
    about: Mapping[str, str] = field(default_factory=dict)
    listing: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "about", MappingProxyType(dict(self.about)))
        object.__setattr__(self, "extra_programs", tuple(self.extra_programs))
        object.__setattr__(self, "conditioning", tuple(self.conditioning))

    def run_about(self, lang: str) -> str:
        """The run function's description in ``lang`` (the title's when none is given)."""
        return self.about.get(lang, f"Run the {self.title}.")

    def unit_fields(self, window: int | None = None, run_tracks: bool = True) -> dict:
        """The fields of a :class:`~derive.runs.unit.Unit` this spec decides: family,
        title, run kind, run descriptions, whether C has run_tracks, extra programs."""
        return {"family": self.name, "title": self.title, "run_kind": self.run_kind,
                "about": {lang: self.run_about(lang).format(window=window)
                          for lang in LANGUAGES},
                "run_tracks": self.run_tracks and run_tracks, "extra_programs": self.extra_programs}


__all__ = ["INNOVATION", "LAINIOTIS", "MATRICES", "METHODS", "NEXT_PRIOR", "NOISE", "NOMINAL",
           "POSTERIOR",
           "PRIOR", "UPDATE", "Conditioned", "FilterSpec"]
