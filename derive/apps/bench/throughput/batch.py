"""Batch throughput: many independent tracks of one small model (mpt3d_b's KF), in
track-steps per second, for derive's generated C (a C loop over tracks calling the
generated run), derive's generated Python on NumPy arrays (one array op per scalar
operation, all tracks at once), simdkalman and a vectorised NumPy KF written here."""

from __future__ import annotations

import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .... import catalog, reference
from ....system_checks import psd_sqrt
from ..cases import Case, Skip
from ..generated import CFLAGS, load

MODEL = "mpt3d_b"
TRACKS = 10_000
STEPS = 100


@dataclass
class Batch:
    """zs: (tracks, steps, m); x0, P0: the model's start, the same for every track."""

    zs: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    F: np.ndarray
    H: np.ndarray
    W: np.ndarray   # G Q Gᵀ
    R: np.ndarray

    @property
    def track_steps(self) -> int:
        return self.zs.shape[0] * self.zs.shape[1]


def make_batch(tracks: int = TRACKS, steps: int = STEPS, seed: int = 5) -> Batch:
    """Tracks simulated from the model, all at once."""
    num = catalog.load(MODEL).numeric()
    F, G, H, Q, R = (np.asarray(getattr(num, k), float) for k in ("F", "G", "H", "Q", "R"))
    rng = np.random.default_rng(seed)
    m = H.shape[0]
    x = np.tile(np.asarray(num.x0, float), (tracks, 1))
    zs = np.empty((tracks, steps, m))
    for k in range(steps):
        x = x @ F.T + rng.standard_normal((tracks, Q.shape[0])) @ psd_sqrt(Q) @ G.T
        zs[:, k] = x @ H.T + rng.standard_normal((tracks, m)) @ psd_sqrt(R)
    return Batch(zs, np.asarray(num.x0, float), np.asarray(num.P0, float), F, H, G @ Q @ G.T,
                 R)


def batch_reference(b: Batch, track: int) -> np.ndarray:
    """derive's NumPy reference KF on one track (states (steps, n))."""
    G = np.eye(b.F.shape[0])        # W = G Q Gᵀ is passed as Q with G = I
    return reference.kf(b.F, G, b.H, b.W, b.R, b.x0, b.P0, b.zs[track])[0]


def numpy_kf(b: Batch) -> np.ndarray:
    """A vectorised NumPy KF over all tracks: states (tracks, steps, n)."""
    tracks, steps, _ = b.zs.shape
    n = b.F.shape[0]
    x = np.tile(b.x0, (tracks, 1))
    P = np.tile(b.P0, (tracks, 1, 1))
    out = np.empty((tracks, steps, n))
    eye = np.eye(n)
    for k in range(steps):
        x = x @ b.F.T
        P = b.F @ P @ b.F.T + b.W
        PHt = P @ b.H.T
        S = b.H @ PHt + b.R
        K = np.linalg.solve(S, PHt.transpose(0, 2, 1)).transpose(0, 2, 1)
        x = x + (K @ (b.zs[:, k, :, None] - b.H @ x[:, :, None]))[:, :, 0]
        P = (eye - K @ b.H) @ P
        out[:, k] = x
    return out


def simdkalman_kf(b: Batch):
    """simdkalman's filter (its first measurement observes its initial state, so it starts
    from x(1/0) = F x0, P(1/0) = F P0 Fᵀ + G Q Gᵀ)."""
    try:
        import simdkalman
    except ImportError:
        raise Skip("simdkalman is not installed") from None
    kf = simdkalman.KalmanFilter(b.F, b.W, b.H, b.R)
    data = b.zs[:, :, 0] if b.zs.shape[2] == 1 else b.zs

    def run():
        result = kf.compute(data, 0, initial_value=b.F @ b.x0,
                            initial_covariance=b.F @ b.P0 @ b.F.T + b.W, smoothed=False,
                            filtered=True, covariances=False, observations=False)
        return result.filtered.states.mean
    return run


def generated_python(b: Batch, workdir: Path):
    """The generated Python run with a trailing track axis."""
    module = load(Case("kf", MODEL), workdir, "python").python
    zs = np.ascontiguousarray(b.zs.transpose(1, 2, 0))          # (steps, m, tracks)
    tracks = b.zs.shape[0]
    x0 = np.repeat(b.x0[:, None], tracks, axis=1)
    P0 = np.repeat(b.P0[:, :, None], tracks, axis=2)
    return lambda: np.asarray(module.run(zs, x0, P0)[0]).transpose(2, 0, 1)


def generated_c_tracks(b: Batch, workdir: Path, with_covariance: bool = False):
    """The generated ``run_tracks``: blocks of tracks in vector lanes, each track's arrays
    contiguous (by default no covariance output, like the other batch rows), writing into
    outputs allocated once (as the C driver's), not new pages each call."""
    module = load(Case("kf", MODEL), workdir, "c").c
    tracks, steps, _ = b.zs.shape
    n = len(b.x0)
    zs = np.ascontiguousarray(b.zs)                               # (tracks, steps, m)
    x0 = np.ascontiguousarray(np.repeat(b.x0[None, :], tracks, axis=0))
    P0 = np.ascontiguousarray(np.repeat(b.P0[None, :, :], tracks, axis=0))
    out = (np.empty((tracks, steps, n)),
           np.empty((tracks, steps, n, n)) if with_covariance else None)
    return lambda: module.run_tracks(zs, x0, P0, with_covariance=with_covariance,
                                     out=out)[0]


def track_step_bytes(b: Batch, with_covariance: bool) -> int:
    """Bytes a track-step moves to or from memory: its z row read, its x (and P) row
    written, doubles."""
    m, n = b.zs.shape[2], len(b.x0)
    return 8 * (m + n + (n * n if with_covariance else 0))


def copy_bandwidth(megabytes: int = 256, repeats: int = 3, threads: int = 1) -> float:
    """This machine's memory bandwidth in bytes per second: the best of ``repeats`` rounds
    of ``threads`` threads each copying its own ``megabytes`` array (NumPy releases the GIL
    while it copies), bytes read plus bytes written by all of them over the round's time."""
    sources = [np.ones(megabytes * 2**20 // 8) for _ in range(threads)]
    targets = [np.empty_like(src) for src in sources]
    for target, src in zip(targets, sources):       # every page touched before the timing
        np.copyto(target, src)
    best = float("inf")
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(np.copyto, targets, sources))
            best = min(best, time.perf_counter() - start)
    return 2 * threads * sources[0].nbytes / best


INTERLEAVE = 4
"""Tracks whose steps the interleaved driver alternates (independent dependency chains for
the CPU to overlap; 4 was fastest of 1, 2, 4, 8, 16, 32 on the development machine)."""

_DRIVER = """\
#include <stddef.h>
#include "kf.h"
#define N {n}
#define M {m}
#define B {interleave}

/* One generated run per track: each step waits for the previous one of its track. */
void batch_run(size_t tracks, size_t steps, const double *z, const double *x0,
               const double *P0, double *xs, int *status)
{{
    size_t t;
    for (t = 0; t < tracks; ++t)
        status[t] = {prefix}_run(steps, z + t * steps * M, x0, P0, xs + t * steps * N, NULL);
}}

/* The generated step, B tracks at a time, their steps interleaved. */
void batch_step(size_t tracks, size_t steps, const double *z, const double *x0,
                const double *P0, double *xs, int *status)
{{
    double P_work[2][B][N * N];
    const double *x[B];
    const double *P[B];
    size_t t0, k, b;
    for (t0 = 0; t0 < tracks; t0 += B) {{
        size_t nb = tracks - t0 < B ? tracks - t0 : B;
        for (b = 0; b < nb; ++b) {{
            x[b] = x0;
            P[b] = P0;
            status[t0 + b] = 0;
        }}
        for (k = 0; k < steps; ++k) {{
            for (b = 0; b < nb; ++b) {{
                size_t t = t0 + b;
                double *x_next = xs + (t * steps + k) * N;
                double *P_next = P_work[k % 2][b];
                int s = {prefix}_step(x[b], P[b], z + (t * steps + k) * M, x_next, P_next);
                if (s)
                    status[t] = s;
                x[b] = x_next;
                P[b] = P_next;
            }}
        }}
    }}
}}
"""
LTO = ("-flto",)


def generated_c(b: Batch, workdir: Path, entry: str = "batch_step"):
    """The generated C called from a C loop over the tracks: ``batch_run`` (the generated
    run per track) or ``batch_step`` (the generated step, INTERLEAVE tracks at a time).
    Compiled with CFLAGS and link-time optimisation, so the step can be inlined."""
    import cffi

    paths = load(Case("kf", MODEL), workdir, "c").paths
    folder = paths[".c"].parent
    tracks, steps, m = b.zs.shape
    n = len(b.x0)
    (folder / "batch.c").write_text(_DRIVER.format(prefix=f"{MODEL}_kf", m=m, n=n,
                                                   interleave=INTERLEAVE))
    library = folder / "libbatch.so"
    if not library.exists():
        cmd = ["gcc", "-std=c99", *CFLAGS, *LTO, "-shared", "-fPIC", "-I", str(folder), "-o",
               str(library), str(paths[".c"]), str(folder / "batch.c"), "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise Skip(f"gcc failed on the batch driver: {proc.stderr.strip()}")
    ffi = cffi.FFI()
    ffi.cdef("".join(f"void {name}(size_t tracks, size_t steps, const double *z, "
                     "const double *x0, const double *P0, double *xs, int *status);"
                     for name in ("batch_run", "batch_step")))
    lib = ffi.dlopen(str(library))
    zs = np.ascontiguousarray(b.zs)
    x0, P0 = np.ascontiguousarray(b.x0), np.ascontiguousarray(b.P0)
    out = np.empty((tracks, steps, n))          # allocated once, like any C caller would
    status = np.zeros(tracks, dtype=np.intc)
    args = [ffi.from_buffer("double[]", a) for a in (zs, x0, P0, out)]
    status_buffer = ffi.from_buffer("int[]", status)
    call = getattr(lib, entry)

    def run():
        call(tracks, steps, *args, status_buffer)
        if status.any():
            raise ArithmeticError(f"{int((status != 0).sum())} track(s) failed")
        return out
    return run
