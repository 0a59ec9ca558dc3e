"""Compile generated C with cffi and call it from Python with NumPy arrays.

``build_c(path)`` first compiles every ``.c`` file with the strict flags
(``gcc -std=c99 -O2 -Wall -Wextra -Werror -pedantic``, plus ``extra_cflags``; the
compiler: ``compiler``, else CC, else gcc; one process per core),
then links those objects into a cffi extension whose ``cdef`` is the header's
prototypes.  Builds are cached by a hash of the sources, flags, compiler and
Python in a per-user directory, :func:`cache_dir` (``$XDG_CACHE_HOME/derive``,
mode 0700, refused unless owned by the user and closed to group and others; or
``tmpdir``, checked the same way), so the same files are compiled once.  A build
happens in a fresh directory renamed into place whole, so a process never loads a
half-written library, and a library is loaded only if the user owns it, no one else can
write it and it is the one built (its SHA-256, written beside it); an entry of the
user's that fails the last two is built again.

The wrappers read the interface the generated header states in its machine-readable
line (derive.interface; the prose ``int PREFIX_step(x[2], P[2*2], z[1], x_new[2] out,
...)`` is rendered from the same description): ``step`` takes
the inputs in C order or by name (``p`` as keyword) and returns x flat and each matrix
(n, n), like the generated Python; ``run`` returns arrays shaped ``(steps, n)`` and
``(steps, n, n)``.  A non-zero status raises :class:`derive.errors.NumericalError`, or
:class:`derive.errors.PatternError` naming the entry for the pattern status.

The arrays are of the C's element type, which the interface line states (derive.interface:
double unless it says ``"element": "float"``): a float32 kernel (``--precision float``)
takes and returns float32 arrays, and refuses a float64 array (or a list of Python
floats) with :class:`derive.errors.DtypeError` naming the argument, rather than rounding
it silently; integer arrays are converted, as for a double kernel.
"""

from __future__ import annotations

import hashlib
import importlib.util
import itertools
import os
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import types
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from derive import interface
from derive.aligned import aligned_empty
from derive.domains import check_row, check_rows
from derive.errors import (
    DomainError,
    DtypeError,
    ModelError,
    NumericalError,
    PatternError,
    ShapeError,
)

STRICT_CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic")
#: Warnings generated C of either precision is also clean under (with STRICT_CFLAGS): any
#: double that slips into float code, or a value narrowed without a cast, is an error.
CONVERSION_CFLAGS = ("-Wdouble-promotion", "-Wfloat-conversion", "-Wconversion")


class BuildError(RuntimeError):
    """The C compiler or cffi failed; the message carries the compiler output."""


class BuildEnvironmentError(BuildError):
    """The environment cannot build: no C compiler, or an unsafe cache directory (the
    command line prints it as one line with exit status 2)."""


class CompilerNotFoundError(BuildEnvironmentError):
    """No C compiler: the message names the command looked for."""


class UnsafeCacheError(BuildEnvironmentError):
    """A cache directory or library that another user could have written."""


CArgument = interface.Argument
CFunction = interface.Function


def parse_interface(header: str) -> tuple[list[CFunction], dict[int, list[str]]]:
    """Functions and, per status number, the failing checks ("program: message") the
    header's interface line (derive.interface) states."""
    try:
        described = interface.read(header)
    except interface.InterfaceError as exc:
        raise BuildError(str(exc)) from None
    return list(described.functions), described.messages()


def _read_interface(header: str) -> interface.Interface:
    try:
        return interface.read(header)
    except interface.InterfaceError as exc:
        raise BuildError(str(exc)) from None


def _cdef(header: str) -> str:
    lines = [line for line in header.splitlines()
             if re.match(r"^(int|void) \w+\(.*\);$", line)
             or re.match(r"^#define \w+ \d+$", line)]
    # cffi's parser knows no restrict: the header spells it PREFIXDERIVE_RESTRICT
    return "\n".join(re.sub(r"\w*DERIVE_RESTRICT |\brestrict ", "", line)
                     for line in lines) + "\n"


class FilterModule:
    """NumPy wrappers around the functions of one generated C file."""

    def __init__(self, prefix: str, ffi, lib, described: interface.Interface) -> None:
        self.prefix = prefix
        self.ffi = ffi
        self.lib = lib
        self.interface = described
        self.functions = {f.name[len(prefix) + 1:]: f for f in described.functions}
        self.statuses = described.messages()
        self.dtype = np.dtype(described.dtype)
        self.c_type = described.element
        #: ``{"storage": n, "tangent": nt}`` for a filter whose P lives in a tangent space
        #: (each argument's ``space`` in ``interface`` names its own), else empty
        self.spaces = dict(described.spaces)

    def __getattr__(self, name: str):
        functions = self.__dict__.get("functions", {})
        if name in functions:
            return lambda *args, **kwargs: self.call(name, *args, **kwargs)
        raise AttributeError(name)

    def buffer(self, array: np.ndarray):
        """The cffi buffer of an array of the kernel's element type."""
        return self.ffi.from_buffer(f"{self.c_type}[]", array)

    def empty(self, shape) -> np.ndarray:
        """An output array of the kernel's element type, starting on a cache line
        (:func:`derive.aligned.aligned_empty`, as derive.batch's outputs)."""
        return aligned_empty(shape, self.dtype)

    def prepared(self, function: str, arrays: dict[str, np.ndarray]) -> PreparedCall:
        """``PREFIX_function`` bound to ``arrays`` (by argument name, each of the kernel's
        dtype, contiguous and of its shape; see :class:`PreparedCall`)."""
        return PreparedCall(self, function, arrays)

    def converted(self, function: str, name: str, value) -> np.ndarray:
        """``value`` as a contiguous array of the kernel's dtype; DtypeError when that would
        round it (a wider floating type given to a float32 kernel, an integer the dtype
        cannot hold exactly) or when it is not real numbers (complex, bool, str, object)."""
        given = np.asarray(value)
        where = f"{self.prefix}_{function}: argument {name!r}"
        if given.dtype.kind not in "fiu":
            # complex (its imaginary part would be dropped), bool, str (parsed), object
            # (None would become NaN): not numbers the kernel takes
            raise DtypeError(f"{where} is an array of {given.dtype}; this kernel takes real "
                             f"numbers ({self.dtype}, C {self.c_type})")
        if given.dtype.kind in "iu":
            exact = np.asarray(given.astype(self.dtype)).astype(given.dtype) == given
            if not np.all(exact):
                wrong = given.ravel()[np.flatnonzero(~exact.ravel())[0]]
                raise DtypeError(f"{where} holds the integer {int(wrong)}, which this kernel's "
                                 f"{self.dtype} (C {self.c_type}) cannot represent exactly")
        if (given.dtype.kind == "f" and given.dtype != self.dtype
                and given.dtype.itemsize > self.dtype.itemsize):
            what = "list of Python floats" if not isinstance(value, np.ndarray) else "array"
            raise DtypeError(f"{where} is a "
                             f"{given.dtype} {what}, but this kernel is {self.dtype} "
                             f"(C {self.c_type}): pass np.asarray({name}, "
                             f"dtype=np.{self.dtype})")
        return np.ascontiguousarray(given, dtype=self.dtype)

    def _array(self, function: str, arg: CArgument, value, steps: int) -> np.ndarray:
        """``value`` as a contiguous array of the kernel's dtype (:meth:`converted`) of one
        of the shapes ``arg`` accepts, or ShapeError naming the argument, the shapes
        accepted and the shape given."""
        array = self.converted(function, arg.name, value)
        accepted = arg.shapes(steps)
        if array.shape not in accepted:
            raise ShapeError(f"{self.prefix}_{function}: argument {arg.name!r} must have shape "
                             + " or ".join(str(s) for s in accepted)
                             + f", got {array.shape}")
        return array

    def call(self, name: str, *args, with_covariance: bool = True, **named):
        """Call ``PREFIX_name`` with NumPy inputs in C order, or by name (the C name or the
        generated Python's: ``z`` or ``zs``, ``u`` or ``us``, ``p``); returns the outputs."""
        fn = self.functions[name]
        inputs = [a for a in fn.arguments if not a.output]
        where = f"{self.prefix}_{name}"
        if len(args) > len(inputs):
            raise TypeError(f"{where} takes {[a.name for a in inputs]}, got {len(args)} "
                            "arrays")
        values = dict(zip((a.name for a in inputs), args))
        aliases = {alias: a.name for a in inputs for alias in (a.name, a.py_name) if alias}
        for key, value in named.items():
            if key == "p" and value is None:  # no parameters given (or none taken)
                continue
            if key not in aliases:
                raise TypeError(f"{where} got an unexpected argument {key!r}; it takes "
                                f"{', '.join(a.py_name or a.name for a in inputs)}")
            if aliases[key] in values:
                raise TypeError(f"{where} got {key!r} twice")
            values[aliases[key]] = value
        absent = [a.name for a in inputs if a.name not in values]
        if absent == ["p"]:
            raise TypeError(f"{where} needs the parameters p")
        if absent:
            raise TypeError(f"{where} takes {[a.name for a in inputs]}, missing {absent}")
        given = [values[a.name] for a in inputs]
        steps = 0
        if fn.has_steps:
            first = next(a for a in inputs if a.per_step)
            shape = np.shape(given[inputs.index(first)])
            steps = shape[0] if shape else 0
        arrays, outputs = {}, []
        for arg in fn.arguments:
            if arg.output:
                if arg.optional and not with_covariance:
                    continue
                arrays[arg.name] = out = self.empty(arg.size(steps))
                if not arg.scratch:  # a work array is written, not returned
                    outputs.append((arg, out))
            else:
                arrays[arg.name] = self._array(name, arg, values[arg.name], steps)
        self.prepared(name, arrays)(*((steps,) if fn.has_steps else ()))
        if fn.has_steps:
            shaped = [out.reshape(tuple(steps if d == "steps" else d for d in arg.dims))
                      for arg, out in outputs]
        else:  # P and U as (n, n) arrays, as run returns (steps, n, n)
            shaped = [out.reshape(tuple(int(d) for d in arg.dims)) for arg, out in outputs]
        return shaped[0] if len(shaped) == 1 else tuple(shaped)


class PreparedCall:
    """One C function of a module with its buffers made once: ``arrays`` holds an array
    for each argument by name (an optional output left out is passed as NULL). A call
    passes the leading counts (steps; then tracks for run_tracks) and the stride of each
    strided input (its row's length when it has a row per step, 0 for one row shared by
    every step), raises the error of a non-zero status and returns the status. The
    arrays may be rewritten in place between calls (a fit's parameters)."""

    def __init__(self, module: FilterModule, function: str,
                 arrays: dict[str, np.ndarray]) -> None:
        fn = module.functions[function]
        self.module, self.function, self.arrays = module, function, arrays
        self.inputs = {a.name: arrays.get(a.name) for a in fn.arguments if not a.output}
        args, strides = [], []
        for arg in fn.arguments:
            array = arrays.get(arg.name)
            if array is None:
                if not arg.optional:
                    raise ShapeError(f"{module.prefix}_{function}: argument {arg.name!r} "
                                     "is required")
                args.append(module.ffi.NULL)
                continue
            args.append(module.buffer(array))
            if arg.strided and not arg.output:
                strides.append(arg.size() if array.ndim == 2 else 0)
        self._c = getattr(module.lib, fn.name)
        self._args, self._strides = args, strides
        self._returns_status = fn.returns_status

    def __call__(self, *counts: int) -> int:
        status = self._c(*counts, *self._args, *self._strides)
        if self._returns_status and status:
            raise status_error(self.module, self.function, status, self.inputs)
        return status


#: The programs run (and run_tracks) calls, whose statuses it returns: ``enter`` (when the
#: unit has one) checks run's start arguments, else run checks them with the step's checks.
RUN_PROGRAMS = ("enter", "step")


def status_error(module: FilterModule, function: str, status: int, values: dict
                 ) -> NumericalError | PatternError:
    """The exception for a non-zero status of ``PREFIX_function`` called with the input
    arrays ``values`` (by argument name): PatternError naming the first entry of a square
    input (P, P0, U; any track) outside the pattern the header states, for a pattern status
    of a program the function runs; DomainError (a NumericalError) naming the step (run),
    the parameter and its value for a parameter's domain status; NumericalError naming the
    failed check otherwise."""
    programs = (RUN_PROGRAMS if function in ("run", "run_tracks") else (function,))
    texts = module.statuses.get(status, [])
    where = f"{module.prefix}_{function} failed with status {status}"
    # the statuses of a file are numbered apart: the number alone names the check
    parameter = next((s.parameter for s in module.interface.statuses
                      if s.number == status and s.parameter), ())
    if parameter and values.get("p") is not None:  # a declared domain: name step and value
        try:
            if function in ("run", "run_tracks"):
                check_rows([parameter], values["p"])
            else:
                check_row([parameter], values["p"])
        except DomainError as exc:
            return DomainError(f"{where}: {exc}")
    present = next((s for s in module.interface.statuses
                    if s.number == status and s.present), None)
    if present is not None and values.get(present.present[0]) is not None:
        named = nan_element(values[present.present[0]], function, present)
        return NumericalError(f"{where}: {named}{present.message}")
    arguments = {a.name: a for a in module.functions.get(function,
                                                         module.functions.get("run")).arguments
                 if not a.output and len(a.dims) == 2 and a.dims[0] == a.dims[1]}
    for program in programs:
        mine = [t.split(": ", 1)[1] for t in texts if t.startswith(f"{program}: ")]
        zero = module.interface.zero(program, status)
        if not (mine and zero):
            continue
        for name, arg in arguments.items():
            if values.get(name) is None:
                continue
            n = int(arg.dims[0])
            flat = np.asarray(values[name], dtype=float).reshape(-1, n * n)
            upper = [k for k in zero if k // n <= k % n]
            for track, row in enumerate(flat):
                for k in upper:
                    if not row[k] == 0:
                        i, j = divmod(k, n)
                        which = f" (track {track})" if len(flat) > 1 else ""
                        return PatternError(f"{where}: {name}[{i}][{j}] = {float(row[k])!r}"
                                            f"{which}: {mine[0]}")
    return NumericalError(f"{where}: " + " or ".join(texts or ["unknown check"]))


def nan_element(rows, function: str, status) -> str:
    """``step K: NAME (z[I]): `` for the first NaN of the measurements ``rows`` the call
    was given (the step's z; run's ``(steps, m)`` then any track axes; run_tracks'
    ``(tracks, steps, m)``, with `` (track T)``), for the status of the presence checks
    ``status`` (its ``present``: the port and the measurement of each element)."""
    port, names = status.present
    array = np.asarray(rows, dtype=float)
    if function == "run_tracks":  # (tracks, steps, m): steps first, then the track
        array = np.moveaxis(array, 0, -1)
    elif function != "run":  # one step: (m,), then any track axes
        array = array[np.newaxis]
    if array.ndim == 1:  # one measurement per step
        array = array[:, np.newaxis]
    nan = np.isnan(array.reshape(array.shape[:2] + (-1,))).any(axis=2)
    if not nan.any():
        return ""
    step, index = (int(v) for v in np.argwhere(nan)[0])
    where = f"step {step}: " if function in ("run", "run_tracks") else ""
    if function == "run_tracks":
        track = int(np.flatnonzero(np.isnan(array[step, index].reshape(-1)))[0])
        where = f"step {step} (track {track}): "
    return f"{where}{names[index]} ({port}[{index}]): "


def _run_tracks(module: FilterModule, zs, x0, P0=None, p=None, with_covariance=True,
                out=None, us=None):
    """Call ``PREFIX_run_tracks`` on track-major arrays: zs (tracks, steps, m), x0
    (tracks, n), P0 (tracks, n, n), for a model with inputs us (tracks, steps, n_u);
    returns xs (tracks, steps, n) and Ps (or None).
    ``out``: (xs, Ps) written in place instead (C-contiguous, of those shapes; Ps None when
    not stored), as derive.batch passes the slices of one result. Every array is of the
    kernel's dtype (float32 for a float kernel)."""
    run = module.functions["run_tracks"]
    inputs = {a.name: a for a in run.arguments if not a.output}
    zs = module.converted("run_tracks", "z", zs)
    shape = zs.shape
    tracks, steps = (shape + (0, 0))[:2]

    def track_major(name: str, value) -> np.ndarray:
        """(tracks, the run's shape of the argument), or ShapeError."""
        array = module.converted("run_tracks", name, value)
        accepted = [(tracks,) + s for s in inputs[name].shapes(steps)]
        if array.shape not in accepted:
            raise ShapeError(f"{module.prefix}_run_tracks: argument {name!r} must have shape "
                             + " or ".join(str(s) for s in accepted) + f", got {array.shape}")
        return array

    zs, x0 = track_major("z", zs), track_major("x0", x0)
    n = int(inputs["x0"].dims[0])
    xs, Ps_out = out if out is not None else (module.empty((tracks, steps, n)), None)
    Ps = None
    if P0 is not None:
        P0 = track_major("P0", P0)
        Ps = (Ps_out if out is not None else module.empty((tracks, steps, n, n))
              ) if with_covariance else None
    if p is not None:
        p = module._array("run_tracks", inputs["p"], p, steps)
    # its other optional outputs (a log-likelihood's lls, dlls) are not stored
    given = {"z": zs, "x0": x0, "P0": P0, "xs": xs, "Ps": Ps, "p": p,
             "u": None if us is None else track_major("u", us)}
    absent = [a.name for a in run.arguments if not a.optional and given.get(a.name) is None]
    if absent:
        raise ShapeError(f"{module.prefix}_run_tracks: argument {absent[0]!r} is "
                         "required (run it track by track with run)")
    module.prepared("run_tracks", {k: v for k, v in given.items() if v is not None}
                    )(steps, tracks)
    return xs if P0 is None else (xs, Ps)


FilterModule.run_tracks = _run_tracks


class CModule:
    """A compiled extension holding one or more generated filters.

    ``module[prefix]`` or ``module.filters[prefix]`` is a :class:`FilterModule`;
    with a single filter, ``module.step(...)`` and ``module.run(...)`` reach it.
    """

    def __init__(self, extension, filters: dict[str, FilterModule], path: Path) -> None:
        self.extension = extension
        self.ffi = extension.ffi
        self.lib = extension.lib
        self.filters = filters
        self.path = path

    def __getitem__(self, prefix: str) -> FilterModule:
        return self.filters[prefix]

    def __getattr__(self, name: str):
        filters = self.__dict__.get("filters", {})
        if len(filters) == 1:
            return getattr(next(iter(filters.values())), name)
        if name in filters:
            return filters[name]
        raise AttributeError(name)


_LOADED: dict[str, object] = {}
_LOADED_PYTHON = itertools.count()


def compiler_command(compiler: str | None = None) -> str:
    """The C compiler command: ``compiler`` when given (build_c's argument), else the CC
    environment variable, else gcc; CompilerNotFoundError when it is not on PATH."""
    cc = compiler if compiler is not None else os.environ.get("CC", "gcc")
    command = cc.split()[0] if cc.split() else cc
    if shutil.which(command) is None:
        where = ("the compiler argument" if compiler is not None
                 else "the CC environment variable, default gcc")
        raise CompilerNotFoundError(f"no C compiler: looked for {command!r} on PATH (set by "
                                    f"{where})")
    return cc


def _check_private(path: Path, what: str) -> None:
    """Refuse ``path`` unless this user owns it and group and others cannot write it."""
    info = os.stat(path)
    if info.st_uid != os.getuid():
        raise UnsafeCacheError(f"{what} {path} belongs to user id {info.st_uid}, not to you "
                               f"({os.getuid()}); derive loads compiled code only from "
                               "your own files")
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise UnsafeCacheError(f"{what} {path} is writable by group or others (mode "
                               f"{stat.S_IMODE(info.st_mode):o}); derive loads compiled code "
                               "only from a directory no one else can write")


def cache_dir(tmpdir: str | os.PathLike | None = None) -> Path:
    """The directory of compiled modules: ``tmpdir`` if given, else ``$XDG_CACHE_HOME/derive``
    (``~/.cache/derive``), created with mode 0700; either must be owned by the user and
    not writable by group or others (:class:`UnsafeCacheError`)."""
    if tmpdir is not None:
        path = Path(tmpdir)
    else:
        base = os.environ.get("XDG_CACHE_HOME", "")
        if not os.path.isabs(base):   # the XDG rule: a relative path is ignored
            base = os.path.join(os.path.expanduser("~"), ".cache")
        path = Path(base) / "derive"
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
    except OSError as exc:
        raise UnsafeCacheError(f"cannot create the cache directory {path}: "
                               f"{exc.strerror or exc}") from None
    _check_private(path, "the cache directory")
    return path


def _built(folder: Path, name: str) -> Path | None:
    found = sorted(folder.glob(f"{name}*.so")) + sorted(folder.glob(f"{name}*.pyd"))
    return found[0] if found else None


def cached_extension(cache: Path, key: str, name: str, build: Callable[[Path], None]) -> Path:
    """The library of the extension ``name`` under ``cache/key``, built if missing.

    ``build(work)`` compiles into a fresh directory ``work``; its library is then closed
    to group and others' writing (whatever the umask made it), its SHA-256 written beside
    it (:data:`_DIGEST`), and ``work`` renamed to ``cache/key`` whole: a process that
    finds ``cache/key`` finds a finished library.  Two processes building the same key
    both build; the first rename wins, the other discards its copy.  An entry of this
    user's that cannot be trusted or used (its directory or library writable by group or
    others, a library that is not the one built: truncated, changed, or without its
    digest) is never loaded: it is moved aside and built again.  An entry of another
    user's is refused (:class:`UnsafeCacheError`)."""
    final = cache / key
    library = _built(final, name)
    if library is not None and _spoiled(final, library):
        _discard(cache, final)
        library = None
    if library is None:
        work = Path(tempfile.mkdtemp(prefix=f"{key}-", dir=cache))
        try:
            build(work)
            built = _built(work, name)
            if built is not None:
                os.chmod(built, stat.S_IMODE(os.stat(built).st_mode) & ~0o022)
                (work / _DIGEST).write_text(_digest(built))
            try:
                os.replace(work, final)
            except OSError:
                if _built(final, name) is None:   # not a lost race: a real failure
                    raise
        finally:
            shutil.rmtree(work, ignore_errors=True)
        library = _built(final, name)
        if library is None:
            raise BuildError(f"cffi built no library {name} in {final}")
    _check_private(final, "the cache directory")
    _check_private(library, "the compiled library")
    return library


_DIGEST = "library.sha256"
"""The file of a cache entry holding its library's SHA-256, written when it was built."""


def _digest(library: Path) -> str:
    return hashlib.sha256(library.read_bytes()).hexdigest()


def _spoiled(final: Path, library: Path) -> bool:
    """Whether this user's cache entry is unfit to load: its directory or library writable
    by group or others (built under umask 002 by an older derive, or changed since), or
    a library whose SHA-256 is not the one written when it was built (a truncated
    library can crash the loader, not just fail it)."""
    mine = [os.stat(p) for p in (final, library)]
    if any(info.st_uid != os.getuid() for info in mine):
        return False        # another user's: refused by _check_private, never replaced
    if any(info.st_mode & (stat.S_IWGRP | stat.S_IWOTH) for info in mine):
        return True
    try:
        return (final / _DIGEST).read_text() != _digest(library)
    except OSError:
        return True


def _discard(cache: Path, final: Path) -> None:
    """Move the entry ``final`` aside (one rename: a process that loaded it keeps its
    mapping) and remove it."""
    aside = Path(tempfile.mkdtemp(prefix="stale-", dir=cache))
    try:
        os.replace(final, aside / "entry")
    except FileNotFoundError:
        pass                # another process discarded it first
    finally:
        shutil.rmtree(aside, ignore_errors=True)


def _compile_object(cc: str, source: Path, obj: Path, flags: list[str]) -> None:
    cmd = cc.split() + flags + ["-fPIC", "-c", str(source), "-o", str(obj)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"{' '.join(cmd)} failed:\n{proc.stderr}")


def load_module_file(name: str, path: Path) -> types.ModuleType:
    """Execute the file ``path`` (Python source or a compiled extension) as the module
    ``name``, not added to ``sys.modules``: derive's one way to import a file."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_python(path: str | os.PathLike) -> types.ModuleType:
    """Load a generated Python file (``MODEL/FILTER.py``) as a fresh module.

    Each call executes the file anew under a name unique to the call, so two files named
    ``kf.py`` of different models never share a module; nothing is added to
    ``sys.modules``.  A path that is not an existing ``.py`` file raises
    :class:`derive.errors.ModelError`.
    """
    path = Path(path)
    if path.suffix != ".py" or not path.is_file():
        raise ModelError(f"{path}: not an existing generated Python file (MODEL/FILTER.py)")
    name = f"derive_generated_{path.parent.name}_{path.stem}_{next(_LOADED_PYTHON)}"
    return load_module_file(name, path)


def _prefix(header: str, path: Path) -> str:
    """``MODEL_FILTER``: the prefix of the functions a generated header declares.

    Generated files are named FILTER.{c,h} inside MODEL/, so the file stem alone does
    not identify a filter; the function names do."""
    functions = _read_interface(header).functions
    for function in functions:  # run, or the step (a file made with --no-run)
        for program in ("run", "step"):
            if function.program == program and function.name.endswith(f"_{program}"):
                return function.name[: -len(f"_{program}")]
    if any(f.name.startswith(path.stem + "_") for f in functions):
        return path.stem  # functions without a run loop (render_functions)
    raise BuildError(f"{path} is not a header generated by derive (its interface comment "
                     "declares no functions)")


def build_c(path_or_paths: str | os.PathLike | Sequence[str | os.PathLike], *,
            extra_cflags: Sequence[str] = (), tmpdir: str | os.PathLike | None = None,
            compiler: str | None = None) -> CModule:
    """Compile generated ``.c`` files (each with its ``.h`` beside it) and wrap them.

    ``path_or_paths``: one path or several, to ``.c`` (or ``.h``) files.
    ``compiler``: the command that compiles them (``"clang"``, ``"gcc-12"``; default: the
    CC environment variable, else gcc), part of the cache key. cffi's own wrapper, which
    includes the headers and calls the filters' objects, is compiled by the compiler
    Python's extensions are built with (setuptools: CC too when set).
    """
    import cffi  # imported on first build only

    paths = [path_or_paths] if isinstance(path_or_paths, (str, os.PathLike)) else path_or_paths
    sources = []
    for p in paths:
        p = Path(p)
        c_file, h_file = p.with_suffix(".c"), p.with_suffix(".h")
        for f in (c_file, h_file):
            if not f.is_file():
                raise BuildError(f"{f} does not exist (build_c needs both {c_file.name} "
                                 f"and {h_file.name})")
        h_text = h_file.read_text()
        sources.append((_prefix(h_text, h_file), c_file.stem, c_file.read_text(), h_text))
    sources.sort()
    if len({prefix for prefix, *_ in sources}) != len(sources):
        raise BuildError(f"two files define the same filter: {[s[0] for s in sources]}")
    flags = list(STRICT_CFLAGS) + [str(f) for f in extra_cflags]
    cc = compiler_command(compiler)
    digest = hashlib.sha256()
    for part in [cc, sys.version, cffi.__version__, *flags] + [
            x for s in sources for x in s]:
        digest.update(part.encode() + b"\0")
    key = digest.hexdigest()[:20]
    name = f"_derive_{key}"
    cache = cache_dir(tmpdir)
    final = cache / key
    interfaces = {prefix: _read_interface(h) for prefix, _, _, h in sources}

    def build(work: Path) -> None:
        objects = []
        for prefix, stem, c_text, h_text in sources:
            folder = work / prefix  # one folder per filter: FILTER.h names repeat
            folder.mkdir()
            (folder / f"{stem}.c").write_text(c_text)
            (folder / f"{stem}.h").write_text(h_text)
            objects.append(str(folder / f"{stem}.o"))
        # one compiler process per core: a catalog's files (76) in a fraction of the time
        with ThreadPoolExecutor(min(len(sources), os.cpu_count() or 1)) as pool:
            compiled = [pool.submit(_compile_object, cc, Path(obj).with_suffix(".c"),
                                    Path(obj), flags) for obj in objects]
        for done in compiled:
            done.result()  # the first file's failure in the files' order
        ffi = cffi.FFI()
        ffi.cdef("".join(_cdef(h) for *_, h in sources))
        ffi.set_source(name, "".join(f'#include "{prefix}/{stem}.h"\n'
                                     for prefix, stem, _, _ in sources),
                       include_dirs=[str(work)], extra_objects=objects, libraries=["m"])
        try:
            ffi.compile(tmpdir=str(work), verbose=False)
        except Exception as exc:  # cffi raises VerificationError and distutils errors
            raise BuildError(f"cffi could not build {name}: {exc}") from exc

    if name not in _LOADED:
        _LOADED[name] = load_module_file(name, cached_extension(cache, key, name, build))
    extension = _LOADED[name]
    filters = {prefix: FilterModule(prefix, extension.ffi, extension.lib, interfaces[prefix])
               for prefix, *_ in sources}
    return CModule(extension, filters, final)
