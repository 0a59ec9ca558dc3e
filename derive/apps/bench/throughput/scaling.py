"""Batch throughput on every core: derive.batch.run_tracks over a large track set
(default 1,000,000 tracks x 100 steps of mpt3d_b's KF, no covariances stored), split
across 1 and 2 threads, and as Dask arrays through a ``distributed.LocalCluster`` of 1
and 2 worker processes; every result is checked bitwise against the threaded one.

Beside each threaded row, the limits of this machine measured in the same run: the
memory-traffic bound (the copy bandwidth of as many threads, each copying its own
array, over the 24 bytes a track-step reads and writes) and the compute ceiling (as many
threads each filtering its own tracks over and over, few enough to stay in its core's
cache). The threaded rows write into outputs passed again and again (``out=``), as a
caller filtering batch after batch would; the note gives the rate into new outputs
(their first writing costs a page fault a page).

The measurements are in track-steps per second. The Dask input is simulated on the
workers, chunk by chunk (the same chunks as the NumPy input, so the same bits), and
kept there (``persist``); the timed part is the filter: ``run_tracks(...).persist()``
until every chunk is done, the result staying on the workers as a larger-than-memory
pipeline would keep it. The comparison gathers it afterwards, untimed."""

from __future__ import annotations

import itertools
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .... import batch as derive_batch
from ....build import FilterModule
from ....errors import NumericalError
from ..bars import BARS
from ..cases import Case, Skip
from ..generated import CFLAGS, load
from ..timing import measure
from .batch import MODEL, copy_bandwidth, make_batch, track_step_bytes

TRACKS = 1_000_000
STEPS = 100
CHUNK = 50_000
"""Tracks per chunk of the simulated input (and per Dask task)."""
WORKERS = (1, 2)
THREADS_BAR = BARS["batch_both_cores"]
"""Track-steps per second the batch reaches on both cores (docs/performance.md)."""
_RUNS = itertools.count()   # names the input of each Dask run (see _dask_rows)
IN_CACHE_BYTES = 512 * 1024
"""Bytes of one thread's tracks (z read, x written) for the compute ceiling: within a
core's L2 (1 MB on the development machine)."""
CEILING_TRACK_STEPS = 20_000_000
"""Track-steps each thread filters in one round of the compute ceiling."""


@dataclass(frozen=True)
class Limits:
    """What this machine allows the batch on ``threads`` cores, measured in the same run."""

    threads: int
    copy_bandwidth: float         # bytes per second, one NumPy copy per thread
    track_step_bytes: int         # bytes a track-step reads and writes
    memory: float                 # track-steps per second: copy_bandwidth / track_step_bytes
    compute: float                # track-steps per second, every thread in its own cache


@dataclass(frozen=True)
class ScaleRow:
    implementation: str           # "threads" or "Dask LocalCluster"
    workers: int
    track_steps_per_second: float | None
    seconds: float | None
    bitwise: bool | None          # equal, bit for bit, to the threaded result
    note: str = ""
    limits: Limits | None = None  # the threaded rows: this machine's limits, same run
    new_outputs: float | None = None   # threaded rows: track-steps/s into fresh outputs


def compute_ceiling(module: FilterModule, x0, P0, steps: int, threads: int, repeats: int,
                    work: int = CEILING_TRACK_STEPS) -> float:
    """Track-steps per second of the C run_tracks (called directly, no covariances
    stored) with ``threads`` threads each filtering its own tracks ``work`` track-steps
    a round, the fewest whole blocks of 64 tracks whose z and x fit IN_CACHE_BYTES: the
    step's rate on that many cores without memory traffic (best of ``repeats`` rounds)."""
    m = make_batch(1, 1).zs.shape[2]
    n = len(x0)
    per_track = steps * (m + n) * module.dtype.itemsize
    tracks = max(64, IN_CACHE_BYTES // per_track // 64 * 64)
    calls = max(1, work // (tracks * steps))
    run_tracks = getattr(module.lib, f"{module.prefix}_run_tracks")
    jobs = []
    for seed in range(threads):
        arrays = [np.random.default_rng(seed).standard_normal((tracks, steps, m)),
                  np.repeat(np.asarray(x0, float)[None], tracks, axis=0),
                  np.repeat(np.asarray(P0, float)[None], tracks, axis=0),
                  np.zeros((tracks, steps, n))]
        jobs.append((arrays, [steps, tracks] + [module.buffer(a) for a in arrays]
                     + [module.ffi.NULL]))

    def filter_again(job) -> None:
        for _ in range(calls):
            if run_tracks(*job[1]):
                raise NumericalError(f"{module.prefix}_run_tracks failed on the "
                                     "compute ceiling's tracks")
    best = float("inf")
    with ThreadPoolExecutor(max_workers=threads) as pool:
        list(pool.map(filter_again, jobs))            # warm: caches, pages, clocks
        for _ in range(repeats):
            start = time.perf_counter()
            list(pool.map(filter_again, jobs))
            best = min(best, time.perf_counter() - start)
    return threads * calls * tracks * steps / best


def machine_limits(module: FilterModule, x0, P0, steps: int, threads: int,
                   repeats: int) -> Limits:
    """This machine's memory-traffic bound and compute ceiling on ``threads`` cores."""
    bandwidth = copy_bandwidth(repeats=repeats, threads=threads)
    per = track_step_bytes(make_batch(1, 1), with_covariance=False)
    return Limits(threads, bandwidth, per, bandwidth / per,
                  compute_ceiling(module, x0, P0, steps, threads, repeats))


def simulated_chunk(start: int, stop: int, steps: int, seed: int = 5) -> np.ndarray:
    """Measurements (stop - start, steps, m) of tracks [start, stop): the same bits
    wherever they are made (the chunk's own random stream)."""
    return make_batch(stop - start, steps, seed=[seed, start]).zs


def chunks(tracks: int, size: int = CHUNK) -> list[tuple[int, int]]:
    return [(a, min(a + size, tracks)) for a in range(0, tracks, size)]


def scaling_rows(tracks: int, steps: int, workdir: Path, repeats: int, tick=lambda text: None,
                 chunk: int = CHUNK) -> list[ScaleRow]:
    """Threads then Dask, each with 1 and 2 workers, on the same simulated tracks made
    ``chunk`` tracks at a time."""
    kernel = derive_batch.Kernel(str(load(Case("kf", MODEL), workdir, "c").paths[".c"]),
                                 CFLAGS)
    start = make_batch(1, 1)
    x0, P0 = start.x0, start.P0
    bounds = chunks(tracks, chunk)
    tick(f"scaling: simulating {tracks:,} tracks x {steps} steps")
    zs = np.concatenate([simulated_chunk(a, b, steps) for a, b in bounds])
    rows, reference = [], None
    module = kernel.load()
    for workers in WORKERS:
        tick(f"scaling: this machine's limits on {workers} core(s)")
        limits = machine_limits(module, x0, P0, steps, workers, repeats)
        tick(f"scaling: threads, {workers} worker(s)")

        def fresh(workers=workers, zs=zs):
            return derive_batch.run_tracks(kernel, zs, x0, P0, workers=workers,
                                           with_covariance=False)[0]
        out = fresh()
        reference = out if reference is None else reference
        same = bool(np.array_equal(out, reference))
        new_outputs = measure(fresh, 1, repeats)

        def again(workers=workers, zs=zs, out=out):
            return derive_batch.run_tracks(kernel, zs, x0, P0, workers=workers,
                                           with_covariance=False, out=(out, None))[0]
        timing = measure(again, 1, repeats)
        same = same and bool(np.array_equal(out, reference))
        rows.append(ScaleRow("threads", workers, tracks * steps / timing.median,
                             timing.median, same,
                             f"outputs reused (out=); into new outputs "
                             f"{tracks * steps / new_outputs.median:,.3g}", limits,
                             tracks * steps / new_outputs.median))
        del out, fresh, again
    del zs   # the Dask rows make their input on the workers
    try:
        rows += _dask_rows(kernel, x0, P0, bounds, steps, reference, repeats, tick)
    except Skip as exc:
        rows += [ScaleRow("Dask LocalCluster", w, None, None, None, f"skipped: {exc}")
                 for w in WORKERS]
    return rows


def _dask_rows(kernel, x0, P0, bounds, steps, reference, repeats, tick) -> list[ScaleRow]:
    try:
        import dask
        import dask.array as da
        from distributed import Client, LocalCluster, wait
    except ImportError:
        raise Skip("dask[array] and distributed are not installed (the [dask] extra)"
                   ) from None
    tracks, m = reference.shape[0], make_batch(1, 1).zs.shape[2]
    rows = []
    for workers in WORKERS:
        tick(f"scaling: Dask LocalCluster, {workers} worker(s)")
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            client.run(kernel.preload)
            zs = da.concatenate([
                da.from_delayed(dask.delayed(simulated_chunk)(a, b, steps),
                                shape=(b - a, steps, m), dtype=np.float64)
                for a, b in bounds]).persist()
            wait(zs)

            def filtered(zs=zs):
                """The filtered states, under keys of their own: the same graph again
                would have the same keys, which the scheduler hands back at once (the
                input passes through np.asarray, which returns the chunk itself)."""
                own = zs.map_blocks(np.asarray, dtype=np.float64,
                                    name=f"scaling-zs-{next(_RUNS)}")
                return derive_batch.run_tracks(kernel, own, x0, P0, with_covariance=False)[0]

            def run(client=client):
                """The filter on every chunk, kept on the workers until done, then
                released."""
                xs = filtered().persist()
                wait(xs)
                client.cancel(xs)
            same = bool(np.array_equal(filtered().compute(), reference))
            timing = measure(run, 1, repeats)
            del zs
        rows.append(ScaleRow("Dask LocalCluster", workers, tracks * steps / timing.median,
                             timing.median, same))
    return rows


def scaling_table(rows: list[ScaleRow]) -> tuple[tuple[str, ...], list[tuple[str, ...]],
                                                 list[str]]:
    """The table's head and body, and the 1 -> 2 worker scaling of each implementation."""
    head = ("implementation", "workers", "track-steps/s", "time per run", "bitwise",
            "this machine's limits, same run", "note")
    body = [(r.implementation, str(r.workers),
             "skipped" if r.track_steps_per_second is None else
             f"{r.track_steps_per_second:,.3g}",
             "" if r.seconds is None else f"{r.seconds:.3g} s",
             "" if r.bitwise is None else ("yes" if r.bitwise else "NO"),
             "" if r.limits is None else limits_text(r.limits), r.note)
            for r in rows]
    scaling = []
    for name in dict.fromkeys(r.implementation for r in rows):
        speed = {r.workers: r.track_steps_per_second for r in rows
                 if r.implementation == name}
        if speed.get(1) and speed.get(2):
            scaling.append(f"scaling of {name} from 1 to 2 workers: "
                           f"{speed[2] / speed[1]:.2f}x")
    both = next((r for r in rows if r.implementation == "threads"
                 and r.workers == max(WORKERS) and r.track_steps_per_second), None)
    if both is not None:
        speed = both.track_steps_per_second
        line = (f"bar: batch {MODEL} KF, covariances not stored, {max(WORKERS)} threads, "
                f"into outputs reused (out=): {speed:,.3g} track-steps/s "
                f"(>= {THREADS_BAR:.3g}: {'met' if speed >= THREADS_BAR else 'NOT met'})")
        if both.new_outputs is not None:
            line += (f"; into new outputs each call {both.new_outputs:,.3g} (first writes "
                     f"fault their pages in)")
        if both.limits is not None:
            limit = min(both.limits.memory, both.limits.compute)
            line += (f"; this machine's limits in this run: {limits_text(both.limits)}; "
                     f"the figure is {speed / limit:.0%} of the lower")
        scaling.append(line)
    return head, body, scaling


def limits_text(limits: Limits) -> str:
    """The two limits of a threaded row, each with what it was measured from."""
    return (f"memory traffic {limits.memory:,.3g} ({limits.threads}-thread copy "
            f"{limits.copy_bandwidth / 1e9:.1f} GB/s / {limits.track_step_bytes} B); compute "
            f"{limits.compute:,.3g} ({limits.threads} thread(s) in cache)")
