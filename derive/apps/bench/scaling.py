"""Batch throughput on every core: derive.batch.run_tracks over a large track set
(default 1,000,000 tracks x 100 steps of mpt3d_b's KF, no covariances stored), split
across 1 and 2 threads, and as Dask arrays through a ``distributed.LocalCluster`` of 1
and 2 worker processes; every result is checked bitwise against the threaded one.

The measurements are in track-steps per second. The Dask input is simulated on the
workers, chunk by chunk (the same chunks as the NumPy input, so the same bits), and
kept there (``persist``); the timed part is the filter: ``run_tracks(...).persist()``
until every chunk is done, the result staying on the workers as a larger-than-memory
pipeline would keep it. The comparison gathers it afterwards, untimed."""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import batch as derive_batch
from .batch import MODEL, make_batch
from .cases import Case, Skip
from .generated import CFLAGS, load
from .timing import measure

TRACKS = 1_000_000
STEPS = 100
CHUNK = 50_000
"""Tracks per chunk of the simulated input (and per Dask task)."""
WORKERS = (1, 2)
THREADS_BAR = 6e8
"""Track-steps per second the batch reaches on both cores (docs/performance.md)."""
_RUNS = itertools.count()   # names the input of each Dask run (see _dask_rows)


@dataclass(frozen=True)
class ScaleRow:
    implementation: str           # "threads" or "Dask LocalCluster"
    workers: int
    track_steps_per_second: float | None
    seconds: float | None
    bitwise: bool | None          # equal, bit for bit, to the threaded result
    note: str = ""


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
    for workers in WORKERS:
        tick(f"scaling: threads, {workers} worker(s)")

        def run(workers=workers, zs=zs):
            return derive_batch.run_tracks(kernel, zs, x0, P0, workers=workers,
                                           with_covariance=False)[0]
        out = run()
        reference = out if reference is None else reference
        timing = measure(run, 1, repeats)
        rows.append(ScaleRow("threads", workers, tracks * steps / timing.median,
                             timing.median, bool(np.array_equal(out, reference))))
        del out, run
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
    head = ("implementation", "workers", "track-steps/s", "time per run", "bitwise", "note")
    body = [(r.implementation, str(r.workers),
             "skipped" if r.track_steps_per_second is None else
             f"{r.track_steps_per_second:,.3g}",
             "" if r.seconds is None else f"{r.seconds:.3g} s",
             "" if r.bitwise is None else ("yes" if r.bitwise else "NO"), r.note)
            for r in rows]
    scaling = []
    for name in dict.fromkeys(r.implementation for r in rows):
        speed = {r.workers: r.track_steps_per_second for r in rows
                 if r.implementation == name}
        if speed.get(1) and speed.get(2):
            scaling.append(f"scaling of {name} from 1 to 2 workers: "
                           f"{speed[2] / speed[1]:.2f}x")
    both = next((r.track_steps_per_second for r in rows if r.implementation == "threads"
                 and r.workers == max(WORKERS) and r.track_steps_per_second), None)
    if both is not None:
        scaling.append(f"bar: batch {MODEL} KF, covariances not stored, "
                       f"{max(WORKERS)} threads: {both:,.3g} track-steps/s (>= "
                       f"{THREADS_BAR:.3g}: {'met' if both >= THREADS_BAR else 'NOT met'})")
    return head, body, scaling
