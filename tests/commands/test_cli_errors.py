"""The command line never prints a traceback: each failure is one line on stderr with its
exit status (see derive/cli.py), checked through a real ``python -m derive`` process."""

import fcntl
import os
import select
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from derive.cli import main

ROOT = Path(__file__).resolve().parents[2]
MODEL = textwrap.dedent("""
    [model]
    name = "{name}"
    states = ["s"]
    measurements = ["z"]

    [discrete]
    F = [["1"]]
    H = [["1"]]
    Q = [["1"]]
    R = [["1"]]
""")


def derive(*argv, env=None, **kwargs) -> subprocess.CompletedProcess:
    environ = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    environ.pop("DERIVE_DEBUG", None) if "DERIVE_DEBUG" not in (env or {}) else None
    return subprocess.run([sys.executable, "-m", "derive", *argv], capture_output=True,
                          cwd=ROOT, env=environ, timeout=300, **kwargs)


def one_line(proc: subprocess.CompletedProcess, status: int, *words: str) -> str:
    """Assert ``status``, exactly one stderr line containing ``words``, no traceback."""
    err = proc.stderr.decode("utf-8", "replace")
    assert proc.returncode == status, (proc.returncode, err)
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1, lines
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def test_a_usage_error_found_by_argparse_is_one_line(tmp_path):
    line = one_line(derive("generate", "mpt3d_b", "--lang", "fortran", "--out", str(tmp_path)),
                    2, "argument --lang", "fortran")
    assert line.startswith("derive: error: ")     # as every other error (was "derive generate:")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("argv, line", [
    (["generate", "mpt3d_b", "--P0-pattern", "diag"],
     "derive: error: argument --P0-pattern: invalid choice: 'diag' (choose from 'dense', "
     "'zero', 'diagonal', 'block') (did you mean 'diagonal'?)"),
    (["verfy"], "derive: error: argument COMMAND: invalid choice: 'verfy' (choose from "
                "'list', 'show', 'check', 'generate', 'verify', 'fit', 'burden', 'audit', "
                "'gnss', 'size', 'reproduce', 'bench') (did you mean 'verify'?)")],
    ids=["option", "command"])
def test_an_invalid_choice_gets_a_close_match_and_the_common_prefix(capsys, argv, line):
    assert main(argv) == 2
    assert capsys.readouterr().err == line + "\n"


def test_out_naming_a_regular_file(tmp_path):
    target = tmp_path / "afile"
    target.write_text("not a directory")
    one_line(derive("generate", "mpt3d_b", "--filter", "kf", "--out", str(target)), 2,
             "derive: error:", "afile", "Not a directory")
    assert target.read_text() == "not a directory"


def test_a_model_name_too_long_for_a_directory(tmp_path):
    """A 300-character model name: the directory OUT/NAME cannot exist (ENAMETOOLONG)."""
    path = tmp_path / "long.toml"
    path.write_text(MODEL.format(name="m" * 300))
    one_line(derive("generate", str(path), "--filter", "kf", "--out", str(tmp_path / "out")),
             2, "derive: error:")


def test_an_out_path_too_long(tmp_path):
    one_line(derive("generate", "mpt3d_b", "--filter", "kf", "--out",
                    str(tmp_path / ("o" * 300))), 2, "derive: error:", "File name too long")


def test_an_output_file_that_is_a_directory(tmp_path):
    (tmp_path / "mpt3d_b" / "kf.c").mkdir(parents=True)
    one_line(derive("generate", "mpt3d_b", "--filter", "kf", "--out", str(tmp_path)), 2,
             "kf.c is a directory")
    assert sorted(p.name for p in (tmp_path / "mpt3d_b").iterdir()) == ["kf.c"]


def _immutable(path: Path) -> bool:
    """Make ``path`` immutable with chattr +i (root ignores mode bits); False if impossible."""
    if shutil.which("chattr") is None:
        return False
    return subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode == 0


@pytest.mark.parametrize("where", ["out", "model"])
def test_an_immutable_output_directory(tmp_path, where):
    out = tmp_path / "out"
    (out / "mpt3d_b").mkdir(parents=True)
    locked = out if where == "out" else out / "mpt3d_b"
    if where == "out":
        (out / "mpt3d_b").rmdir()
    if not _immutable(locked):
        pytest.skip("chattr +i is not available here (needs root and a file system with "
                    "attributes); mode bits do not stop root")
    try:
        one_line(derive("generate", "mpt3d_b", "--filter", "kf", "--out", str(out)), 2,
                 "derive: error: cannot", str(locked), "Operation not permitted")
        assert not list(locked.iterdir())
    finally:
        subprocess.run(["chattr", "-i", str(locked)], check=True)


def test_an_out_path_with_bytes_that_are_not_utf8(tmp_path):
    out = os.fsencode(tmp_path) + b"/out\xff\xfe"
    line = one_line(derive("generate", "mpt3d_b", "--filter", "kf", "--out", out), 2,
                    "is not valid UTF-8")
    assert "out\\xff\\xfe" in line
    assert not list(tmp_path.iterdir())


def test_a_model_path_with_bytes_that_are_not_utf8(tmp_path):
    path = os.fsencode(tmp_path) + b"/model\xff.toml"
    with open(path, "w") as handle:
        handle.write(MODEL.format(name="scalar"))
    one_line(derive("generate", path, "--filter", "kf", "--out", str(tmp_path / "out")), 2,
             "model\\xff.toml", "is not valid UTF-8")
    assert not (tmp_path / "out").exists()


def test_a_missing_c_compiler_is_named(tmp_path):
    line = one_line(derive("verify", "mpt3d_b", "--filter", "kf", "--steps", "5",
                           env={"CC": "derive-no-such-cc"}), 2, "derive-no-such-cc")
    assert "no C compiler" in line


def test_a_closed_pipe_ends_quietly():
    """``derive list | head -0``: the reader is gone before derive writes."""
    read, write = os.pipe()
    os.close(read)
    try:
        proc = subprocess.run([sys.executable, "-m", "derive", "list"], stdout=write,
                              stderr=subprocess.PIPE, cwd=ROOT, timeout=300,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    finally:
        os.close(write)
    assert proc.stderr == b""
    assert proc.returncode == 141


def _blocked_writing_a_pipe(pid: int) -> bool:
    """Whether process ``pid`` sleeps in the kernel's pipe write (Linux's wchan names it
    ``pipe_write`` or ``anon_pipe_write``)."""
    with open(f"/proc/{pid}/wchan") as wchan:
        return "pipe_write" in wchan.read()


@pytest.mark.skipif(not os.path.exists("/proc/self/wchan"), reason="needs Linux's /proc")
def test_ctrl_c_is_one_line_and_status_130():
    """Interrupt a run that cannot finish first: ``derive show ins_gnss`` writes 32 KB to a
    stdout pipe shrunk to one page that nothing reads, more than the pipe and Python's
    8 KB buffer hold. SIGINT is sent once the kernel shows derive asleep in that pipe's
    write, inside its command (with PYTHONUNBUFFERED set, data reaches the pipe at the
    first line, while derive still computes: that moment is not one state)."""
    read, write = os.pipe()
    fcntl.fcntl(write, fcntl.F_SETPIPE_SZ, 4096)
    proc = subprocess.Popen([sys.executable, "-m", "derive", "show", "ins_gnss"], cwd=ROOT,
                            stdout=write, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    os.close(write)
    try:
        readable, _, _ = select.select([read], [], [], 120)   # a hang guard
        assert readable
        waited = time.monotonic()
        while not _blocked_writing_a_pipe(proc.pid):   # a hang guard, not a timing
            assert proc.poll() is None and time.monotonic() - waited < 120
            time.sleep(0.01)
        proc.send_signal(signal.SIGINT)
        with os.fdopen(read, "rb") as out:   # drain: exit's flush must not block again
            shown = out.read()
        err = proc.stderr.read()
        proc.wait(timeout=120)
    finally:
        proc.kill()
        proc.stderr.close()
    assert proc.returncode == 130
    assert err.decode().splitlines() == ["derive: interrupted"]
    assert b"ins_gnss" in shown


INTERNAL = textwrap.dedent("""
    import sys
    import derive.commands.list as command
    def run(args):
        raise RuntimeError("an injected bug")
    command.run = run
    from derive.cli import main
    sys.exit(main(["list"]))
""")


def test_an_internal_error_is_one_line_with_a_hint_and_debug_shows_it():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DERIVE_DEBUG", None)
    proc = subprocess.run([sys.executable, "-c", INTERNAL], capture_output=True, cwd=ROOT,
                          env=env, timeout=120)
    one_line(proc, 70, "internal error: RuntimeError: an injected bug", "report",
             "DERIVE_DEBUG=1")
    proc = subprocess.run([sys.executable, "-c", INTERNAL], capture_output=True, cwd=ROOT,
                          env={**env, "DERIVE_DEBUG": "1"}, timeout=120)
    assert proc.returncode == 1
    assert b"Traceback" in proc.stderr and b"an injected bug" in proc.stderr
