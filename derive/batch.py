"""Many independent tracks through a generated C ``run_tracks``, on every core.

``run_tracks(kernel, zs, x0s, P0s, p=None, workers=None)`` splits the tracks into
contiguous slices and runs each slice's ``MODEL_FILTER_run_tracks`` in its own thread
(cffi releases the GIL during the call), writing into slices of one result. Given a
Dask array ``zs`` chunked along the track axis it returns lazy Dask arrays instead: one
task per chunk, each calling the kernel, which every worker compiles (or finds in the
build cache) and loads once. Each track's result is bitwise the same however the tracks
are split, since run_tracks treats every track on its own. The threads' slices start at
multiples of :data:`TRACK_MULTIPLE` tracks (whole blocks of lanes, no cache line shared
between threads in the outputs, which are allocated cache-line aligned) and each thread
is the first to write its slice of a new output; a caller may pass its own outputs
(``out=``) to reuse them from call to call.

The kernel travels to Dask's workers as a :class:`Kernel`: the path of the generated
``.c`` file (its ``.h`` beside it) and the compiler flags, never a cffi object. Dask is
imported only when a Dask array is given (``pip install derive-filters[dask]``).
"""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .build import FilterModule, build_c
from .errors import DtypeError, ModelError, NumericalError, PatternError, ShapeError


@dataclass(frozen=True)
class Kernel:
    """A generated C filter to load where it runs: ``path`` to ``MODEL/FILTER.c`` (its
    ``.h`` beside it), built by :func:`derive.build_c` with ``extra_cflags`` in the
    build cache ``tmpdir`` (None: the user's cache)."""

    path: str
    extra_cflags: tuple[str, ...] = ()
    tmpdir: str | None = None

    def load(self) -> FilterModule:
        """The filter's wrappers, built and loaded once per process."""
        with _LOCK:
            module = _KERNELS.get(self)
            if module is None:
                built = build_c(self.path, extra_cflags=self.extra_cflags, tmpdir=self.tmpdir)
                if len(built.filters) != 1:
                    raise ModelError(f"{self.path}: holds {len(built.filters)} filters; a "
                                     "batch kernel is one generated filter")
                module = _KERNELS[self] = next(iter(built.filters.values()))
            return module

    def preload(self) -> None:
        """Load the kernel here and return nothing (``Client.run(kernel.preload)`` loads it
        on every Dask worker ahead of a timed computation)."""
        self.load()


_KERNELS: dict[Kernel, FilterModule] = {}
_LOCK = threading.Lock()


def as_kernel(kernel) -> Kernel:
    """``kernel`` as a :class:`Kernel`: a Kernel, or the path of a generated ``.c`` file."""
    if isinstance(kernel, Kernel):
        return kernel
    if isinstance(kernel, (str, os.PathLike)):
        return Kernel(str(Path(kernel).with_suffix(".c")))
    raise ModelError("batch kernel: expected a derive.batch.Kernel or the path of a generated "
                     f".c file, got {type(kernel).__name__}")


def _module(kernel) -> FilterModule:
    module = kernel if isinstance(kernel, FilterModule) else as_kernel(kernel).load()
    if not hasattr(module.lib, f"{module.prefix}_run_tracks"):
        raise ModelError(f"{module.prefix}: its C has no run_tracks (generated with "
                         "--no-run-tracks, or a filter without a batch function)")
    return module


@dataclass(frozen=True)
class _Layout:
    """The checked shapes of one batch: per track or shared (``*_shared``)."""

    tracks: int
    steps: int
    n: int
    x0_shared: bool
    P0_shared: bool


def _check(module: FilterModule, zs_shape, x0_shape, P0_shape, p) -> _Layout:
    """The batch's layout, or ShapeError / ModelError naming the argument."""
    name = f"{module.prefix} batch run_tracks"
    inputs = {a.name: a for a in module.functions["run"].arguments if not a.output}
    if len(zs_shape) < 2:
        raise ShapeError(f"{name}: zs must have shape (tracks, steps, ...), got {zs_shape}")
    tracks, steps = zs_shape[:2]
    if any(not isinstance(d, (int, np.integer)) for d in zs_shape):
        raise ShapeError(f"{name}: zs has unknown chunk sizes {zs_shape} (compute them "
                         "first, e.g. dask's compute_chunk_sizes())")
    accepted = [(tracks,) + s for s in inputs["z"].shapes(steps)]
    if tuple(zs_shape) not in accepted:
        raise ShapeError(f"{name}: zs must have shape " + " or ".join(map(str, accepted))
                         + f", got {tuple(zs_shape)}")

    def per_track_or_shared(arg: str, given: str, shape) -> bool:
        own = [tuple(s) for s in inputs[arg].shapes(steps)]
        if tuple(shape) in [(tracks,) + s for s in own]:
            return False
        if tuple(shape) in own:
            return True
        raise ShapeError(f"{name}: {given} must have shape "
                         + " or ".join(str((tracks,) + s) for s in own) + " (one per track) or "
                         + " or ".join(map(str, own)) + f" (shared), got {tuple(shape)}")

    x0_shared = per_track_or_shared("x0", "x0s", x0_shape)
    if ("P0" in inputs) != (P0_shape is not None):
        raise ModelError(f"{name}: " + ("P0s is required (the filter starts from a "
                                        "covariance)" if "P0" in inputs else
                                        "the filter takes no P0s (it carries no covariance)"))
    P0_shared = P0_shape is not None and per_track_or_shared("P0", "P0s", P0_shape)
    if ("p" in inputs) != (p is not None):
        raise ModelError(f"{name}: " + ("p is required (the filter has free parameters)"
                                        if "p" in inputs else
                                        "the filter takes no parameters p"))
    if p is not None:
        shapes = inputs["p"].shapes(steps)
        if np.shape(p) not in shapes:
            raise ShapeError(f"{name}: p must have shape " + " or ".join(map(str, shapes))
                             + f" (shared by every track), got {np.shape(p)}")
    return _Layout(int(tracks), int(steps), int(inputs["x0"].dims[0]), x0_shared, P0_shared)


def _slice(array, shared: bool, start: int, stop: int):
    if array is None:
        return None
    if shared:
        return np.broadcast_to(array, (stop - start,) + np.shape(array))
    return array[start:stop]


def _is_dask(array) -> bool:
    """A Dask array (dask.array is imported only by code that made one)."""
    dask_array = sys.modules.get("dask.array")
    return dask_array is not None and isinstance(array, dask_array.Array)


#: Threads' slices of tracks start at multiples of this many tracks (when every thread
#: gets at least as many): a multiple of every default lane count of run_tracks (8 to 64),
#: so each slice runs whole blocks and only the last has a scalar tail, and of a 64-byte
#: cache line in every array of one track after another, so that two threads never write
#: the same line of an aligned output (:func:`derive.aligned.aligned_empty`).
TRACK_MULTIPLE = 64
#: Slices of tracks per thread when there are enough tracks (each at least
#: TRACK_MULTIPLE): the threads take them in turn, so a thread whose core is shared with
#: another job does less of the batch instead of the others waiting for it.
SLICES_PER_WORKER = 8


def split(tracks: int, parts: int, multiple: int = 1) -> list[tuple[int, int]]:
    """``parts`` contiguous slices [start, stop) of ``tracks`` (no empty slice): when each
    part gets at least ``multiple`` tracks, every start the multiple of ``multiple``
    nearest the even split (sizes differ by at most ``multiple``); else sizes differing
    by at most one."""
    parts = max(1, min(parts, tracks))
    if multiple > 1 and tracks >= parts * multiple:
        edges = [multiple * ((tracks * i // parts + multiple // 2) // multiple)
                 for i in range(parts)] + [tracks]
    else:
        edges = [tracks * i // parts for i in range(parts + 1)]
    return [(a, b) for a, b in zip(edges, edges[1:]) if b > a]


def _checked_out(module: FilterModule, out, layout: _Layout, has_P0: bool,
                 with_covariance: bool, inputs: dict[str, np.ndarray]):
    """The caller's output arrays ``out`` (xs, or (xs, Ps) for a filter with P0, Ps None
    when covariances are not stored) as (xs, Ps), checked: ndarrays of the kernel's dtype
    and the result's shapes, C-contiguous, writeable, sharing no memory with the inputs or
    with each other; DtypeError / ShapeError / ModelError naming the array."""
    name = f"{module.prefix} batch run_tracks"
    tracks, steps, n = layout.tracks, layout.steps, layout.n
    if has_P0:
        if not (isinstance(out, tuple) and len(out) == 2):
            raise ModelError(f"{name}: out must be a pair (xs, Ps) for a filter with P0 "
                             f"(Ps None when with_covariance is False), got "
                             f"{type(out).__name__}")
        xs, Ps = out
        if (Ps is None) == with_covariance:
            raise ModelError(f"{name}: out's Ps must be " + (
                "an array (tracks, steps, n, n): with_covariance is True" if with_covariance
                else "None: with_covariance is False"))
    elif isinstance(out, tuple):
        raise ModelError(f"{name}: out must be one array xs for a filter without P0, got a "
                         "tuple")
    else:
        xs, Ps = out, None
    wanted = {"xs": (xs, (tracks, steps, n)), "Ps": (Ps, (tracks, steps, n, n))}
    checked = {}
    for label, (array, shape) in wanted.items():
        if array is None:
            continue
        if not isinstance(array, np.ndarray):
            raise ModelError(f"{name}: out {label} must be a NumPy array, got "
                             f"{type(array).__name__}")
        if array.dtype != module.dtype:
            raise DtypeError(f"{name}: out {label} is {array.dtype}, but this kernel writes "
                             f"{module.dtype} (C {module.c_type})")
        if array.shape != shape:
            raise ShapeError(f"{name}: out {label} must have shape {shape}, got "
                             f"{array.shape}")
        if not array.flags.c_contiguous:
            raise ShapeError(f"{name}: out {label} must be C-contiguous (one track after "
                             "another)")
        if not array.flags.writeable:
            raise ModelError(f"{name}: out {label} is read-only")
        for other, value in {**inputs, **checked}.items():
            if value is not None and np.may_share_memory(array, value):
                raise ModelError(f"{name}: out {label} shares memory with {other}: the "
                                 "outputs must be arrays of their own")
        checked[label] = array
    return xs, Ps


def run_tracks(kernel, zs, x0s, P0s=None, p=None, *, workers: int | None = None,
               with_covariance: bool = True, out=None, us=None):
    """Filter ``tracks`` independent tracks with the generated C ``run_tracks``.

    ``kernel``: a :class:`Kernel`, the path of a generated ``.c`` file, or (NumPy inputs
    only) a loaded :class:`derive.build.FilterModule`. ``zs``: (tracks, steps, m) (or
    (tracks, steps) when m = 1); ``x0s``: (tracks, n) or one (n,) shared by all;
    ``P0s``: (tracks, n, n) / (tracks, n*n) or one shared, required exactly when the
    filter starts from a covariance; ``p``: the free parameters, one row or one row per
    step, shared by every track (as the C takes them); ``us``: a model with inputs'
    (tracks, steps, n_u), NumPy only.

    NumPy inputs: the tracks are split into contiguous slices (``workers`` of them, or
    :data:`SLICES_PER_WORKER` times as many for a large batch) run by ``workers`` threads
    (default: the usable cores); returns ``xs`` (tracks, steps, n) and, for a filter
    with P0, ``(xs, Ps)`` with Ps (tracks, steps, n, n) or None when ``with_covariance``
    is False. A Dask ``zs`` (chunked along the track axis; ``x0s``, ``P0s`` NumPy or Dask)
    returns the same as lazy Dask arrays, one task per chunk of tracks; ``workers`` is
    then Dask's business (its scheduler) and must be None.

    ``out`` (NumPy inputs only): the arrays to write the result into and return, instead
    of new ones: ``xs``, or ``(xs, Ps)`` for a filter with P0 (Ps None when
    ``with_covariance`` is False), of the kernel's dtype, C-contiguous. New outputs cost
    a page fault per page on their first writing (as much as the filter's own work for
    small models); a caller filtering batch after batch passes the same ``out`` again.

    Each track's result is bitwise its own ``run``'s, however the tracks are split.
    A failed check raises the wrapper's NumericalError or PatternError, naming the slice
    of tracks it came from."""
    if _is_dask(zs) or _is_dask(x0s) or _is_dask(P0s):
        if workers is not None:
            raise ModelError("batch run_tracks: workers= is for NumPy inputs; with Dask "
                             "arrays the scheduler (e.g. a distributed Client) decides")
        if out is not None:
            raise ModelError("batch run_tracks: out= is for NumPy inputs; Dask arrays give "
                             "lazy results (store them with e.g. to_zarr)")
        if not _is_dask(zs):
            raise ModelError("batch run_tracks: Dask inputs need zs as a Dask array "
                             "chunked along the track axis")
        if us is not None:
            raise ModelError("batch run_tracks: us= is for NumPy inputs")
        return _run_dask(as_kernel(kernel), zs, x0s, P0s, p, with_covariance)
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
            else (os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ModelError(f"batch run_tracks: workers must be an integer >= 1, got {workers!r}")
    module = _module(kernel)
    # arrays of the kernel's dtype (float32 for --precision float; float64 refused there)
    zs = module.converted("run_tracks", "zs", zs)
    x0s = module.converted("run_tracks", "x0s", x0s)
    P0s = None if P0s is None else module.converted("run_tracks", "P0s", P0s)
    us = None if us is None else module.converted("run_tracks", "us", us)
    layout = _check(module, zs.shape, x0s.shape, None if P0s is None else P0s.shape, p)
    tracks, steps, n = layout.tracks, layout.steps, layout.n
    if out is not None:
        xs, Ps = _checked_out(module, out, layout, P0s is not None, with_covariance,
                              {"zs": zs, "x0s": x0s, "P0s": P0s,
                               "p": None if p is None else np.asarray(p)})
    else:   # aligned (module.empty): the threads' slices (TRACK_MULTIPLE) share no line
        xs = module.empty((tracks, steps, n))
        Ps = (module.empty((tracks, steps, n, n))
              if P0s is not None and with_covariance else None)

    def one(start: int, stop: int) -> None:
        try:
            module.run_tracks(zs[start:stop], _slice(x0s, layout.x0_shared, start, stop),
                              _slice(P0s, layout.P0_shared, start, stop), p, with_covariance,
                              out=(xs[start:stop], None if Ps is None else Ps[start:stop]),
                              us=None if us is None else us[start:stop])
        except (NumericalError, PatternError) as exc:
            note = f" (its track numbers count from {start})" if "(track " in str(exc) else ""
            raise type(exc)(f"tracks {start} to {stop - 1}{note}: {exc}") from None

    many = workers * SLICES_PER_WORKER
    slices = split(tracks, many if tracks >= many * TRACK_MULTIPLE else workers,
                   TRACK_MULTIPLE)
    if len(slices) == 1:
        one(*slices[0])
    elif slices:
        with ThreadPoolExecutor(max_workers=min(workers, len(slices))) as pool:
            for future in [pool.submit(one, a, b) for a, b in slices]:
                future.result()
    return xs if P0s is None else (xs, Ps)


def _dask_block(zs, x0s, P0s=None, *, kernel: Kernel, x0_shared, P0_shared, p,
                with_covariance: bool):
    """One chunk of tracks on a Dask worker: the kernel loaded once per worker process;
    xs and the flattened Ps side by side along the last axis."""
    module = kernel.load()
    tracks = zs.shape[0]
    x0s = np.broadcast_to(x0_shared, (tracks,) + x0_shared.shape) if x0s is None else x0s
    if P0_shared is not None:
        P0s = np.broadcast_to(P0_shared, (tracks,) + P0_shared.shape)
    result = module.run_tracks(zs, x0s, P0s, p, with_covariance)
    if P0s is None:
        return result
    xs, Ps = result
    if Ps is None:
        return xs
    # the width spelled out: -1 cannot be inferred for a chunk of 0 tracks
    width = int(np.prod(Ps.shape[2:]))
    return np.concatenate([xs, Ps.reshape(xs.shape[:2] + (width,))], axis=2)


def _run_dask(kernel: Kernel, zs, x0s, P0s, p, with_covariance: bool):
    import dask.array as da

    module = kernel.load()
    layout = _check(module, zs.shape, np.shape(x0s), None if P0s is None else np.shape(P0s),
                    p)
    n, steps = layout.n, layout.steps
    # the kernel's element type, as the thread path (float32 for --precision float): a
    # wider float is refused here with DtypeError naming the argument, before any task

    def element(name: str, array) -> np.dtype:
        """The kernel's dtype, once the Dask ``array``'s has been checked against it."""
        return module.converted("run_tracks", name, np.empty(0, array.dtype)).dtype

    zs = zs.rechunk({axis: -1 for axis in range(1, zs.ndim)}).astype(element("zs", zs))
    track_chunks = zs.chunks[0]

    def aligned(array, name: str):
        """A per-track array chunked as zs along the tracks, whole along the rest."""
        chunks = (track_chunks,) + tuple((d,) for d in np.shape(array)[1:])
        if not _is_dask(array):
            return da.from_array(module.converted("run_tracks", name, array), chunks=chunks)
        return array.astype(element(name, array)).rechunk(chunks)

    def shared(array, name: str):
        return None if array is None else module.converted("run_tracks", name, array)

    letters = "tsm"[:zs.ndim]
    args = [zs, letters]
    args += ([None, None] if layout.x0_shared
             else [aligned(x0s, "x0s"), "t" + "abc"[:np.ndim(x0s) - 1]])
    stored = P0s is not None and with_covariance
    if P0s is not None:
        args += [None, None] if layout.P0_shared else [aligned(P0s, "P0s"),
                                                       "t" + "ij"[:np.ndim(P0s) - 1]]
    width = n + n * n if stored else n
    out = da.blockwise(
        _dask_block, "tsk", *args, new_axes={"k": width}, concatenate=True,
        dtype=module.dtype, meta=module.empty((0, 0, 0)), kernel=kernel,
        x0_shared=shared(x0s, "x0s") if layout.x0_shared else None,
        P0_shared=shared(P0s, "P0s") if layout.P0_shared else None,
        p=shared(p, "p"), with_covariance=with_covariance)
    if P0s is None:
        return out
    if not stored:
        return out, None
    return out[:, :, :n], out[:, :, n:].reshape(layout.tracks, steps, n, n)
