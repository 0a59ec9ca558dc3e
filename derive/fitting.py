"""Maximum-likelihood estimates of a model's free parameters from measurements.

:func:`fit` generates the model's Kalman filter (a nonlinear model's EKF, whose Gaussian
log-likelihood of the innovations is a quasi-likelihood) with the exact gradient of its
log-likelihood (the option ``gradient``, derive.sensitivity), compiles it
and hands ``-log L`` and its gradient to SciPy's BFGS, then polishes the optimum with
Newton steps on the Hessian from central differences of the exact gradient. A parameter
with a declared domain (``positive`` or ``nonnegative``) is optimised as its logarithm,
so the optimiser never leaves the domain; one without a domain is optimised as it is,
and a step the filter refuses there (S not positive definite) is bad input naming it.
The standard errors are the square roots of the diagonal of the inverse observed
information, -d^2 log L / d theta^2 at the estimate, in the parameters themselves.

Several tracks (a list of measurement arrays, one parameter set) sum their
log-likelihoods and gradients: the tracks of one length go through the C ``run_tracks``
(in slices over threads, as derive.batch splits a batch: the C releases the GIL), or,
for a filter without it, one C ``run`` per track.

A model file's text with some valued parameters freed (:func:`free_text`, their values
becoming the examples the fit starts from) and with the fitted values written back
(:func:`fitted_text`) is what ``derive fit`` reads and writes: the fitted file is an
ordinary model file that ``derive generate`` takes.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import numpy as np
import scipy.optimize

from . import batch, catalog
from .domains import declared_domain
from .errors import ModelError, NumericalError
from .generation import is_model_file, resolve_model
from .modelfile import tomllib
from .pipeline import load_generated

#: The filter whose log-likelihood the fit maximises, by the model's kind: the Kalman
#: filter's (exact for a linear model), the EKF's (its Gaussian approximation).
FILTERS = {"linear": "kf", "nonlinear": "ekf"}


class FitError(ModelError):
    """Bad input to a fit: data that do not match the model, an unknown parameter, a
    parameter driven where the model is not defined, nothing free."""


@dataclass(frozen=True)
class FitResult:
    """A maximum-likelihood fit: the free parameters' ``names`` (the order of p), their
    ``estimates`` and ``standard_errors`` (from the observed information), the
    log-likelihood at the estimate (``loglik``) and its ``gradient`` there, the
    optimiser's ``iterations``, the ``evaluations`` of log L and its gradient,
    ``converged`` and the optimiser's ``message``; ``information``: the observed
    information matrix; ``seconds``: the time the fit took (generation excluded),
    ``generation_seconds`` the time generating and compiling the filter took."""

    names: tuple[str, ...]
    estimates: np.ndarray
    standard_errors: np.ndarray
    loglik: float
    gradient: np.ndarray
    information: np.ndarray
    iterations: int
    evaluations: int
    converged: bool
    message: str
    seconds: float
    generation_seconds: float

    def values(self) -> dict[str, float]:
        """``{name: estimate}``."""
        return {n: float(v) for n, v in zip(self.names, self.estimates)}

    def table(self) -> str:
        """The estimates and standard errors, one line per parameter."""
        width = max(len(n) for n in self.names)
        lines = [f"{n:<{width}}  {v: .10g}  (se {s:.3g})"
                 for n, v, s in zip(self.names, self.estimates, self.standard_errors)]
        return "\n".join(lines + [f"log-likelihood {self.loglik:.12g} ({self.iterations} "
                                  f"iterations, {self.evaluations} evaluations)"])


# -- model files: freeing parameters and writing the fitted values ---------------------------

_TABLE = re.compile(r"^\s*\[([^\[\]]+)\]\s*(#.*)?$")


def _parameters_span(text: str) -> tuple[int, int]:
    """The line range [start, stop) of the ``[parameters]`` table's entries."""
    lines = text.splitlines(keepends=True)
    start = next((i + 1 for i, line in enumerate(lines)
                  if (m := _TABLE.match(line)) and m.group(1).strip() == "parameters"), None)
    if start is None:
        raise FitError("the model file has no [parameters] table: nothing to fit")
    stop = next((i for i in range(start, len(lines)) if _TABLE.match(lines[i])), len(lines))
    return start, stop


def _table(text: str) -> dict:
    """The ``[parameters]`` table of a model file's text, numbers as their decimal text."""
    return tomllib.loads(text, parse_float=Decimal).get("parameters", {})


def _toml_string(value: str) -> str:
    return json.dumps(value, ensure_ascii=False)


def _entry(name: str, spec) -> str:
    """One ``[parameters]`` line: ``name = { value = ..., description = ..., ... }``."""
    if not isinstance(spec, dict):
        return f"{name} = {spec}\n"
    parts = []
    for key in ("value", "description", "domain", "example"):
        if key in spec:
            v = spec[key]
            text = _toml_string(v) if isinstance(v, str) else str(v) if isinstance(
                v, Decimal) else repr(v)
            parts.append(f"{key} = {text}")
    return f"{name} = {{ {', '.join(parts)} }}\n"


def _rewrite_parameters(text: str, change: Callable[[str, object], object]) -> str:
    """``text`` with each ``[parameters]`` entry ``name = spec`` replaced by
    ``change(name, spec)`` (the other tables and the comments kept as they are)."""
    table = _table(text)
    start, stop = _parameters_span(text)
    lines = text.splitlines(keepends=True)
    out = []
    for line in lines[start:stop]:
        key = line.split("=", 1)[0].strip() if "=" in line else ""
        if key in table and not line.lstrip().startswith("#"):
            new = change(key, table[key])
            out.append(line if new is table[key] else _entry(key, new))
        else:
            out.append(line)
    return "".join(lines[:start] + out + lines[stop:])


def free_text(text: str, names: Sequence[str], positive: Sequence[str] = ()) -> str:
    """The model file ``text`` with the valued parameters ``names`` made free (each value
    becomes the parameter's ``example``, where a fit starts) and the parameters
    ``positive`` declared ``domain = "positive"`` (a fit optimises their logarithm)."""
    table = _table(text)
    for name in list(names) + list(positive):
        if name not in table:
            known = ", ".join(table) or "none"
            raise FitError(f"unknown parameter {name!r} (the model's parameters: {known})")

    def change(name, spec):
        if name not in names and name not in positive:
            return spec
        spec = dict(spec) if isinstance(spec, dict) else {"value": spec}
        if name in names and "value" in spec:
            spec["example"] = spec.pop("value")
        if name in positive:
            spec["domain"] = "positive"
        return spec

    return _rewrite_parameters(text, change)


def fitted_text(text: str, values: dict[str, float]) -> str:
    """The model file ``text`` with each free parameter of ``values`` given its value
    (its example dropped): a model with nothing of those free, which ``derive generate``
    takes as it takes any model file. A parameter the text's own ``[parameters]`` does
    not declare (a composed block's) is refused: the file would keep it free."""
    table = _table(text)
    elsewhere = [name for name in values if name not in table]
    if elsewhere:
        raise FitError(f"parameter {elsewhere[0]!r} is not declared in the model file's own "
                       "[parameters] (a composed block's?): the fitted file cannot give it "
                       "its value")

    def change(name, spec):
        if name not in values:
            return spec
        spec = dict(spec) if isinstance(spec, dict) else {}
        spec.pop("example", None)
        return {"value": float(values[name]), **spec}

    return _rewrite_parameters(text, change)


def model_text(ref: str) -> tuple[str, str]:
    """(the model file's text, its label) for a catalog name or a model-file path."""
    if is_model_file(ref):
        path = Path(ref)
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise FitError(f"{ref}: cannot read the model file ({exc})") from None
    if ref not in catalog.names():
        known = ", ".join(catalog.names())
        raise FitError(f"unknown model {ref!r}: neither a catalog name ({known}) nor a "
                       "model file (.toml)")
    return catalog.read_text(ref), catalog.label(ref)


def write_model_file(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all (a temporary beside it, renamed)."""
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(temporary, "x", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise FitError(f"{path}: cannot write the fitted model file ({exc.strerror})") from None


# -- data -----------------------------------------------------------------------------------

def read_data(path: str | Path) -> np.ndarray:
    """A measurement file: ``.npy`` (a 2-D float array) or CSV (comma-separated, ``#``
    comments and one header line of names allowed, ``nan`` or an empty field missing),
    one row per step."""
    path = Path(path)
    try:
        if path.suffix == ".npy":
            data = np.load(path, allow_pickle=False)
        else:
            with open(path, encoding="utf-8") as handle:
                rows = [line for line in handle if line.strip() and not
                        line.lstrip().startswith("#")]
            if rows and not _numeric_row(rows[0]):
                rows = rows[1:]
            data = np.array([[float(f) if f.strip() else math.nan for f in r.split(",")]
                             for r in rows], dtype=float) if rows else np.zeros((0, 0))
    except (ValueError, OSError) as exc:
        raise FitError(f"{path}: cannot be read as measurements ({exc})") from None
    data = np.asarray(data, dtype=float)
    if data.ndim == 1:
        data = data[:, None]
    if data.ndim != 2 or len(data) == 0:
        raise FitError(f"{path}: measurements must be a non-empty table, one row per step")
    return data


def _numeric_row(row: str) -> bool:
    try:
        [float(f) for f in row.split(",") if f.strip()]
    except ValueError:
        return False
    return True


def split_columns(model, data: np.ndarray, where: str = "data") -> tuple[np.ndarray,
                                                                        np.ndarray | None]:
    """(z, u): the model's m measurement columns (NaN: missing) and, for a model with
    inputs, its n_u input columns (finite); any other column count is refused."""
    n_u = getattr(model, "n_inputs", 0)
    want = model.m + n_u
    if data.ndim != 2 or data.shape[1] != want:
        cols = data.shape[1] if data.ndim == 2 else "?"
        what = f"{model.m} measurement" + (f" and {n_u} input" if n_u else "")
        raise FitError(f"{where}: {cols} columns, but model {model.name!r} takes {want} "
                       f"({what} columns)")
    zs, us = data[:, :model.m], (data[:, model.m:] if n_u else None)
    if np.isinf(zs).any():
        row = int(np.argwhere(np.isinf(zs))[0][0])
        raise FitError(f"{where}: row {row} holds an infinite measurement (NaN marks a "
                       "missing one)")
    if model.kind != "linear" and np.isnan(zs).any():
        row = int(np.argwhere(np.isnan(zs))[0][0])
        raise FitError(f"{where}: row {row} holds a missing (NaN) measurement, which the "
                       "EKF's run does not skip (a linear model's does)")
    if us is not None and not np.isfinite(us).all():
        row = int(np.argwhere(~np.isfinite(us))[0][0])
        raise FitError(f"{where}: row {row} holds a non-finite input (inputs cannot be "
                       "missing)")
    return zs, us


# -- the fit --------------------------------------------------------------------------------

class _TracksRun:
    """Tracks of one length through one C call prepared once (their arrays converted and
    laid one track after another, the outputs allocated, Ps left NULL): ``run_tracks``
    over all of them, or ``run`` on the one track of a filter without run_tracks. Each
    call writes the parameters in place and returns (log L, its gradient) summed over the
    tracks and steps."""

    def __init__(self, module, tracks, x0, P0, q: int) -> None:
        name = "run_tracks" if "run_tracks" in module.functions else "run"
        if name == "run" and len(tracks) != 1:
            raise ValueError("a filter without run_tracks runs one track a call")
        fn = module.functions[name]
        count, steps = len(tracks), len(tracks[0][0])
        self.p = np.zeros(q, dtype=module.dtype)
        self.lls = module.empty(count * steps)
        self.dlls = module.empty(count * steps * q).reshape(count * steps, q)
        given = {"z": [zs for zs, _ in tracks], "u": [us for _, us in tracks],
                 "x0": [x0] * count, "P0": [P0] * count}
        # run's arrays by name, each track's rows after the one before (Ps not stored)
        arrays = {"lls": self.lls, "dlls": self.dlls, "p": self.p}
        for arg in fn.arguments:
            if arg.output and arg.name not in arrays and not arg.optional:
                arrays[arg.name] = module.empty(count * arg.size(steps))
            elif not arg.output and arg.name not in arrays:
                arrays[arg.name] = np.ascontiguousarray(np.stack(given[arg.name]),
                                                        dtype=module.dtype)
        #: run's outputs by name (xs, lls, dlls)
        self.outputs = {a.name: arrays[a.name] for a in fn.arguments
                        if a.output and a.name in arrays}
        self.counts = (steps, count) if name == "run_tracks" else (steps,)
        self.call = module.prepared(name, arrays)

    def __call__(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        self.p[:] = theta
        self.call(*self.counts)
        return float(np.sum(self.lls)), np.sum(self.dlls, axis=0)


def _track_runs(module, tracks, x0, P0, q: int, workers: int) -> list[_TracksRun]:
    """The C calls of one evaluation: the tracks of each length in ``run_tracks`` calls,
    split into ``workers`` slices as derive.batch splits a batch (whole blocks of lanes);
    without run_tracks, one ``run`` per track."""
    if "run_tracks" not in module.functions:
        return [_TracksRun(module, [track], x0, P0, q) for track in tracks]
    lengths: dict[int, list] = {}
    for track in tracks:
        lengths.setdefault(len(track[0]), []).append(track)
    return [_TracksRun(module, group[a:b], x0, P0, q) for group in lengths.values()
            for a, b in batch.split(len(group), workers, batch.TRACK_MULTIPLE)]


@dataclass
class _Objective:
    """-log L and its gradient over the tracks, in the optimiser's coordinates."""

    module: object
    tracks: list[tuple[np.ndarray, np.ndarray | None]]
    x0: np.ndarray
    P0: np.ndarray
    logs: np.ndarray  # True where a parameter is optimised as its log
    names: tuple[str, ...]
    workers: int = 1
    pool: ThreadPoolExecutor | None = None
    evaluations: int = 0
    runs: list | None = None
    last: float = math.inf
    memo: tuple | None = None  # (theta's bytes, (log L, gradient)) of the last evaluation

    def theta(self, phi: np.ndarray) -> np.ndarray:
        return np.where(self.logs, np.exp(np.where(self.logs, phi, 0.0)), phi)

    def loglik(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """(log L, d log L / d theta) summed over the tracks (the C calls on the pool's
        threads when there are several: the C releases the GIL); the last evaluation's
        again without running it (BFGS ends where it evaluated last)."""
        key = theta.tobytes()
        if self.memo is not None and self.memo[0] == key:
            return self.memo[1]
        self.evaluations += 1
        self.memo = None
        if self.runs is None:
            self.runs = _track_runs(self.module, self.tracks, self.x0, self.P0, len(theta),
                                    self.workers)
        if len(self.runs) == 1:
            value = self.runs[0](theta)
        else:
            if self.pool is None:
                self.pool = ThreadPoolExecutor(min(self.workers, len(self.runs)))
            parts = list(self.pool.map(lambda run: run(theta), self.runs))
            value = sum(p[0] for p in parts), np.sum([p[1] for p in parts], axis=0)
        self.memo = key, value
        return value

    def __call__(self, phi: np.ndarray) -> tuple[float, np.ndarray]:
        theta = self.theta(phi)
        try:
            ll, grad = self.loglik(theta)
        except NumericalError as exc:
            free = [n for n, log in zip(self.names, self.logs) if not log]
            at = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.names, theta))
            hint = (f"; declare a domain for {', '.join(free)} (domain = \"positive\")"
                    if free else "")
            raise FitError(f"the optimiser reached parameters where the filter fails ({at}: "
                           f"{exc}){hint}") from None
        if not math.isfinite(ll):
            return math.inf, np.zeros_like(phi)
        self.last = -ll
        return -ll, -np.where(self.logs, grad * theta, grad)


def _hessian(objective: _Objective, theta: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """d^2 log L / d theta^2 by forward differences of the exact gradient (``grad`` at
    ``theta``), steps of 1e-7 relative, symmetrised: q evaluations, each column accurate
    to ~1e-7 of its size (the step's truncation and the gradient's rounding, which the
    step divides, balance there)."""
    q = len(theta)
    H = np.empty((q, q))
    for j in range(q):
        h = HESSIAN_STEP * max(abs(theta[j]), 1e-8)
        e = np.zeros(q)
        e[j] = h
        H[:, j] = (objective.loglik(theta + e)[1] - grad) / h
    return (H + H.T) / 2


#: The relative step of the Hessian's forward differences.
HESSIAN_STEP = 1e-7


def _progress(enabled: bool):
    started = time.perf_counter()

    def line(iteration: int, value: float) -> None:
        if enabled:
            print(f"\rderive fit: iteration {iteration}, log-likelihood {-value:.10g}, "
                  f"{time.perf_counter() - started:.1f} s", end="", file=sys.stderr,
                  flush=True)
    return line


def fit(model, data, *, start: dict[str, float] | None = None,
        x0: Sequence[float] | None = None, P0=None, progress: bool | None = None,
        workers: int | None = None, gtol: float = 1e-6, polish: int = 3,
        generated=None) -> FitResult:
    """Fit the free parameters of ``model`` (a model object, a catalog name or a
    model-file path; linear, or nonlinear by its EKF) to ``data``: one array (steps, m
    [+ n_u]) of measurements (NaN: missing, for a linear model) and the model's inputs,
    or a list of such arrays or an array (tracks, steps, m [+ n_u]), tracks that share
    the parameters. The run starts from ``x0`` and ``P0`` (default: the model's; they
    must not depend on the free parameters). ``start``: the starting values by name
    (default: each parameter's example). ``progress``: a line on stderr per iteration
    (default: when stderr is a terminal). ``generated``: the model's KF with the option
    gradient (and missing, for data with NaN) already loaded
    (derive.pipeline.load_generated), to fit again without generating."""
    model = resolve_model(model)
    if model.kind not in FILTERS or getattr(model, "n_tangent", model.n) != model.n:
        raise FitError(f"model {model.name!r}: derive fit takes a linear or nonlinear model "
                       "without manifold states")
    names = tuple(p.name for p in model.parameters)
    if not names:
        raise FitError(f"model {model.name!r} has no free parameters: nothing to fit "
                       "(free valued ones with --free NAME)")
    start = dict(start or {})
    unknown = [k for k in start if k not in names]
    if unknown:
        raise FitError(f"unknown parameter {unknown[0]!r} (free: {', '.join(names)})")
    examples = getattr(model, "examples", {}) or {}
    theta0 = []
    for name in names:
        value = start.get(name, examples.get(name))
        if value is None:
            raise FitError(f"parameter {name!r} has no starting value (give it an example "
                           "in the model file, or --start NAME=VALUE)")
        theta0.append(float(value))
    theta0 = np.array(theta0)
    logs = np.array([declared_domain(p) is not None for p in model.parameters])
    if np.any(theta0[logs] <= 0):
        bad = names[int(np.argmax(logs & (theta0 <= 0)))]
        raise FitError(f"parameter {bad!r} starts at {start.get(bad, examples.get(bad))}, "
                       "outside its domain (> 0 for a fit)")
    arrays = ([data] if isinstance(data, np.ndarray) and data.ndim < 3 else list(data))
    tracks = [split_columns(model, np.asarray(a, dtype=float),
                            "data" if len(arrays) == 1 else f"track {i}")
              for i, a in enumerate(arrays)]
    x0, P0 = _start(model, x0, P0)
    began = time.perf_counter()
    if generated is None:
        generated = kernel(model, [zs for zs, _ in tracks])
    generation = time.perf_counter() - began
    began = time.perf_counter()
    objective = _Objective(generated.c, tracks, x0, P0, logs, names,
                           min(len(tracks), workers or os.cpu_count() or 1))
    try:
        theta, ll, grad, H, result = _maximise(objective, theta0, logs, gtol, polish,
                                               _progress(sys.stderr.isatty() if progress
                                                         is None else progress))
    finally:
        if objective.pool is not None:
            objective.pool.shutdown()
    if progress or (progress is None and sys.stderr.isatty()):
        print(file=sys.stderr)
    information = -H
    try:
        covariance = np.linalg.inv(information)
        se = np.sqrt(np.where(np.diag(covariance) > 0, np.diag(covariance), np.nan))
    except np.linalg.LinAlgError:
        se = np.full(len(names), np.nan)
    return FitResult(names, theta, se, ll, grad, information, int(result.nit),
                     objective.evaluations, bool(result.success) or
                     bool(np.all(np.abs(grad) * np.maximum(np.abs(theta), 1) <= 1e-6
                                 * max(abs(ll), 1))),
                     str(result.message), time.perf_counter() - began, generation)


def _maximise(objective: _Objective, theta0: np.ndarray, logs: np.ndarray, gtol: float,
              polish: int, line):
    """BFGS from ``theta0``, then Newton's polish: (theta, log L, its gradient, the
    Hessian, SciPy's result)."""
    iterations = [0]

    def callback(phi):
        iterations[0] += 1
        line(iterations[0], objective.last)

    phi0 = np.where(logs, np.log(np.where(logs, theta0, 1.0)), theta0)
    options = {"gtol": gtol, "maxiter": 2000}
    result = scipy.optimize.minimize(objective, phi0, jac=True, method="BFGS",
                                     callback=callback, options=options)
    theta = objective.theta(result.x)
    ll, grad = objective.loglik(theta)
    # Newton's polish on the exact gradient, the Hessian from BFGS's end point (each step
    # gains the digits the Hessian has: BFGS stops where the gradient is small, not zero)
    H = _hessian(objective, theta, grad)
    for _ in range(polish):
        try:
            step = np.linalg.solve(H, grad)
        except np.linalg.LinAlgError:
            break
        trial = theta - step
        if np.max(np.abs(step) / np.maximum(np.abs(trial), 1e-300)) <= 1e-12:
            break  # the step would not move the estimate: not evaluated
        if np.any(trial[logs] <= 0):
            break
        ll_trial, grad_trial = objective.loglik(trial)
        if not ll_trial >= ll - 1e-13 * abs(ll):  # (near the optimum, log L's rounding)
            break
        theta, ll, grad = trial, ll_trial, grad_trial
    return theta, ll, grad, H, result


def kernel_filter(model, zs: Sequence[np.ndarray]) -> tuple[str, dict]:
    """(the filter, its options) :func:`fit` evaluates log L with: a linear model's KF
    with the option gradient (and missing when a track of measurements ``zs`` has a NaN),
    a nonlinear model's EKF with the gradient."""
    options = {"gradient": True}
    if model.kind == "linear":  # (the EKF takes no NaN: split_columns refuses one)
        options["missing"] = any(np.isnan(z).any() for z in zs)
    return FILTERS[model.kind], options


def kernel(model, zs: Sequence[np.ndarray]):
    """The filter of :func:`kernel_filter`, generated and compiled for this machine
    (:data:`KERNEL_CFLAGS`; the build cache keeps it)."""
    name, options = kernel_filter(model, zs)
    return load_generated(model, name, options, "c", extra_cflags=KERNEL_CFLAGS)


#: The fit's filter runs where it is compiled: for this machine's instructions (its fused
#: multiply-add, so the file's DERIVE_FMA is the hardware one).
KERNEL_CFLAGS = ("-O3", "-march=native")


def _start(model, x0, P0) -> tuple[np.ndarray, np.ndarray]:
    """run's x0 and P0: given, or the model's (numbers in every model)."""
    n = model.n
    x0 = np.array(model.x0, dtype=float) if x0 is None else x0
    P0 = np.array(model.P0, dtype=float) if P0 is None else P0
    return (np.asarray(x0, dtype=float).reshape(n).copy(),
            np.asarray(P0, dtype=float).reshape(n, n).copy())
