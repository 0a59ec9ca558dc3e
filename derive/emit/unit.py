"""A generation unit (one model, one filter) and the interface of each filter family.

A :class:`Unit` is everything the renderer needs and nothing it must compute
about filters: names, sizes, the programs (``step``; for ``pred`` also ``init``;
for ``ekf``/``ukf`` also ``predict`` and, optionally, ``update1``, the sequential
form for a varying number of measurements), header facts and the regeneration
command.  :data:`FAMILIES` says
which ports each family's programs must have; the run loop of each *kind*
(time-varying, steady, FIR, prediction) lives in its templates and its
arguments in :func:`run_arguments`.
"""

from __future__ import annotations

import keyword
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from derive.program import PARAMETER_PORT, Program, ProgramError

_IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Family:
    """A filter family: template name, kind of run loop, title."""

    name: str
    kind: str
    title: str


KINDS = ("timevarying", "steady", "fir", "pred")

FAMILIES: Mapping[str, Family] = MappingProxyType({f.name: f for f in (
    Family("kf", "timevarying", "Kalman filter"),
    Family("lf", "timevarying", "Lainiotis filter"),
    Family("jklf", "timevarying", "joint Kalman-Lainiotis filter"),
    Family("ikf", "timevarying", "information-form Kalman filter"),
    Family("ekf", "timevarying", "extended Kalman filter"),
    Family("ukf", "timevarying", "unscented Kalman filter"),
    Family("sskf", "steady", "steady-state Kalman filter"),
    Family("sslf", "steady", "steady-state Lainiotis filter"),
    Family("jssklf", "steady", "joint steady-state Kalman-Lainiotis filter"),
    Family("fir", "fir", "steady-state FIR filter"),
    Family("pred", "pred", "steady-state N-step predictor"),
)})


EXTRA_PROGRAMS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "predict": ("ekf", "ukf"),
    "update1": ("ekf", "ukf"),
})
"""Programs besides step and init, and the families that may have them:
``predict(x, P[, p]) -> (x_new, P_new)`` and
``update1(x, P, z[1][, u][, p]) -> (x_new, P_new, innovation[1], variance[1])``."""


@dataclass(frozen=True)
class Argument:
    """One array argument of a run function; ``dims`` may start with ``"steps"``."""

    c_name: str
    py_name: str
    dims: tuple[int | str, ...]
    output: bool = False
    optional: bool = False
    doc: str = ""


@dataclass(frozen=True)
class Unit:
    """One generated filter for one model.

    ``parameters``: names of the free parameters in the order of ``p`` (empty:
    no ``p`` anywhere).  ``step_inputs``: the per-step input ports of ``step``
    (their sequences are the run's inputs).  ``facts``: extra ``"key: value"``
    header lines.  ``command``: the command that regenerates the files.
    ``options``: e.g. ``{"window": N}`` (fir, required), ``{"horizon": N}`` (pred).
    """

    model: str
    filter: str
    family: str
    n: int
    m: int
    programs: Mapping[str, Program]
    parameters: tuple[str, ...] = ()
    step_inputs: tuple[str, ...] = ("z",)
    facts: tuple[str, ...] = ()
    command: str = ""
    options: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for what, value in (("model", self.model), ("filter", self.filter)):
            if not isinstance(value, str) or not _IDENT.match(value) or keyword.iskeyword(value):
                raise ProgramError(f"unit {what} name {value!r} is not a plain identifier")
        if self.family not in FAMILIES:
            raise ProgramError(f"unknown filter family {self.family!r}; known: "
                               f"{sorted(FAMILIES)}")
        object.__setattr__(self, "parameters", tuple(str(p) for p in self.parameters))
        object.__setattr__(self, "step_inputs", tuple(self.step_inputs))
        object.__setattr__(self, "facts", tuple(str(f) for f in self.facts))
        object.__setattr__(self, "programs", MappingProxyType(dict(self.programs)))
        object.__setattr__(self, "options", MappingProxyType(dict(self.options)))
        for name, program in self.programs.items():
            if not isinstance(program, Program) or program.name != name:
                raise ProgramError(f"unit {self.prefix}: programs[{name!r}] must be a Program "
                                   f"named {name!r}")
        _validate(self)

    @property
    def prefix(self) -> str:
        """``MODEL_FILTER``: the C function prefix and the file stem."""
        return f"{self.model}_{self.filter}"

    @property
    def kind(self) -> str:
        return FAMILIES[self.family].kind

    @property
    def title(self) -> str:
        return FAMILIES[self.family].title

    @property
    def window(self) -> int:
        """The FIR order N (fir only)."""
        return int(self.options["window"])

    def step_input_size(self, name: str) -> int:
        """Doubles per step of a per-step input (fir: one row of its window)."""
        if self.kind == "fir":
            return self.m
        return self.programs["step"].port(name).size


def expected_ports(unit: Unit, program: str) -> tuple[list[tuple[str, tuple[int, ...] | None]],
                                                     list[tuple[str, tuple[int, ...]]]]:
    """(inputs, outputs) as (name, shape) the family requires; shape None: any 1-D shape."""
    n, m = unit.n, unit.m
    p = [(PARAMETER_PORT, (len(unit.parameters),))] if unit.parameters else []
    per_step = [(name, (m,) if name == "z" else None) for name in unit.step_inputs]
    if program == "init":
        return [("x0", (n,))] + p, [("x_new", (n,))]
    if program == "predict":
        return [("x", (n,)), ("P", (n, n))] + p, [("x_new", (n,)), ("P_new", (n, n))]
    if program == "update1":
        u = [("u", None)] if "u" in unit.step_inputs else []
        return ([("x", (n,)), ("P", (n, n)), ("z", (1,))] + u + p,
                [("x_new", (n,)), ("P_new", (n, n)), ("innovation", (1,)), ("variance", (1,))])
    if unit.kind == "timevarying":
        return [("x", (n,)), ("P", (n, n))] + per_step + p, [("x_new", (n,)), ("P_new", (n, n))]
    if unit.kind in ("steady", "pred"):
        return [("x", (n,))] + per_step + p, [("x_new", (n,))]
    return [("zw", (unit.window, m))] + p, [("x_new", (n,))]


def _validate(unit: Unit) -> None:
    if not isinstance(unit.n, int) or not isinstance(unit.m, int) or unit.n < 1 or unit.m < 1:
        raise ProgramError(f"unit {unit.prefix}: n and m must be positive integers, "
                           f"got n={unit.n!r}, m={unit.m!r}")
    if "step" not in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: the program 'step' is required")
    if unit.kind == "pred" and "init" not in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: a predictor needs the program 'init' "
                           "(x(N/0) = F^N x0)")
    if unit.kind != "pred" and "init" in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: only the pred family takes an 'init' program")
    if unit.kind == "fir":
        window = unit.options.get("window")
        if not isinstance(window, int) or isinstance(window, bool) or window < 1:
            raise ProgramError(f"unit {unit.prefix}: fir needs options['window'], a positive "
                               f"integer, got {window!r}")
        if unit.step_inputs != ("z",):
            raise ProgramError(f"unit {unit.prefix}: fir takes the per-step input 'z' only, "
                               f"got {unit.step_inputs}")
    if not unit.step_inputs or unit.step_inputs[0] != "z":
        raise ProgramError(f"unit {unit.prefix}: the first per-step input must be 'z', "
                           f"got {unit.step_inputs}")
    for name in unit.programs:
        if name in ("step", "init"):
            continue
        if unit.family not in EXTRA_PROGRAMS.get(name, ()):
            raise ProgramError(f"unit {unit.prefix} ({unit.family}): no program {name!r} in "
                               f"this family; programs beyond step and init: "
                               + ", ".join(f"{k} ({'/'.join(v)})"
                                           for k, v in EXTRA_PROGRAMS.items()))
    for name in ("step", "init", *EXTRA_PROGRAMS):
        if name not in unit.programs:
            continue
        program = unit.programs[name]
        inputs, outputs = expected_ports(unit, name)
        for what, want, have in (("inputs", inputs, program.inputs),
                                 ("outputs", outputs, program.outputs)):
            names = [w[0] for w in want]
            if [p.name for p in have] != names:
                raise ProgramError(
                    f"unit {unit.prefix} ({unit.family}): program {name!r} must have {what} "
                    f"{names}, got {[p.name for p in have]}")
            for (port_name, shape), port in zip(want, have):
                if shape is None and len(port.shape) != 1:
                    raise ProgramError(f"unit {unit.prefix}: per-step input {port_name!r} must "
                                       f"be 1-D, got shape {port.shape}")
                if shape is not None and port.shape != shape:
                    raise ProgramError(
                        f"unit {unit.prefix}: port {port_name!r} of program {name!r} must have "
                        f"shape {shape}, got {port.shape}")


def run_arguments(unit: Unit) -> list[Argument]:
    """The array arguments of the run function, in C order (``steps`` comes first in C)."""
    n = unit.n
    args = [Argument(name, f"{name}s", ("steps", unit.step_input_size(name)),
                     doc=f"{name} per step, one row each") for name in unit.step_inputs]
    if unit.kind != "fir":
        args.append(Argument("x0", "x0", (n,), doc="initial state estimate"))
    if unit.kind == "timevarying":
        args.append(Argument("P0", "P0", (n, n), doc="initial covariance (symmetric)"))
    args.append(Argument("xs", "xs", ("steps", n), output=True, doc="estimate after each step"))
    if unit.kind == "timevarying":
        args.append(Argument("Ps", "Ps", ("steps", n, n), output=True, optional=True,
                             doc="covariance after each step (C: may be NULL)"))
    if unit.parameters:
        args.append(Argument(PARAMETER_PORT, PARAMETER_PORT, (len(unit.parameters),),
                             doc="free parameters: " + ", ".join(unit.parameters)))
    return args
