"""Independent work beside the caller, in a forked process, while a core is free.

Rendering a derived filter's Python and its C are independent of each other and of the
next filter's derivation; each takes seconds on a large model. :class:`Job` runs one
such function in a child forked from this process (it sees every object the caller has,
nothing is sent to it) and brings its result back through a pipe, pickled; the caller
goes on meanwhile. When no core is free (see :func:`spare_cores`), fork is not
available or not safe here, or the caller is itself such a child, the function runs in
the caller, at once: the result is the same either way, bit for bit, since the child
computes it from the same objects with the same code.

``DERIVE_JOBS`` caps the processes busy at once (the caller counts as one): ``1`` runs
everything in the caller. By default the cap is the number of cores this process may
run on.
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

_ENVIRONMENT = "DERIVE_JOBS"

#: True in a child: it runs its own work in itself.
_in_child = False
#: The jobs whose child runs or has a result not yet read, by the child's process id.
_running: dict[int, Job] = {}


def spare_cores() -> int:
    """How many more processes may be busy beside this one now: the cap (``DERIVE_JOBS``,
    default the cores this process may run on) less one for this process and one for each
    child still running; 0 where fork is unsafe (not Linux, other threads running, or in
    a child)."""
    if _in_child or not sys.platform.startswith("linux") or threading.active_count() > 1:
        return 0
    setting = os.environ.get(_ENVIRONMENT, "").strip()
    try:
        cap = int(setting) if setting else len(os.sched_getaffinity(0))
    except ValueError:
        cap = 1
    if cap - 1 - len(_running) <= 0:
        _collect_finished()
    return max(0, cap - 1 - len(_running))


def _collect_finished() -> None:
    """Read the results of the children that have finished: a child writes its result
    only once it is computed, so a pipe with data to read (or at its end) is one whose
    child no longer needs a core. Their jobs keep the results for :meth:`Job.result`."""
    pipes = {job._read: job for job in _running.values() if job._read is not None}
    if pipes:
        ready, _, _ = select.select(list(pipes), [], [], 0)
        for fd in ready:
            job = pipes[fd]
            job._outcome = job._collect()


class Job:
    """``function(*args)``, in a forked child if a core is spare (:func:`spare_cores`),
    else here and now; :meth:`result` returns its value or raises what it raised.
    ``background`` False runs it here in any case: work of well under a second, for which
    a fork (several milliseconds of a large process) and the trip through the pipe cost
    about what running it beside the caller saves."""

    def __init__(self, function: Callable[..., Any], *args: Any, background: bool = True
                 ) -> None:
        self._pid: int | None = None
        self._read: int | None = None
        self._outcome: tuple[bool, Any] | None = None
        if background and spare_cores() > 0:
            self._start(function, args)
        else:
            self._outcome = _call(function, args)

    @property
    def in_background(self) -> bool:
        """Whether the work runs (or ran) in a child."""
        return self._pid is not None

    def _start(self, function: Callable[..., Any], args: tuple) -> None:
        read, write = os.pipe()
        for stream in (sys.stdout, sys.stderr):   # what the caller buffered is printed once
            stream.flush()
        pid = os.fork()
        if pid == 0:    # the child: compute, send, leave without running the caller's exits
            global _in_child
            _in_child = True
            status = 1
            try:
                os.close(read)
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller handles Ctrl-C
                data = _pickled(_call(function, args))
                with os.fdopen(write, "wb") as pipe:
                    pipe.write(data)
                status = 0
            finally:
                os._exit(status)
        os.close(write)
        self._pid, self._read = pid, read
        _running[pid] = self

    def result(self) -> Any:
        """The function's value (waiting for the child if it still runs), or its exception
        raised again."""
        if self._outcome is None:
            self._outcome = self._collect()
        ok, value = self._outcome
        if ok:
            return value
        raise value

    def _collect(self) -> tuple[bool, Any]:
        assert self._pid is not None and self._read is not None
        read, self._read = self._read, None
        try:
            with os.fdopen(read, "rb") as pipe:
                data = pipe.read()
        except BaseException:    # Ctrl-C while waiting: the child is not waited for
            self._stop()
            raise
        _, status = os.waitpid(self._pid, 0)
        _running.pop(self._pid, None)
        if not data:
            return False, RuntimeError(
                f"a background process of derive ended without a result (wait status "
                f"{status}); DERIVE_JOBS=1 runs everything in one process")
        return pickle.loads(data)

    def cancel(self) -> None:
        """Stop the child if it still runs (nothing to do for work done here)."""
        if self._pid is not None and self._outcome is None:
            if self._read is not None:
                os.close(self._read)
                self._read = None
            self._stop()

    def _stop(self) -> None:
        """Kill the child and reap it (once: its process id may be another's after)."""
        if _running.pop(self._pid, None) is not None:
            os.kill(self._pid, signal.SIGKILL)
            os.waitpid(self._pid, 0)
        self._outcome = (False, RuntimeError("cancelled"))


@contextmanager
def stopped_on_failure(jobs: list[Job]) -> Iterator[list[Job]]:
    """Run the body with ``jobs`` (which it may extend); if it raises (Ctrl-C included),
    the children of those still running are stopped first."""
    try:
        yield jobs
    except BaseException:
        for job in jobs:
            job.cancel()
        raise


def _call(function: Callable[..., Any], args: tuple) -> tuple[bool, Any]:
    try:
        return True, function(*args)
    except Exception as exc:   # raised again by Job.result, in the caller
        return False, exc


def _pickled(outcome: tuple[bool, Any]) -> bytes:
    """The outcome for the pipe; an exception that cannot be pickled goes as a
    RuntimeError with its type and message."""
    try:
        return pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:   # noqa: BLE001 - any failure to pickle: send what can be sent
        ok, value = outcome
        if ok:
            raise
        return pickle.dumps((False, RuntimeError(f"{type(value).__name__}: {value}")))
