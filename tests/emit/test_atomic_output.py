"""Atomic output: every file is rendered, then written to a temporary file in its destination
and renamed; a run that fails or is interrupted midway leaves the previous files intact."""

import errno
import hashlib
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from derive.errors import SteadyStateError
from derive.generation import generate

ROOT = Path(__file__).resolve().parents[2]
FILTERS = ["kf", "lf", "sskf"]


def snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).digest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def out(tmp_path):
    """mpt3d_b generated once with its defaults: the previous files."""
    root = tmp_path / "out"
    generate("mpt3d_b", FILTERS, "all", root)
    assert len(snapshot(root)) == 9
    return root


def regenerate(out: Path) -> None:
    """A run that would change every file (another option), then writes them."""
    generate("mpt3d_b", FILTERS, "all", out, {"P0_pattern": "dense"})


def test_a_successful_run_replaces_every_file_and_leaves_no_temporary(out):
    before = snapshot(out)
    regenerate(out)
    after = snapshot(out)
    assert sorted(after) == sorted(before)
    assert all(after[name] != before[name] for name in ("mpt3d_b/kf.py", "mpt3d_b/kf.c"))
    assert not [p for p in out.rglob("*.tmp")]
    assert all((p.stat().st_mode & 0o777) == 0o644 for p in out.rglob("*") if p.is_file())


def test_a_failed_derivation_writes_nothing(out):
    before = snapshot(out)
    with pytest.raises(SteadyStateError):
        generate("mpt3d_b", ["kf", "fir"], "all", out, {"P0_pattern": "dense"},
                 {"fir": {"eps": 1e-300}})  # needs an order above the bound
    assert snapshot(out) == before


def test_a_failure_while_rendering_the_last_filter_writes_nothing(out, monkeypatch):
    import derive.generation as generate_module

    real, calls = generate_module.render_c, []

    def render_c(unit, **kw):
        calls.append(unit.filter)
        if len(calls) == len(FILTERS):
            raise RuntimeError("injected failure while rendering")
        return real(unit, **kw)

    monkeypatch.setattr(generate_module, "render_c", render_c)
    before = snapshot(out)
    with pytest.raises(RuntimeError, match="injected"):
        regenerate(out)
    assert calls == FILTERS
    assert snapshot(out) == before


def _fail_on_call(monkeypatch, name: str, call: int, error: BaseException) -> list:
    """Make ``os.<name>`` raise ``error`` on its ``call``-th use (1-based)."""
    real, calls = getattr(os, name), []

    def wrapper(*args, **kwargs):
        calls.append(args)
        if len(calls) == call:
            raise error
        return real(*args, **kwargs)

    monkeypatch.setattr(os, name, wrapper)
    return calls


@pytest.mark.parametrize("error", [OSError(errno.ENOSPC, "No space left on device"),
                                   KeyboardInterrupt()], ids=["disk full", "interrupted"])
def test_a_failure_midway_through_writing_keeps_the_previous_files(out, monkeypatch, error):
    """The fifth of nine files fails while its temporary is written: nothing is replaced
    and the temporaries written so far are removed."""
    before = snapshot(out)
    calls = _fail_on_call(monkeypatch, "fsync", 5, error)
    with pytest.raises(type(error)):
        regenerate(out)
    monkeypatch.undo()
    assert len(calls) == 5
    assert snapshot(out) == before
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]


def test_a_killed_run_keeps_the_previous_files(out):
    """SIGKILL while the temporaries are written: the previous files stay; at most hidden
    temporaries (.NAME.XXXX.tmp) are left behind, which no reader mistakes for output."""
    before = snapshot(out)
    script = textwrap.dedent(f"""
        import os, sys, time
        real = os.fsync
        count = [0]
        def fsync(fd):
            count[0] += 1
            if count[0] == 5:
                print("ready", flush=True)
                time.sleep(60)
            return real(fd)
        os.fsync = fsync
        from derive.generation import generate
        generate("mpt3d_b", {FILTERS!r}, "all", {str(out)!r}, {{"P0_pattern": "dense"}})
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    after = snapshot(out)
    leftovers = sorted(set(after) - set(before))
    assert {name: after[name] for name in before} == before
    assert all(Path(name).name.startswith(".") and name.endswith(".tmp") for name in leftovers)
    assert 1 <= len(leftovers) <= 5


def test_a_failure_between_renames_keeps_the_previous_files(out, monkeypatch):
    before = snapshot(out)
    _fail_on_call(monkeypatch, "rename", 3, OSError(errno.EIO, "I/O error"))
    with pytest.raises(OSError):
        regenerate(out)
    monkeypatch.undo()
    assert snapshot(out) == before

