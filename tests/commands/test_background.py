"""Work beside the caller (derive.background): a Job runs in a forked child while a core is
spare and gives the caller what the function would have given it here (its value, or its
exception); the generation of a large model renders and derives in children, its files
byte for byte those of one process, and a failure or Ctrl-C there is still one line with
no process left behind. Time limits here guard against hangs only."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from derive import background
from derive.background import Job
from derive.errors import ModelError

ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD = 120    # seconds
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="background processes are forked on Linux only")


# Forking from a pytest worker that other tests have left threads in (a Dask cluster's)
# is what derive.background refuses, so each case runs in a fresh interpreter.
CASES = textwrap.dedent("""\
    import os, select, sys, time
    from derive import background
    from derive.background import Job, spare_cores
    from derive.errors import ModelError

    def child_pid():
        return os.getpid()

    def refuse(message):
        raise ModelError(message)

    class Unpicklable(Exception):
        def __reduce__(self):
            raise TypeError("not picklable")

    def refuse_unpicklable():
        raise Unpicklable("with a lock inside")

    def nested():
        return os.getpid(), Job(child_pid).result()

    def raised(job):
        try:
            job.result()
        except Exception as exc:
            return exc
        raise AssertionError("nothing raised")

    case = sys.argv[1]
    if case == "value":
        job = Job(child_pid)
        assert job.in_background
        assert job.result() not in (os.getpid(), None)
        assert not background._running
    elif case == "exceptions":
        job = Job(refuse, "model 'x': matrix F[1][2] is not finite")
        assert job.in_background
        exc = raised(job)
        assert type(exc) is ModelError and str(exc) == "model 'x': matrix F[1][2] is not finite"
        exc = raised(Job(refuse_unpicklable))
        assert type(exc) is RuntimeError and str(exc) == "Unpicklable: with a lock inside"
    elif case == "nested":
        outer, inner = Job(nested).result()
        assert outer == inner != os.getpid()
    elif case == "cap":
        hold, release = os.pipe()
        first = Job(os.read, hold, 1)      # the child waits until this process writes
        assert first.in_background and spare_cores() == 0
        second = Job(child_pid)            # no core spare: here, at once
        assert not second.in_background and second.result() == os.getpid()
        os.write(release, b"x")
        ready, _, _ = select.select([first._read], [], [], 120)   # its result is written
        assert ready
        assert spare_cores() == 1          # read, so the core is free again
        assert first.result() == b"x"
    elif case == "cancel":
        job = Job(time.sleep, 600)
        pid = job._pid
        job.cancel()
        assert not os.path.exists(f"/proc/{pid}") and not background._running
        assert str(raised(job)) == "cancelled"
    print("passed", case)
""")


@linux_only
@pytest.mark.parametrize("case", ["value", "exceptions", "nested", "cap", "cancel"])
def test_a_job_in_a_child(case):
    """value: a job runs in a child and returns its value; exceptions: what the child
    raised is raised here (one that does not pickle as a RuntimeError with its type and
    message); nested: a child runs its own jobs in itself; cap: the cap counts the
    children, and a finished one's core is free once its result is read; cancel: a
    cancelled child is gone."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DERIVE_JOBS": "2"}
    done = subprocess.run([sys.executable, "-c", CASES, case], env=env, capture_output=True,
                          text=True, timeout=HANG_GUARD)
    assert done.returncode == 0 and done.stdout.split() == ["passed", case], done.stderr


@pytest.fixture
def two_jobs(monkeypatch):
    """A cap of two busy processes whatever the cores of the machine."""
    monkeypatch.setenv("DERIVE_JOBS", "2")
    assert not background._running


def _child_pid() -> int:
    return os.getpid()


@pytest.mark.parametrize("setting", ["1", "0", "many"])
def test_one_process_when_the_cap_says_so(monkeypatch, setting):
    monkeypatch.setenv("DERIVE_JOBS", setting)
    job = Job(_child_pid)
    assert not job.in_background and job.result() == os.getpid()


def test_no_fork_while_another_thread_runs(two_jobs):
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        job = Job(_child_pid)
        assert not job.in_background and job.result() == os.getpid()
    finally:
        stop.set()
        other.join()


def test_work_marked_small_runs_here(two_jobs):
    job = Job(_child_pid, background=False)
    assert not job.in_background and job.result() == os.getpid()
    assert pickle.loads(pickle.dumps(ModelError("x"))).args == ("x",)


# -- the command line: a large model's renderings in a child -------------------------------

MODEL_FILE = textwrap.dedent("""\
    [model]
    name = "wide"
    states = ["a", "b", "c"]
    measurements = ["z"]
    [nonlinear]
    f = ["a + b", "b + c", "c"]
    h = ["sin(a) * cos(b) + c"]
    Q = [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]
    R = [[0.1]]
    [initial]
    x0 = [0.1, 0.2, 0.3]
    P0 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
""")

# every unit counts as large, so the first rendering goes to a child; ``render_python``
# replaced there by what the test asks for
SCRIPT = textwrap.dedent("""\
    import os, sys, time
    import derive.generation as generation
    from derive.errors import ModelError
    parent = os.getpid()
    mode = sys.argv[1]
    generation.BACKGROUND_STATEMENTS = 0
    real = generation.render_python
    def replaced(unit):
        if os.getpid() == parent:
            raise SystemExit("render_python ran in the parent")
        if mode == "fail":
            raise ModelError(f"injected failure in process {os.getpid()}")
        if mode == "hang":
            time.sleep(600)
        return real(unit)
    generation.render_python = replaced
    from derive.cli import main
    sys.exit(main(sys.argv[2:]))
""")


@pytest.fixture
def wide(tmp_path) -> Path:
    """A folder with the model file wide.toml."""
    (tmp_path / "wide.toml").write_text(MODEL_FILE)
    return tmp_path


def _run(tmp_path: Path, mode: str, *args: str, jobs: str = "2", **popen):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DERIVE_JOBS": jobs}
    env.pop("DERIVE_PROGRESS", None)
    return subprocess.Popen([sys.executable, "-c", SCRIPT, mode, *args], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **popen)


@linux_only
def test_files_rendered_in_a_child_are_those_of_one_process(wide):
    tmp_path = wide
    one = subprocess.run([sys.executable, "-m", "derive", "generate", "wide.toml", "--out",
                          "one"], cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "DERIVE_JOBS": "1"},
                         capture_output=True, text=True, timeout=HANG_GUARD)
    assert one.returncode == 0, one.stderr
    proc = _run(tmp_path, "plain", "generate", "wide.toml", "--out", "two")
    out, err = proc.communicate(timeout=HANG_GUARD)
    assert proc.returncode == 0, err
    names = sorted(p.name for p in (tmp_path / "one" / "wide").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "two" / "wide").iterdir())
    assert len(names) == 6    # ekf and ukf, Python and C
    for name in names:
        mine = (tmp_path / "two" / "wide" / name).read_text().replace("--out two", "--out one")
        assert mine == (tmp_path / "one" / "wide" / name).read_text(), name


@linux_only
def test_a_failure_in_a_child_is_one_line_and_writes_nothing(wide):
    tmp_path = wide
    proc = _run(tmp_path, "fail", "generate", "wide.toml", "--filter", "ukf", "--out", "out")
    out, err = proc.communicate(timeout=HANG_GUARD)
    assert proc.returncode == 2
    (line,) = err.splitlines()
    assert line.startswith("derive: error: injected failure in process ")
    assert int(line.rsplit(" ", 1)[1]) != proc.pid       # it came from the child
    assert not (tmp_path / "out").exists()


def _children(pid: int) -> list[int]:
    with open(f"/proc/{pid}/task/{pid}/children") as children:
        return [int(c) for c in children.read().split()]


def _asleep_reading_a_pipe(pid: int) -> bool:
    with open(f"/proc/{pid}/wchan") as wchan:
        return "pipe_read" in wchan.read()


@linux_only
@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="needs Linux's /proc")
def test_ctrl_c_while_a_child_renders_is_one_line_and_stops_it(wide):
    """The terminal's Ctrl-C reaches the whole process group: derive says it was
    interrupted, stops its child and writes nothing. The signal is sent once derive sleeps
    in the read of the child's pipe and the child (which never ends) is running."""
    tmp_path = wide
    proc = _run(tmp_path, "hang", "generate", "wide.toml", "--filter", "ukf", "--out", "out",
                start_new_session=True)
    try:
        waited = time.monotonic()
        while not (_children(proc.pid) and _asleep_reading_a_pipe(proc.pid)):   # a hang guard
            assert proc.poll() is None and time.monotonic() - waited < HANG_GUARD
            time.sleep(0.01)
        (child,) = _children(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=HANG_GUARD)
    finally:
        proc.kill()
    assert proc.returncode == 130
    assert err.splitlines() == ["derive: interrupted"]
    assert not os.path.exists(f"/proc/{child}")
    assert not (tmp_path / "out").exists()
