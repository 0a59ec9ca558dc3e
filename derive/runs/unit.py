"""A generation unit (one model, one filter) and the interface of each filter family.

A :class:`Unit` is everything the renderer needs and nothing it must compute
about filters: names, title, sizes, its run-loop kind, its carried state, the
programs (``step``; those its run kind needs, e.g. ``init``; those it adds, e.g.
``predict`` and ``update1``, the sequential form for a varying number of
measurements), header facts and the regeneration command.  :data:`RUN_KINDS`
says which ports each kind's programs must have and what run takes and stores;
the run loop of each kind lives in one template per language and its arguments
in :func:`run_arguments`.  No filter is named here.
"""

from __future__ import annotations

import keyword
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from derive.precision import PRECISIONS
from derive.program import PARAMETER_PORT, Program, ProgramError

_IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


"""The languages a unit is rendered in (one template per run kind in each)."""


@dataclass(frozen=True)
class RunKind:
    """A kind of run loop: a small declarative entry plus one template per language
    (``templates/<language>/<name>.jinja``).

    ``programs``: programs the unit must have besides ``step``.  ``carried``: the
    default (input port, output port) pairs of ``step`` carried from step to step (a
    unit may declare its own).  ``start``: run's arguments that start the carried state
    (name, dims).  ``stores``: run's per-step outputs (name, output port of ``step``,
    dims after ``steps``, optional in C).  ``window``: the step reads the last
    ``window`` rows of z (port ``zw``) instead of one row.  ``run_tracks``: C may have
    ``run_tracks``.  ``lookahead``: C run takes two steps per pass when the step is affine
    and has no free parameters (derive.runs.kinds.two_steps).  ``extra_programs``: programs a
    unit of this kind may add.  ``work``: C run's caller-provided scratch arrays, after
    the stored ones: (name, the ports of the unit's programs one row of it holds per
    step, in order), e.g. a smoother's forward pass; Python run allocates its own.  The
    step's outputs are the carried ones, the stored ones, then those the work rows hold.
    """

    name: str
    programs: tuple[str, ...] = ()
    carried: tuple[tuple[str, str], ...] = ()
    start: tuple[tuple[str, tuple[str, ...]], ...] = ()
    stores: tuple[tuple[str, str, tuple[str, ...], bool], ...] = ()
    window: bool = False
    run_tracks: bool = False
    lookahead: bool = False
    extra_programs: tuple[str, ...] = ()
    work: tuple[tuple[str, tuple[str, ...]], ...] = ()
    sensors: bool = False


RUN_KINDS: Mapping[str, RunKind] = MappingProxyType({k.name: k for k in (
    RunKind("timevarying", carried=(("x", "x_new"), ("P", "P_new")),
            start=(("x0", ("n",)), ("P0", ("nt", "nt"))),
            stores=(("xs", "x_new", ("n",), False), ("Ps", "P_new", ("nt", "nt"), True)),
            run_tracks=True, extra_programs=("predict", "update1", "enter", "store", "update")),
    RunKind("steady", carried=(("x", "x_new"),), start=(("x0", ("n",)),),
            stores=(("xs", "x_new", ("n",), False),), run_tracks=True, lookahead=True),
    RunKind("windowed", stores=(("xs", "x_new", ("n",), False),), window=True),
    RunKind("predictor", programs=("init",), carried=(("x", "x_new"),),
            start=(("x0", ("n",)),), stores=(("xs", "x_new", ("n",), False),),
            lookahead=True),
    RunKind("smoother", programs=("backward",), carried=(("x", "x_new"), ("P", "P_new")),
            start=(("x0", ("n",)), ("P0", ("n", "n"))),
            stores=(("xs", "x_new", ("n",), False), ("Ps", "P_new", ("n", "n"), False)),
            work=(("work", ("x_new", "P_new", "x_pred", "P_pred")),),
            extra_programs=("update",)),
    RunKind("filter_predict", carried=(("x", "x_new"), ("P", "P_new")),
            start=(("x0", ("n",)), ("P0", ("nt", "nt"))),
            stores=(("xs", "x_new", ("n",), False), ("Ps", "P_new", ("nt", "nt"), True),
                    ("x_preds", "x_pred", ("n",), False),
                    ("P_preds", "P_pred", ("nt", "nt"), True))),
    RunKind("sensors", programs=("predict",), carried=(("x", "x_new"), ("P", "P_new")),
            start=(("x0", ("n",)), ("P0", ("nt", "nt"))),
            stores=(("xs", "x_new", ("n",), False), ("Ps", "P_new", ("nt", "nt"), True)),
            sensors=True),
)})
"""The run-loop kinds; a unit names one (``Unit.run_kind``) and emit switches on it only."""

KINDS = tuple(RUN_KINDS)

#: Ports of the programs a run kind may add (``RunKind.extra_programs``):
#: ``predict(x, P[, u][, p]) -> (x_new, P_new)`` (u when the prediction uses inputs),
#: ``update1(x, P, z[1][, u][, p]) -> (x_new, P_new, innovation[1], variance[1])``,
#: ``enter(<run's start arguments>) -> (<the carried input ports>)``: run's first state
#: from its arguments (P0 into a factored covariance), and
#: ``store(<the carried input ports>) -> (<stored outputs no carried port holds>)``: what
#: run stores from the carried state after each step (P from its factors; C: only when
#: the array is given), and ``update`` (the step's ports): the update alone, which an
#: update-first run (``Unit.update_first``) calls at step 0 in place of a step that fuses
#: the prediction and the update.
EXTRA_PROGRAMS = ("predict", "update1", "enter", "store", "update")

#: The port of the second measurement row of a two-step map (``z`` is row k, this row
#: k + 1): ``Unit.lookahead`` is ``(x, z, zn) -> x_new``, x(k+2) from x(k).
LOOKAHEAD_NEXT = "zn"

#: The shapes of the ports every kind names (in sizes n, m and nt, the covariance's
#: dimension: n, or the tangent space's of a model with manifold states); other ports:
#: any shape.
_PORT_DIMS = {"x": ("n",), "x_new": ("n",), "x0": ("n",), "P": ("nt", "nt"),
              "P_new": ("nt", "nt")}

#: The space each array of x and P lives in, when the two differ (``Unit.nt < n``): x
#: in the storage space (n numbers), P in the tangent space (nt x nt).
STORAGE, TANGENT = "storage", "tangent"
SPACES = {"x": STORAGE, "x_new": STORAGE, "x0": STORAGE, "xs": STORAGE,
          "P": TANGENT, "P_new": TANGENT, "P0": TANGENT, "Ps": TANGENT}


@dataclass(frozen=True)
class Argument:
    """One array argument of a run function; ``dims`` may start with ``"steps"``."""

    c_name: str
    py_name: str
    dims: tuple[int | str, ...]
    output: bool = False
    optional: bool = False
    doc: str = ""
    scratch: bool = False


@dataclass(frozen=True)
class SensorSlot:
    """One sensor of a unit of the run kind ``sensors``: its name, its measurement count,
    the columns of run's u (the model's inputs) its update takes, and whether its update
    is gated (returns nis and applied); ``R_argument``: its update takes R per call (run:
    one R per step, ``R_<sensor>``); ``implicit``: the one sensor of a model that declares
    none (all its measurements), whose run array is ``z`` (Python ``zs``) as in every other
    run kind, so that the start does not change how run is called."""

    name: str
    m: int
    inputs: tuple[int, ...] = ()
    gated: bool = False
    R_argument: bool = False
    implicit: bool = False

    @property
    def z_c(self) -> str:
        """The C name of run's array of this sensor's measurements."""
        return "z" if self.implicit else f"z_{self.name}"

    @property
    def z_py(self) -> str:
        """The Python name of run's array of this sensor's measurements."""
        return "zs" if self.implicit else f"z_{self.name}"


@dataclass(frozen=True)
class Unit:
    """One generated filter for one model.

    ``parameters``: names of the free parameters in the order of ``p`` (empty:
    no ``p`` anywhere).  ``step_inputs``: the per-step input ports of ``step``
    (their sequences are the run's inputs).  ``facts``: extra ``"key: value"``
    header lines.  ``command``: the command that regenerates the files.
    ``run_function``: False leaves ``MODEL_FILTER_run`` out of the C (its loop stays
    private to run_tracks when the unit has one; the Python run stays).
    ``options``: e.g. ``{"window": N}`` (required by a windowed run), ``{"horizon": N}``.
    ``lookahead``: the two-step map x(k+2) from x(k), z(k), z(k+1) (ports ``x``, ``z``,
    :data:`LOOKAHEAD_NEXT` -> ``x_new``), built by the derivation from its exact
    constants, for a run kind with ``lookahead``: C run takes two steps per pass.
    ``precision``: the floating-point type of the C (``double`` or ``float``,
    derive.precision); the Python is double in either.  ``nt``: P's dimension (0: n),
    fewer than n for a model with quaternion states, whose covariance lives in the
    tangent space (x is stored with n numbers, P is nt x nt; :func:`space`).
    ``extra_stores``: per-step outputs run stores besides its kind's (as
    ``RunKind.stores``), each an output of ``step`` after the kind's (the log-likelihood
    ``ll`` into ``lls``). ``update_first``: run's step 0 updates x0, P0 with its
    measurements without a prediction (the sensors run leaves predict out there; a step
    that fuses the prediction and the update is replaced there by the program
    ``update``).
    """

    model: str
    filter: str
    family: str
    title: str
    run_kind: str
    n: int
    m: int
    programs: Mapping[str, Program]
    parameters: tuple[str, ...] = ()
    step_inputs: tuple[str, ...] = ("z",)
    facts: tuple[str, ...] = ()
    command: str = ""
    options: Mapping[str, object] = field(default_factory=dict)
    about: Mapping[str, str] = field(default_factory=dict)
    run_tracks: bool = False
    extra_programs: tuple[str, ...] = ()
    carried: tuple[tuple[str, str], ...] | None = None
    lookahead: Program | None = None
    symbol_prefix: str = ""
    sensors: tuple[SensorSlot, ...] = ()
    n_inputs: int = 0
    predict_inputs: tuple[int, ...] = ()
    update_first: bool = False
    precision: str = "double"
    run_function: bool = True
    nt: int = 0
    extra_stores: tuple[tuple[str, str, tuple[str, ...], bool], ...] = ()

    def __post_init__(self) -> None:
        if not self.nt:
            object.__setattr__(self, "nt", self.n)
        for what, value in (("model", self.model), ("filter", self.filter)):
            if not isinstance(value, str) or not _IDENT.match(value) or keyword.iskeyword(value):
                raise ProgramError(f"unit {what} name {value!r} is not a plain identifier")
        if not isinstance(self.symbol_prefix, str) or (
                self.symbol_prefix and not _IDENT.match(self.symbol_prefix)):
            raise ProgramError(f"unit symbol prefix {self.symbol_prefix!r} is not empty or a "
                               "C identifier")
        if self.precision not in PRECISIONS:
            raise ProgramError(f"unit precision {self.precision!r} is not one of "
                               f"{', '.join(PRECISIONS)}")
        if self.run_kind not in RUN_KINDS:
            raise ProgramError(f"unknown run kind {self.run_kind!r}; known: "
                               f"{sorted(RUN_KINDS)}")
        if self.carried is None:
            object.__setattr__(self, "carried", RUN_KINDS[self.run_kind].carried)
        object.__setattr__(self, "carried", tuple(tuple(c) for c in self.carried))
        object.__setattr__(self, "extra_programs", tuple(self.extra_programs))
        object.__setattr__(self, "about", MappingProxyType(dict(self.about)))
        if self.run_tracks and not RUN_KINDS[self.run_kind].run_tracks:
            raise ProgramError(f"unit {self.prefix}: run kind {self.run_kind!r} has no "
                               "function run_tracks")
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
        """``PREFIX`` ``MODEL_FILTER``: the prefix of the C functions and macros
        (``symbol_prefix``, the ``--prefix`` option, in front; the files are still
        ``MODEL/FILTER.*``)."""
        return f"{self.symbol_prefix}{self.model}_{self.filter}"

    @property
    def kind(self) -> str:
        """The run-loop kind (a key of :data:`RUN_KINDS`)."""
        return self.run_kind

    @property
    def run(self) -> RunKind:
        """The run-loop kind's entry."""
        return RUN_KINDS[self.run_kind]

    @property
    def stores(self) -> tuple[tuple[str, str, tuple[str, ...], bool], ...]:
        """run's per-step outputs: its kind's, then the unit's ``extra_stores``."""
        return self.run.stores + self.extra_stores

    @property
    def window(self) -> int:
        """The number of measurements a windowed step reads, N (windowed runs only)."""
        return int(self.options["window"])

    def step_input_size(self, name: str) -> int:
        """Doubles per step of a per-step input (windowed: one row of its window)."""
        if self.run.window:
            return self.m
        return self.programs["step"].port(name).size


def sizes(unit: Unit) -> dict[str, int]:
    """The unit's named sizes: n (x), m (z), nt (P: nt x nt) and np (p)."""
    return {"n": unit.n, "m": unit.m, "nt": unit.nt, "np": len(unit.parameters)}


def space(unit: Unit, name: str) -> str:
    """``storage`` or ``tangent`` for an array of x or P of a unit whose covariance lives
    in a tangent space (``unit.nt < unit.n``), else ``""``."""
    return SPACES.get(name, "") if unit.nt != unit.n else ""


def _shape(unit: Unit, name: str) -> tuple[int, ...] | None:
    named = sizes(unit)
    dims = _PORT_DIMS.get(name)
    return None if dims is None else tuple(named[d] for d in dims)


def expected_ports(unit: Unit, program: str) -> tuple[list[tuple[str, tuple[int, ...] | None]],
                                                     list[tuple[str, tuple[int, ...]]]]:
    """(inputs, outputs) as (name, shape) the run kind requires; shape None: any shape
    (a per-step input: any 1-D shape)."""
    n, m, nt = unit.n, unit.m, unit.nt
    p = [(PARAMETER_PORT, (len(unit.parameters),))] if unit.parameters else []
    per_step = [(name, (m,) if name == "z" else None) for name in unit.step_inputs]
    if program == "init":
        return [("x0", (n,))] + p, [("x_new", (n,))]
    if program == "predict":  # u: the inputs the prediction uses (a nonlinear f's)
        takes_u = "u" in unit.step_inputs and any(
            port.name == "u" for port in unit.programs["predict"].inputs)
        u = [("u", None)] if takes_u else []
        return [("x", (n,)), ("P", (nt, nt))] + u + p, [("x_new", (n,)), ("P_new", (nt, nt))]
    if program == "update1":
        u = [("u", None)] if "u" in unit.step_inputs else []
        return ([("x", (n,)), ("P", (nt, nt)), ("z", (1,))] + u + p,
                [("x_new", (n,)), ("P_new", (nt, nt)), ("innovation", (1,)),
                 ("variance", (1,))])
    kind = unit.run
    if program == "enter":
        named = sizes(unit)
        return ([(name, tuple(named[d] for d in dims)) for name, dims in kind.start],
                [(port, _shape(unit, port)) for port, _ in unit.carried])
    if program == "store":
        carried_out = {out for _, out in unit.carried}
        return ([(port, _shape(unit, port)) for port, _ in unit.carried],
                [(out, _shape(unit, out)) for _, out, _, _ in kind.stores
                 if out not in carried_out])
    carried_in = [(port, _shape(unit, port)) for port, _ in unit.carried]
    outputs = [out for _, out in unit.carried]
    if "store" not in unit.programs:  # else the store program computes the rest
        outputs += [port for _, port, _, _ in kind.stores if port not in outputs]
    outputs += [port for _, port, _, _ in unit.extra_stores]
    # then the ports the run's work rows hold that the step writes (a smoother's prediction)
    outputs += [port for _, held in kind.work for port in held if port not in outputs]
    if kind.window:
        per_step = [("zw", (unit.window, m))]
    return carried_in + per_step + p, [(out, _shape(unit, out)) for out in outputs]


def _validate_sensors(unit: Unit) -> None:
    """A unit of the run kind ``sensors``: ``predict`` and one ``update_<sensor>`` per
    sensor, with the ports run calls them with, and no other program."""
    n, nt = unit.n, unit.nt
    if not unit.sensors:
        raise ProgramError(f"unit {unit.prefix}: run kind 'sensors' needs its sensors")
    p = [(PARAMETER_PORT, (len(unit.parameters),))] if unit.parameters else []
    want = {"predict": None}
    for s in unit.sensors:
        u = [("u", (len(s.inputs),))] if s.inputs else []
        gated = [("nis", (1,)), ("applied", (1,))] if s.gated else []
        R = [("R", (s.m, s.m))] if s.R_argument else []
        want[f"update_{s.name}"] = ([("x", (n,)), ("P", (nt, nt)), ("z", (s.m,))] + R + u + p,
                                    [("x_new", (n,)), ("P_new", (nt, nt))] + gated)
    if set(unit.programs) != set(want):
        raise ProgramError(f"unit {unit.prefix}: run kind 'sensors' takes the programs "
                           f"{sorted(want)}, got {sorted(unit.programs)}")
    columns = [c for s in unit.sensors for c in s.inputs] + list(unit.predict_inputs)
    if any(not 0 <= c < unit.n_inputs for c in columns):
        raise ProgramError(f"unit {unit.prefix}: an input column is outside run's u "
                           f"({unit.n_inputs} inputs)")
    u = [("u", (len(unit.predict_inputs),))] if unit.predict_inputs else []
    want["predict"] = ([("x", (n,)), ("P", (nt, nt))] + u + p,
                       [("x_new", (n,)), ("P_new", (nt, nt))])
    for name, (inputs, outputs) in want.items():
        program = unit.programs[name]
        for what, expected, have in (("inputs", inputs, program.inputs),
                                     ("outputs", outputs, program.outputs)):
            if [(q.name, q.shape) for q in have] != [(w[0], tuple(w[1])) for w in expected]:
                raise ProgramError(
                    f"unit {unit.prefix}: program {name!r} must have {what} "
                    f"{[(w[0], tuple(w[1])) for w in expected]}, got "
                    f"{[(q.name, q.shape) for q in have]}")


def _validate(unit: Unit) -> None:
    if not isinstance(unit.n, int) or not isinstance(unit.m, int) or unit.n < 1 or unit.m < 1:
        raise ProgramError(f"unit {unit.prefix}: n and m must be positive integers, "
                           f"got n={unit.n!r}, m={unit.m!r}")
    if unit.run.sensors:
        _validate_sensors(unit)
        return
    if "step" not in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: the program 'step' is required")
    if unit.update_first and "update" not in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: an update-first run needs the program "
                           "'update' (the step without its prediction)")
    for name in unit.run.programs:
        if name not in unit.programs:
            raise ProgramError(f"unit {unit.prefix}: run kind {unit.kind!r} needs the program "
                               f"{name!r}")
    if "init" in unit.programs and "init" not in unit.run.programs:
        raise ProgramError(f"unit {unit.prefix}: run kind {unit.kind!r} takes no 'init' "
                           "program")
    if unit.run.window:
        window = unit.options.get("window")
        if not isinstance(window, int) or isinstance(window, bool) or window < 1:
            raise ProgramError(f"unit {unit.prefix}: run kind {unit.kind!r} needs "
                               f"options['window'], a positive "
                               f"integer, got {window!r}")
        if unit.step_inputs != ("z",):
            raise ProgramError(f"unit {unit.prefix}: run kind {unit.kind!r} takes the per-step "
                               f"input 'z' only, "
                               f"got {unit.step_inputs}")
    if not unit.step_inputs or unit.step_inputs[0] != "z":
        raise ProgramError(f"unit {unit.prefix}: the first per-step input must be 'z', "
                           f"got {unit.step_inputs}")
    for name in unit.programs:
        if name == "step" or name in unit.run.programs:
            continue
        if name not in unit.extra_programs or name not in unit.run.extra_programs:
            raise ProgramError(f"unit {unit.prefix} ({unit.family}): no program {name!r} in "
                               f"this filter; programs beyond its run kind's: "
                               f"{', '.join(unit.extra_programs) or 'none'}")
    if unit.run_tracks and "store" in unit.programs:
        raise ProgramError(f"unit {unit.prefix}: run_tracks does not take a store "
                           "program; give run_tracks=False")
    if unit.lookahead is not None:
        two = unit.lookahead
        if not unit.run.lookahead:
            raise ProgramError(f"unit {unit.prefix}: run kind {unit.kind!r} takes no "
                               "two-step map")
        if ([p.name for p in two.inputs] != ["x", "z", LOOKAHEAD_NEXT]
                or [p.name for p in two.outputs] != ["x_new"]):
            raise ProgramError(f"unit {unit.prefix}: the two-step map must be (x, z, "
                               f"{LOOKAHEAD_NEXT}) -> x_new")
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
                if shape is None and port_name in unit.step_inputs and len(port.shape) != 1:
                    raise ProgramError(f"unit {unit.prefix}: per-step input {port_name!r} must "
                                       f"be 1-D, got shape {port.shape}")
                if shape is not None and port.shape != shape:
                    raise ProgramError(
                        f"unit {unit.prefix}: port {port_name!r} of program {name!r} must have "
                        f"shape {shape}, got {port.shape}")


def sensor_run_arguments(unit: Unit) -> list[Argument]:
    """run's arguments for the run kind ``sensors``: one z_<sensor> per sensor (``z`` for
    a model's implicit sensor), then u (when the model has inputs), as every run kind takes
    z before u; then x0, P0, xs, Ps and, per gated sensor, nis_<sensor> and
    applied_<sensor> (optional), then p."""
    n, nt = unit.n, unit.nt
    args = []
    for s in unit.sensors:
        args.append(Argument(s.z_c, s.z_py, ("steps", s.m),
                             doc=f"sensor {s.name} per step, one row each; a row with a NaN: "
                                 "no measurement of this sensor at that step"))
        if s.R_argument:
            args.append(Argument(f"R_{s.name}", f"R_{s.name}", ("steps", s.m, s.m),
                                 doc=f"R of sensor {s.name} per step (symmetric; read where "
                                     "its row of z is present)"))
    if unit.n_inputs:
        args.append(Argument("u", "us", ("steps", unit.n_inputs),
                             doc="u(k) per step, one row each (predict's and the updates')"))
    args += [Argument("x0", "x0", (n,), doc="initial state estimate"),
             Argument("P0", "P0", (nt, nt), doc="initial covariance (symmetric)"),
             Argument("xs", "xs", ("steps", n), output=True, doc="estimate after each step"),
             Argument("Ps", "Ps", ("steps", nt, nt), output=True, optional=True,
                      doc="covariance after each step (C: may be NULL)")]
    for s in unit.sensors:
        if s.gated:
            args += [Argument(f"nis_{s.name}", f"nis_{s.name}", ("steps",), output=True,
                              optional=True, doc=f"NIS of {s.name} per step (NaN: no "
                              "measurement) (C: may be NULL)"),
                     Argument(f"applied_{s.name}", f"applied_{s.name}", ("steps",),
                              output=True, optional=True,
                              doc=f"1 where {s.name}'s update was applied, 0 where gated "
                                  "out or absent (C: may be NULL)")]
    if unit.parameters:
        args.append(Argument(PARAMETER_PORT, PARAMETER_PORT, (len(unit.parameters),),
                             doc="free parameters: " + ", ".join(unit.parameters)))
    return args


def run_arguments(unit: Unit) -> list[Argument]:
    """The array arguments of the run function, in C order (``steps`` comes first in C)."""
    if unit.run.sensors:
        return sensor_run_arguments(unit)
    named = sizes(unit)
    docs = {"x0": "initial state estimate", "P0": "initial covariance (symmetric)",
            "xs": "estimate after each step",
            "Ps": "covariance after each step",
            "lls": "log-likelihood of each step's innovation",
            "dlls": "gradient of each step's log-likelihood with respect to p"}
    args = [Argument(name, f"{name}s", ("steps", unit.step_input_size(name)),
                     doc=f"{name} per step, one row each") for name in unit.step_inputs]
    args += [Argument(name, name, tuple(named[d] for d in dims), doc=docs.get(name, name))
             for name, dims in unit.run.start]
    args += [Argument(name, name, ("steps",) + tuple(named[d] for d in dims), output=True,
                      optional=optional, doc=docs.get(name, f"{port} after each step")
                      + (" (C: may be NULL)" if optional else ""))
             for name, port, dims, optional in unit.stores]
    ports = {p.name: p.size for program in unit.programs.values()
             for p in program.inputs + program.outputs}
    for name, held in unit.run.work:
        missing = [p for p in held if p not in ports]
        if missing:
            raise ProgramError(f"unit {unit.prefix}: run's work array {name!r} holds ports "
                               f"{missing} that no program of the unit has")
        args.append(Argument(name, name, ("steps", sum(ports[p] for p in held)), output=True,
                             scratch=True, doc=f"C: scratch, per step {', '.join(held)}"))
    if unit.parameters:
        args.append(Argument(PARAMETER_PORT, PARAMETER_PORT, (len(unit.parameters),),
                             doc="free parameters: " + ", ".join(unit.parameters)))
    return args
