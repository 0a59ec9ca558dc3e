"""Output files of one call are replaced together (a roll-forward journal finished by the
next run), leftovers of a killed run are removed, and every path is looked up once
(derive/emit/write.py)."""

import errno
import hashlib
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from derive.emit import write
from derive.emit.write import JOURNAL, recover, write_files
from derive.errors import OutputPathError
from derive.generation import generate

ROOT = Path(__file__).resolve().parents[2]
FILTERS = ["kf", "lf", "sskf"]


def snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).digest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def hidden(root: Path) -> list[str]:
    return sorted(p.name for p in root.rglob(".*"))


KILLED_IN_THE_RENAMES = textwrap.dedent("""
    import os, sys, time
    real = os.rename
    def rename(source, target, *args, **kwargs):
        if target == "kf.h":                 # kf.c is renamed already, kf.h not yet
            print("ready", flush=True)
            time.sleep(120)
        return real(source, target, *args, **kwargs)
    os.rename = rename
    from derive.generation import generate
    generate("mpt3d_b", {filters!r}, "all", sys.argv[1], {{"P0_pattern": "dense"}})
""")


def test_a_run_killed_between_renames_is_finished_by_the_next(tmp_path):
    out, wanted = tmp_path / "out", tmp_path / "wanted"
    generate("mpt3d_b", FILTERS, "all", out)
    before = snapshot(out)
    generate("mpt3d_b", FILTERS, "all", wanted, {"P0_pattern": "dense"})
    new = {p.relative_to(wanted).as_posix(): hashlib.sha256(  # headers name their --out
        p.read_text().replace(str(wanted), str(out)).encode()).digest()
        for p in wanted.rglob("*") if p.is_file()}
    assert new["mpt3d_b/kf.h"] != before["mpt3d_b/kf.h"]
    proc = subprocess.Popen([sys.executable, "-c", KILLED_IN_THE_RENAMES.format(
        filters=FILTERS), str(out)], cwd=ROOT, stdout=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout.readline().strip() == "ready"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    # what a reader sees until the next run: kf.c new beside kf.h old, and the journal
    killed = snapshot(out)
    assert killed["mpt3d_b/kf.c"] == new["mpt3d_b/kf.c"]
    assert killed["mpt3d_b/kf.h"] == before["mpt3d_b/kf.h"]
    assert (out / "mpt3d_b" / JOURNAL).is_file()
    # the next run (another filter, Python only) first finishes the killed one
    proc = subprocess.run([sys.executable, "-m", "derive", "generate", "mpt3d_b", "--filter",
                           "sskf", "--lang", "python", "--out", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    after = snapshot(out)
    assert hidden(out) == []
    assert sorted(after) == sorted(before)
    # sskf.py is the second run's own: Python only (its command says --lang python)
    python_only = tmp_path / "python_only"
    generate("mpt3d_b", ["sskf"], "python", python_only)
    new["mpt3d_b/sskf.py"] = hashlib.sha256((python_only / "mpt3d_b" / "sskf.py").read_text(
        ).replace(str(python_only), str(out)).encode()).digest()
    assert new["mpt3d_b/sskf.py"] != before["mpt3d_b/sskf.py"]
    for name in after:
        assert after[name] == new[name], name


def test_recover_alone_finishes_a_killed_run(tmp_path):
    out = tmp_path / "out"
    write_files(out, "m", {"a.c": "old c\n", "a.h": "old h\n"})
    directory = write._ModelDirectory(out, "m")
    try:
        entry = {"direction": "forward", "replace": [], "backups": [], "created": []}
        for name, text in (("a.c", b"new c\n"), ("a.h", b"new h\n")):
            entry["replace"].append([directory.new_file(name, text), name])
            entry["backups"].append([name, directory.backup(name)])
        directory.write_journal(entry)
        directory.rename(*entry["replace"][0])        # killed here
    finally:
        directory.close()
    assert (out / "m" / "a.c").read_text() == "new c\n"
    assert (out / "m" / "a.h").read_text() == "old h\n"
    recover(out, "m")
    assert (out / "m" / "a.h").read_text() == "new h\n"
    assert hidden(out) == []


def test_leftovers_of_killed_runs_are_removed_and_nothing_else(tmp_path):
    out = tmp_path / "out"
    write_files(out, "m", {"a.c": "one\n"})
    folder = out / "m"
    leftovers = [".a.c.derive-0123abcd.tmp", ".a.c.derive-89abcdef.old",
                 ".derive-journal.derive-00ff00ff.tmp",
                 ".a.c.0a1b2c3d4e5f.old", ".a.c.k2_9xq0z.tmp"]   # the last two: derive 0.1.0
    kept = [".notes", ".a.c.swp", "a.c.tmp", "b.c"]
    for name in leftovers + kept:
        (folder / name).write_text("x\n")
    write_files(out, "m", {"a.c": "two\n"})
    assert sorted(p.name for p in folder.iterdir()) == sorted(kept + ["a.c"])
    assert (folder / "a.c").read_text() == "two\n"


@pytest.mark.parametrize("error", [OSError(errno.EIO, "I/O error"), KeyboardInterrupt()],
                         ids=["I/O error", "interrupted"])
def test_a_failure_between_renames_puts_every_previous_file_back(tmp_path, monkeypatch, error):
    out = tmp_path / "out"
    write_files(out, "m", {"a.c": "old c\n", "a.h": "old h\n"})
    before = snapshot(out)
    real, calls = os.rename, []

    def rename(source, target, *args, **kwargs):
        calls.append(target)
        if calls == [JOURNAL, "a.c", "a.h"]:     # a.c was replaced, a.h not yet
            raise error
        return real(source, target, *args, **kwargs)

    monkeypatch.setattr(os, "rename", rename)
    with pytest.raises(type(error)):
        write_files(out, "m", {"a.c": "new c\n", "a.h": "new h\n", "b.c": "new b\n"})
    monkeypatch.undo()
    assert calls[:5] == [JOURNAL, "a.c", "a.h", JOURNAL, "a.c"]   # the journal turns first
    assert snapshot(out) == before
    assert hidden(out) == []


def test_a_directory_swapped_for_a_link_mid_run_writes_nothing_outside(tmp_path, monkeypatch):
    """Between opening OUT/m and writing, OUT/m becomes a link to a directory outside OUT
    (as renameat2(RENAME_EXCHANGE) would do): every file still goes into the directory
    opened at the start, none through the link."""
    out, outside = tmp_path / "out", tmp_path / "outside"
    outside.mkdir()
    (out / "m").mkdir(parents=True)
    real_open, swapped = os.open, []

    def swapping_open(path, flags, *args, **kwargs):
        if str(path).startswith(".a.") and not swapped:
            os.rename(out / "m", out / "moved")
            os.symlink(outside, out / "m")
            swapped.append(path)
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", swapping_open)
    write_files(out, "m", {"a.c": "c\n", "a.h": "h\n"})
    monkeypatch.undo()
    assert swapped
    assert list(outside.iterdir()) == []
    assert sorted(p.name for p in (out / "moved").iterdir()) == ["a.c", "a.h"]


def test_a_journal_derive_did_not_write_is_refused(tmp_path):
    out = tmp_path / "out"
    write_files(out, "m", {"a.c": "one\n"})
    (out / "m" / JOURNAL).write_text('{"direction": "forward", "replace": [["a.c", "../x"]], '
                                     '"backups": [], "created": []}')
    before = snapshot(out)
    with pytest.raises(OutputPathError, match="not written by derive"):
        write_files(out, "m", {"a.c": "two\n"})
    assert snapshot(out) == before


CONCURRENT = textwrap.dedent("""
    import sys
    from derive.emit.write import write_files
    label = sys.argv[2]
    for n in range(40):
        write_files(sys.argv[1], "m", {f"f{i}.c": f"{label} {n}\\n" for i in range(6)})
""")


def test_two_writers_of_one_directory_take_turns(tmp_path):
    """The lock: neither run removes the other's temporaries as leftovers, and the files
    are always those of one complete run."""
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, "-c", CONCURRENT, str(out), label], cwd=ROOT,
                              env=env, stderr=subprocess.PIPE, text=True)
             for label in ("A", "B")]
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    texts = {p.read_text() for p in (out / "m").iterdir()}
    assert len(texts) == 1 and texts <= {"A 39\n", "B 39\n"}
    assert hidden(out) == []
