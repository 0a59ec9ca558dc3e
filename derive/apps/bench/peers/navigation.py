"""The navigation rows of ``derive bench``: the INS/GNSS EKF of the catalog model
``ins_gnss`` (docs/navigation.md) against its peers.

- Generation: seconds for derive to generate the EKF's C (predict and both updates, with
  run), against SymForce's C++ codegen of the same three functions
  (derive.apps.ins.symforce_ekf).
- Operations per function: derive's header counts (flops: add + sub + mul + div + sqrt +
  2 fma) against SymForce's C++ counted by derive's C rules (no fma there, so its flops
  are its instructions), SymForce's own ``Total ops`` beside it.
- Per-call time of the generated C predict and GNSS update, each called in a C loop
  (derive.apps.ins.c_loop), against CasADi's generated C of the same functions in the
  same loop and FilterPy's ExtendedKalmanFilter doing the same step in Python
  (derive.apps.ins.filterpy_ekf). Each implementation's first call is checked against the
  NumPy reference (derive.apps.ins.reference).
- The update form: a sensor the catalog model fuses one measurement at a time (``update =
  "sequential"``, gnss) is also timed in its batch form (option ``update="batch"``, the
  LDL^T solve of S) in the same run, its count in a note: what the sequential form gains.
  SymForce's updates are batch (its symbolic inverse of S); both compute the same
  function (inputs and outputs), so the flops rows compare the two generators' code.
- The row form: a function the catalog model derives as vector rows (``rows = "vector"``:
  predict and the sequential GNSS update) is also timed entry by entry (option
  ``rows="scalar"``) in the same run, its count in a note.
- What decides the per-call bars: the time each bar needs (the peer's fastest repeat over
  the bar's ratio: best case against best case, so that load on a shared machine, which
  inflates the medians, does not hide it) beside the floor of scalar code with the
  function's operation count on this machine, from its scalar throughput measured in the
  same run (derive.apps.bench.machine.scalar_throughput). A bar whose need is below that floor
  is out of reach of scalar code with that count; vector rows are not scalar code, and the
  note says so instead.

The state, covariance and inputs of the timed calls are those of the seeded flight at its
GNSS epoch 20 s in (the filter converged, P realistic).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .... import catalog
from ....build import STRICT_CFLAGS
from ....filters.eskf import reference_predict
from ....filters.sensors import program_name
from ....flops import c_function_body
from ....generation import generate_units
from ....interface import read as read_interface
from ....options import validate
from ....trees import OpCount
from ...ins import c_loop, casadi_ekf, fc24, filterpy_ekf, flight, reference, symforce_ekf
from ...verify import sensors_case
from .. import generated
from ..bars import BARS
from ..cases import Skip
from ..machine.scalar_throughput import Throughput, measure_throughput
from ..timing import Timing, columns, human, measure, measure_turns, timing_cells
from . import casadi_c, symforce_peer

MODEL = "ins_gnss"
FUNCTIONS = ("predict", "update_gnss", "update_baro")
TIMED = ("predict", "update_gnss")
GENERATION_BAR = BARS["ins_gnss_generation"]
FILTERPY_BAR = BARS["ins_over_filterpy"]
CASADI_BAR = BARS["ins_over_casadi"]
EPOCH_SECONDS = 20.0
PEER_BARS = (("FilterPy", FILTERPY_BAR), ("CasADi C", CASADI_BAR))
"""The per-call bars: (peer, how many times faster the generated C must be)."""
TURN_CALLS = 200
"""Calls per window when derive's C and CasADi's take turns (derive.apps.bench.timing)."""


@dataclass(frozen=True)
class CountRow:
    function: str
    derive: OpCount
    symforce: OpCount | None
    symforce_total: int | None

    @property
    def ratio(self) -> float | None:
        """derive's flops over SymForce's (counted by derive's rules)."""
        return None if self.symforce is None else self.derive.flops / self.symforce.flops


@dataclass(frozen=True)
class TimeRow:
    function: str
    implementation: str
    timing: Timing | None
    ratio: float | None          # time per call / generated C's
    agreement: float | None      # first call against the NumPy reference, relative
    note: str = ""


@dataclass
class NavigationResult:
    generation_seconds: float | None = None
    generation_cpu_seconds: float | None = None   # this process's CPU time (a loaded machine)
    symforce_seconds: float | None = None
    counts: list[CountRow] = field(default_factory=list)
    times: list[TimeRow] = field(default_factory=list)
    throughput: Throughput | None = None   # this machine's scalar throughput, same run
    notes: list[str] = field(default_factory=list)
    vector: frozenset[str] = frozenset()   # the functions generated as vector rows
    peer: symforce_peer.PeerResult | None = None   # SymForce's C++ timed beside derive's

    def time_row(self, function: str, implementation: str) -> TimeRow | None:
        return next((r for r in self.times if r.function == function
                     and r.implementation == implementation), None)

    def count(self, function: str) -> OpCount | None:
        return next((r.derive for r in self.counts if r.function == function), None)

    def floor_seconds(self, function: str) -> float | None:
        """The floor of scalar code with ``function``'s count here (None unmeasured)."""
        count = self.count(function)
        if self.throughput is None or count is None:
            return None
        return self.throughput.floor_seconds(count)

    def needed_seconds(self, function: str, peer: str, ratio: float) -> float | None:
        """The time per call of the generated C that makes it ``ratio`` times faster than
        ``peer``: the peer's fastest repeat in this run over the ratio."""
        row = self.time_row(function, peer)
        if row is None or row.timing is None:
            return None
        return row.timing.low / ratio

    def decisive_lines(self) -> list[str]:
        """Per timed function: what each per-call bar needs, against the floor."""
        out = []
        for function in TIMED:
            base = self.time_row(function, "generated C")
            needs = [f"<= {human(need)} for {ratio:g}x {peer} ({human(need * ratio)} / "
                     f"{ratio:g})" for peer, ratio in PEER_BARS
                     if (need := self.needed_seconds(function, peer, ratio)) is not None]
            count = self.count(function)
            floor = ("n/a" if self.throughput is None or count is None
                     else self.throughput.floor_text(count))
            form = " (vector rows)" if function in self.vector else ""
            out.append(f"{function}: generated C{form} "
                       + ("n/a" if base is None or base.timing is None
                          else f"{human(base.timing.low)} (fastest repeat)")
                       + f"; needs {', '.join(needs) or 'n/a'}; floor of scalar code with its "
                       f"count here {floor}")
        return out

    def lines(self) -> list[str]:
        out = [f"navigation: {MODEL} EKF (docs/navigation.md, 16 states, inputs in f, sensors "
               "gnss and baro); generation of predict + update_gnss + update_baro: derive "
               + ("n/a" if self.generation_seconds is None else
                  f"{self.generation_seconds:.2f} s (C; CPU {self.generation_cpu_seconds:.2f} s)")
               + ", SymForce " + ("n/a" if self.symforce_seconds is None else
                                  f"{self.symforce_seconds:.2f} s (C++)"), ""]
        head = ("function", "derive flops", "derive instructions", "SymForce flops (derive's "
                "rules)", "SymForce Total ops (its own)", "derive / SymForce")
        body = [(r.function, str(r.derive.flops), str(r.derive.instructions),
                 "n/a" if r.symforce is None else str(r.symforce.flops),
                 "n/a" if r.symforce_total is None else str(r.symforce_total),
                 "" if r.ratio is None else f"{r.ratio:.2f}") for r in self.counts]
        out += columns(head, body) + [""]
        head = ("function", "implementation", "per call", "min-max", "ratio", "agrees", "note")
        body = []
        for r in self.times:
            body.append((r.function, r.implementation,
                         *timing_cells(r.timing, r.ratio, r.agreement), r.note))
        out += columns(head, body)
        out += [""] + self.decisive_lines()
        out += [f"note: {n}" for n in self.notes]
        if self.peer is not None:
            out += [""] + self.peer.lines()
        return out

    def bars(self, bar_type):
        cpu = self.generation_cpu_seconds
        out = [bar_type(f"generating {MODEL} EKF (predict + both updates), C",
                        self.generation_seconds, GENERATION_BAR, "time",
                        "" if cpu is None else f"CPU time of this process {human(cpu)}")]
        for r in self.counts:
            if r.ratio is not None:  # fewer: SymForce has at least one flop more
                out.append(bar_type(f"{MODEL} {r.function}: SymForce's flops over derive's",
                                    1.0 / r.ratio, (r.derive.flops + BARS["ins_flops_fewer"])
                                    / r.derive.flops, "ratio",
                                    f"derive {r.derive.flops}, SymForce {r.symforce.flops} "
                                    f"(its own Total ops {r.symforce_total})"))
        for function in TIMED:
            for peer, need in PEER_BARS:
                row = self.time_row(function, peer)
                out.append(bar_type(f"generated C {MODEL} {function} faster per call than "
                                    f"{peer}", None if row is None else row.ratio, need,
                                    "ratio", self._bar_note(function, peer, need)))
        if self.peer is not None:
            out += self.peer.bars(bar_type)
        return out

    def _bar_note(self, function: str, peer: str, ratio: float) -> str:
        need = self.needed_seconds(function, peer, ratio)
        floor = self.floor_seconds(function)
        if need is None or floor is None:
            return ""
        note = (f"needs <= {human(need)} per call ({peer}'s fastest repeat / {ratio:g}); floor "
                f"of scalar code with its count here {human(floor)}")
        if function in self.vector:
            note += " (vector rows: not scalar code, so that floor does not bound it)"
        elif need < floor:
            note += " (the need is below the floor: out of reach of scalar code with this count)"
        return note

    def as_json(self) -> dict:
        return {"generation_seconds": self.generation_seconds,
                "generation_cpu_seconds": self.generation_cpu_seconds,
                "symforce_seconds": self.symforce_seconds,
                "counts": [{"function": r.function, "derive": r.derive.__dict__,
                            "symforce": None if r.symforce is None else r.symforce.__dict__,
                            "symforce_total": r.symforce_total} for r in self.counts],
                "times": [{"function": r.function, "implementation": r.implementation,
                           "median": r.timing.median if r.timing else None,
                           "ratio": r.ratio, "agreement": r.agreement, "note": r.note}
                          for r in self.times],
                "throughput": None if self.throughput is None else self.throughput.__dict__,
                "floors": {f: self.floor_seconds(f) for f in TIMED},
                "notes": self.notes,
                "peer": None if self.peer is None else self.peer.as_json()}


@dataclass(frozen=True)
class Point:
    """Where the timed calls start: x, P, u, z_gnss, z_baro and dt."""

    x: np.ndarray
    P: np.ndarray
    u: np.ndarray
    z: dict
    dt: float


def operating_point() -> Point:
    """The seeded flight's filter state at the GNSS epoch EPOCH_SECONDS in."""
    fl = flight.simulate(seed=0, duration=EPOCH_SECONDS + 1.0)
    row = int(fl.gnss_rows[np.searchsorted(fl.gnss_rows, int(EPOCH_SECONDS / fl.dt[0])) - 1])
    short = replace(fl, imu=fl.imu[:row], dt=fl.dt[:row], gnss=fl.gnss[:row],
                    baro=fl.baro[:row])
    run = reference.run(short)
    return Point(run.xs[-1], run.Ps[-1], fl.imu[row], {"gnss": fl.gnss[row],
                                                     "baro": fl.baro[row]}, float(fl.dt[row]))


def _expected(point: Point, function: str):
    if function == "predict":
        return reference.predict(point.x, point.P, point.u, point.dt)
    sensor = function.split("_", 1)[1]
    return reference.update(point.x, point.P, point.z[sensor], sensor)[:2]


def _agreement(got, expected) -> float:
    x, P = (np.asarray(v, dtype=float) for v in got)
    x_ref, P_ref = expected
    sd = np.sqrt(np.diag(P_ref))
    return float(max(np.abs(x - x_ref).max() / np.abs(x_ref).max(),
                     (np.abs(P.reshape(P_ref.shape) - P_ref) / np.outer(sd, sd)).max()))


def _derive(workdir: Path, result: NavigationResult):
    """Generate (timed), count, and build the loops of derive's C."""
    start, cpu = time.perf_counter(), time.process_time()
    paths, _ = generate_units(MODEL, ["ekf"], "c", workdir / "derive")
    result.generation_seconds = time.perf_counter() - start
    result.generation_cpu_seconds = time.process_time() - cpu
    header = next(p for p in paths if p.suffix == ".h")
    source = next(p for p in paths if p.suffix == ".c")
    functions = {f.program: f for f in read_interface(header.read_text()).functions}
    derive_counts = {name: _header_count(header.read_text(), name) for name in FUNCTIONS}
    result.vector = frozenset(
        name for name in FUNCTIONS
        if "#if DERIVE_VECTOR" in c_function_body(source.read_text(), functions[name].name))
    loops = [c_loop.derive_call(functions[name], f"derive_{name}") for name in TIMED]
    built = c_loop.build(workdir / "derive_loops", [str(header)], [source], loops,
                         [*STRICT_CFLAGS, *generated.CFLAGS])
    return derive_counts, built


SCALAR_ROWS = "generated C, scalar rows"
"""The time row of a function of vector rows generated with option rows="scalar"."""


def _variant(workdir: Path, names: tuple[str, ...], option: str, value: str):
    """The counts and loops of ``names`` generated with ``option=value`` (the functions
    prefixed with ``value``: scalar rows, the batch form), timed beside the catalog's."""
    paths, _ = generate_units(MODEL, ["ekf"], "c", workdir / f"derive_{value}",
                              {option: value, "prefix": f"{value}_"})
    header = next(p for p in paths if p.suffix == ".h")
    source = next(p for p in paths if p.suffix == ".c")
    functions = {f.program: f for f in read_interface(header.read_text()).functions}
    counts = {name: _header_count(header.read_text(), name) for name in names}
    loops = [c_loop.derive_call(functions[name], f"{value}_{name}") for name in names]
    return counts, c_loop.build(workdir / f"derive_{value}_loops", [str(header)], [source],
                                loops, [*STRICT_CFLAGS, *generated.CFLAGS])


BATCH_FORM = "generated C, batch form"
"""The time row of a sequential sensor's update generated with option update="batch"."""


def sequential_updates() -> tuple[str, ...]:
    """The timed updates whose sensor the catalog model fuses sequentially."""
    forms = {program_name(g.name): g.update for g in catalog.load(MODEL).sensors}
    return tuple(name for name in TIMED if forms.get(name) == "sequential")


def _header_count(text: str, function: str) -> OpCount:
    count = symforce_peer.header_count(text, function)
    if count is None:
        raise ValueError(f"no operation count of {function} in the generated header")
    return count


def _casadi(workdir: Path):
    try:
        source, fns = casadi_ekf.generate(workdir / "casadi")
    except ImportError as exc:
        raise Skip(f"{exc.name} is not installed") from None
    loops = [c_loop.casadi_call(name, fns[name], f"casadi_{name}") for name in TIMED]
    return c_loop.build(workdir / "casadi", ["ins_casadi.h"], [source], loops,
                        casadi_c.CFLAGS)


def _arg(point: Point, function: str) -> np.ndarray:
    return point.u if function == "predict" else point.z[function.split("_", 1)[1]]


def peer_points() -> dict:
    """model -> (the point its functions are timed at, {function: (x, P) of its NumPy
    reference}) for the SymForce peer: ins_gnss at operating_point(), ins_fc24 25 s into
    its flight (derive.apps.ins.fc24.operating_point)."""
    point = operating_point()
    args = {name: _arg(point, name) for name in FUNCTIONS}
    out = {MODEL: (symforce_peer.Point(point.x, point.P, args, point.dt),
                   {name: _expected(point, name) for name in FUNCTIONS})}
    x, P, args, dt = fc24.operating_point()
    out[fc24.MODEL] = (symforce_peer.Point(x, P, args, dt),
                       {name: fc24.expected(x, P, name, arg, dt) for name, arg in args.items()})
    for name in ERROR_STATE:
        out[name] = error_state_point(name)
    return out


ERROR_STATE = ("ins_eskf", "ins_fc24_eskf")
"""The error-state models whose predict the SymForce peer times against its Rot3 version."""

ERROR_STATE_STEP = 500
"""The step of `derive verify`'s run of an error-state model whose x, P and u the peer's
predict is called with."""


def error_state_point(model_name: str):
    """(Point, {"predict": (x, P) of the error-state reference}) of ``model_name`` at step
    ERROR_STATE_STEP of `derive verify`'s simulated run (derive.apps.verify.sensors_case)."""
    model = catalog.load(model_name)
    case = sensors_case(model, "eskf", ERROR_STATE_STEP + 100, 7, validate("eskf", {}),
                        float_c=False)
    step = case.trace[ERROR_STATE_STEP]
    u = step.u[[model.inputs.index(s) for s in model.f_inputs]]
    expected = reference_predict(model)(step.x_before, step.P_before, step.u, step.p)
    return (symforce_peer.Point(step.x_before, step.P_before, {"predict": u}, float(step.p[0])),
            {"predict": expected})


def run_navigation(workdir: Path, calls: int, python_calls: int, repeats: int,
                   symforce: bool = True, tick=lambda text: None,
                   peer_calls: int = 0, peer_repeats: int = 1) -> NavigationResult:
    """Measure everything above; ``calls`` per C timing, ``python_calls`` per FilterPy
    timing; with ``peer_calls``, SymForce's C++ timed beside derive's C
    (derive.apps.bench.peers.symforce_peer), that many calls per timing, ``peer_repeats``
    repeats."""
    result = NavigationResult()
    if peer_calls:
        tick("navigation: the SymForce peer's operating points")
        try:
            result.peer = symforce_peer.run_peer(peer_points(), workdir / "peer", peer_calls,
                                                 peer_repeats, tick)
        except ImportError as exc:
            result.notes.append(f"SymForce peer skipped: {exc.name} is not installed")
        except (OSError, RuntimeError) as exc:  # no g++, or a compile failed
            result.notes.append(f"SymForce peer skipped: {str(exc).splitlines()[0][:300]}")
    tick("navigation: the flight's operating point")
    point = operating_point()
    tick("navigation: derive generates ins_gnss")
    derive_counts, derive_loops = _derive(workdir, result)
    symforce_functions = {}
    if symforce and result.peer is not None:  # the peer generated them: its time is theirs
        symforce_functions = result.peer.symforce[MODEL]
        result.symforce_seconds = result.peer.symforce_seconds[MODEL]
    elif symforce:
        tick("navigation: SymForce codegen")
        try:
            symforce_functions = symforce_ekf.generate(FUNCTIONS)
            result.symforce_seconds = sum(f.seconds for f in symforce_functions.values())
        except ImportError as exc:
            result.notes.append(f"SymForce skipped: {exc.name} is not installed")
    else:
        result.notes.append("SymForce codegen left out (--quick)")
    for name in FUNCTIONS:
        sf = symforce_functions.get(name)
        result.counts.append(CountRow(name, derive_counts[name], sf and sf.count,
                                      sf and sf.total_ops))
    tick("navigation: CasADi C")
    try:
        casadi_loops = _casadi(workdir)
    except Skip as exc:
        casadi_loops, casadi_note = None, f"skipped: {exc}"
    tick("navigation: this machine's scalar throughput")
    try:
        result.throughput = measure_throughput(generated.CFLAGS, repeats)
    except Exception as exc:  # no compiler or cffi failure: the floors are left out
        result.notes.append(f"scalar throughput not measured: {str(exc).splitlines()[0][:200]}")
    sequential = sequential_updates()
    if sequential:
        tick("navigation: the batch form of " + ", ".join(sequential))
        batch_counts, batch_loops = _variant(workdir, sequential, "update", "batch")
        result.notes += [f"{name} is sequential (one scalar update per measurement); its batch "
                         f"form (update=batch): flops {batch_counts[name].flops}, instructions "
                         f"{batch_counts[name].instructions}" for name in sequential]
    vector = tuple(name for name in TIMED if name in result.vector)
    if vector:
        tick("navigation: the scalar rows of " + ", ".join(vector))
        scalar_counts, scalar_loops = _variant(workdir, vector, "rows", "scalar")
        result.notes += [f"{name} is vector rows (rows=vector: flops {result.count(name).flops}, "
                         f"instructions {result.count(name).instructions}); entry by entry "
                         f"(rows=scalar): flops {scalar_counts[name].flops}, instructions "
                         f"{scalar_counts[name].instructions}" for name in vector]
    p = np.array([point.dt])
    # against CasADi: short windows in turns, as many calls in all (a window that a moment
    # of load misses is likelier than a long one, and the minima are what is compared)
    window = min(calls, TURN_CALLS)
    for name in TIMED:
        expected = _expected(point, name)
        tick(f"navigation: {name}")
        mine = derive_loops.runner(f"derive_{name}", point.x, point.P, _arg(point, name), p)
        base = measure(lambda mine=mine: mine(calls), calls, repeats)
        result.times.append(TimeRow(name, "generated C", base, 1.0,
                                    _agreement(mine(1), expected), "a C loop of calls"))
        if name in vector:
            run = scalar_loops.runner(f"scalar_{name}", point.x, point.P, _arg(point, name), p)
            t = measure(lambda run=run: run(calls), calls, repeats)
            result.times.append(TimeRow(name, SCALAR_ROWS, t, t.median / base.median,
                                        _agreement(run(1), expected),
                                        "option rows=scalar (entry by entry); the same C loop"))
        if name in sequential:
            run = batch_loops.runner(f"batch_{name}", point.x, point.P, _arg(point, name), p)
            t = measure(lambda run=run: run(calls), calls, repeats)
            result.times.append(TimeRow(name, BATCH_FORM, t, t.median / base.median,
                                        _agreement(run(1), expected),
                                        "option update=batch (the LDL^T solve of S); the same "
                                        "C loop"))
        if casadi_loops is None:
            result.times.append(TimeRow(name, "CasADi C", None, None, None, casadi_note))
        else:
            run = casadi_loops.runner(f"casadi_{name}", point.x, point.P, _arg(point, name), p)
            ours, t = measure_turns([lambda mine=mine: mine(window),
                                     lambda run=run: run(window)], window,
                                    repeats * calls // window)
            result.times.append(TimeRow(name, "CasADi C", t, t.low / ours.low,
                                        _agreement(run(1), expected),
                                        "dense P read symmetric, symbolic Jacobians and "
                                        "inverse; the same C loop; ratio of the minima, "
                                        f"windows of {window} calls timed in turns with "
                                        f"derive's ({human(ours.low)})"))
        result.times.append(_filterpy_row(name, point, python_calls, repeats, base, expected))
    return result


def _filterpy_row(name: str, point: Point, calls: int, repeats: int, base: Timing,
                  expected) -> TimeRow:
    try:
        ekf = filterpy_ekf.make_filter(point.x, point.P)
    except ImportError as exc:
        return TimeRow(name, "FilterPy", None, None, None, f"skipped: {exc.name} is not "
                                                            "installed")
    sensor = name.split("_", 1)[1] if name != "predict" else None

    def step():
        if sensor is None:
            ekf.predict_step(point.u, point.dt)
        else:
            ekf.update_step(point.z[sensor], sensor)

    step()
    agreement = _agreement((ekf.x.ravel(), ekf.P), expected)

    def run():
        for _ in range(calls):
            ekf.x, ekf.P = point.x.reshape(-1, 1).copy(), point.P.copy()
            step()
    t = measure(run, calls, repeats)
    return TimeRow(name, "FilterPy", t, t.median / base.median, agreement,
                   "ExtendedKalmanFilter; F, Q (predict) and H from the NumPy reference's "
                   "hand-written Jacobians each call")
