"""Writing generated files into ``OUT_DIR/MODEL/``: all of one call replaced together.

Every path is looked up once: ``OUT_DIR`` is opened (it may be a link: the user's
choice), ``MODEL`` is opened relative to it and checked to lie beneath it, and every
later operation (create, link, rename, unlink) names a plain file relative to that
open directory, never following a link.  Swapping a directory for a symbolic link
during a run therefore cannot move a file outside ``OUT_DIR``.

The files of one call are replaced together, by a roll-forward journal:

1. each file is written in full to a hidden temporary ``.NAME.derive-XXXXXXXX.tmp``
   and fsynced; an existing file is kept as a hard link ``.NAME.derive-XXXXXXXX.old``;
2. the journal ``.derive-journal`` (which temporary becomes which file) is written
   to a temporary, fsynced and renamed into place: from here the run is committed;
3. the temporaries are renamed over their files, the directory is fsynced, the
   backups and then the journal are removed.

A failure in the process before step 2 removes the temporaries: nothing changed.
A failure during step 3 marks the journal "back" and puts every previous file back.
A process killed during step 3 leaves the journal; the next :func:`write_files` into
the same directory (or :func:`recover`) finishes the renames before anything else,
and removes every leftover temporary and backup.  Writers of one directory are
serialised by an exclusive ``flock`` on it, so a run never removes the temporaries
of another.  Renames of several files are not one atomic operation: while step 3
runs, or after a kill in it until the next run, a reader can see some files new
and some old (with ``.derive-journal`` present); at every other moment the files
are those of one complete run.
"""

from __future__ import annotations

import errno
import fcntl
import json
import keyword
import os
import re
import secrets
import stat
from collections.abc import Mapping
from pathlib import Path

from derive.errors import OutputPathError, OutputWriteError

JOURNAL = ".derive-journal"
#: hidden files derive leaves only when killed: temporaries, backups and journal
#: temporaries (also the ``.NAME.XXXXXXXX.tmp`` and ``.NAME.<12 hex>.old`` of 0.1.0).
_LEFTOVER = re.compile(r"^\..+\.(derive-[0-9a-f]{8}\.(tmp|old)"
                       r"|[0-9a-f]{12}\.old|[a-z0-9_]{8}\.tmp)$")
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC
_NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


def _check_name(name: str, what: str) -> None:
    if (not isinstance(name, str) or not name or name in (".", "..") or "/" in name
            or "\\" in name or "\0" in name or os.sep in name
            or (os.altsep is not None and os.altsep in name)):
        raise OutputPathError(f"{what} {name!r} must be a plain file name (no path separators, "
                              "not '.' or '..')")


def _check_model_name(model_name: str) -> None:
    if not isinstance(model_name, str) or not model_name.isidentifier() or keyword.iskeyword(
            model_name):
        raise OutputPathError(f"model name {model_name!r} is not a plain identifier, so it "
                              "cannot name an output directory")
    _check_name(model_name, "model name")


def _failure(path: Path, what: str, exc: OSError) -> OutputWriteError:
    error = OutputWriteError(f"cannot {what} {path}: {exc.strerror or exc}")
    error.errno = exc.errno
    return error


def _same(a: os.stat_result, b: os.stat_result) -> bool:
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _beneath(dir_fd: int, root: os.stat_result) -> bool:
    """Whether the open directory ``dir_fd`` is ``root`` or lies beneath it (walks '..')."""
    current = os.dup(dir_fd)
    try:
        for _ in range(4096):
            here = os.fstat(current)
            if _same(here, root):
                return True
            parent = os.open("..", _DIR_FLAGS, dir_fd=current)
            os.close(current)
            current = parent
            if _same(os.fstat(current), here):   # reached "/"
                return False
        return False
    finally:
        os.close(current)


def _lstat(name: str, dir_fd: int) -> os.stat_result | None:
    try:
        return os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except FileNotFoundError:
        return None


def _link_target(path: Path, dir_fd: int, name: str) -> str:
    """Where the link ``name`` leads (for the check and messages: writing never follows it)."""
    return os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                         os.readlink(name, dir_fd=dir_fd)))


def _open_or_create(path: Path) -> int:
    try:
        return os.open(path, _DIR_FLAGS)
    except FileNotFoundError:
        os.makedirs(path, exist_ok=True)
        return os.open(path, _DIR_FLAGS)


class _ModelDirectory:
    """``OUT/MODEL`` opened beneath ``OUT`` and locked; all names relative to it."""

    def __init__(self, out_dir: str | os.PathLike, model_name: str) -> None:
        self.out = Path(out_dir)
        self.path = self.out / model_name
        try:
            out_fd = _open_or_create(self.out)
        except OSError as exc:
            raise _failure(self.out, "use the output directory", exc) from None
        try:
            self.fd = self._open_beneath(out_fd, model_name)
        finally:
            os.close(out_fd)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX)
        except OSError as exc:
            os.close(self.fd)
            raise _failure(self.path, "lock the output directory", exc) from None

    def _open_beneath(self, out_fd: int, model_name: str) -> int:
        try:
            os.mkdir(model_name, 0o755, dir_fd=out_fd)
        except FileExistsError:
            pass
        except OSError as exc:
            raise _failure(self.path, "create the output directory", exc) from None
        try:
            fd = os.open(model_name, _DIR_FLAGS, dir_fd=out_fd)
        except OSError as exc:
            raise _failure(self.path, "open the output directory", exc) from None
        if _beneath(fd, os.fstat(out_fd)):
            return fd
        os.close(fd)
        root = os.path.realpath(self.out)
        try:
            target = _link_target(self.path, out_fd, model_name)
        except OSError:   # not a link: a mount or a bind beneath OUT leading elsewhere
            raise OutputPathError(f"{self.path} resolves outside the output directory "
                                  f"{root}") from None
        raise OutputPathError(f"{self.path} is a symbolic link to {target}, outside the "
                              f"output directory {root}")

    def close(self) -> None:
        os.close(self.fd)   # also releases the lock

    def __enter__(self) -> _ModelDirectory:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- primitives relative to the open directory ---------------------------------------

    def new_file(self, name: str, data: bytes, suffix: str = "tmp") -> str:
        """Write ``data`` to a new hidden ``.NAME.derive-XXXXXXXX.SUFFIX``; its name."""
        while True:
            hidden = f".{name}.derive-{secrets.token_hex(4)}.{suffix}"
            try:
                fd = os.open(hidden, _NEW_FILE_FLAGS, 0o600, dir_fd=self.fd)
                break
            except FileExistsError:
                continue
        try:
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fchmod(handle.fileno(), 0o644)
                os.fsync(handle.fileno())
        except BaseException:
            self.unlink(hidden)
            raise
        return hidden

    def rename(self, source: str, target: str) -> None:
        os.rename(source, target, src_dir_fd=self.fd, dst_dir_fd=self.fd)

    def unlink(self, name: str) -> None:
        try:
            os.unlink(name, dir_fd=self.fd)
        except FileNotFoundError:
            pass

    def exists(self, name: str) -> bool:
        return _lstat(name, self.fd) is not None

    def sync(self) -> None:
        os.fsync(self.fd)

    # -- the journal ---------------------------------------------------------------------

    def write_journal(self, entry: dict) -> None:
        hidden = self.new_file(JOURNAL, json.dumps(entry, sort_keys=True).encode())
        self.rename(hidden, JOURNAL)
        self.sync()

    def read_journal(self) -> dict | None:
        try:
            fd = os.open(JOURNAL, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=self.fd)
        except FileNotFoundError:
            return None
        with os.fdopen(fd, "rb") as handle:
            text = handle.read(1 << 20)
        try:
            entry = json.loads(text)
            names = [n for key in ("replace", "backups") for pair in entry[key] for n in pair]
            names += entry["created"]
            if entry["direction"] not in ("forward", "back"):
                raise ValueError(entry["direction"])
            for name in names:
                _check_name(name, "journal entry")
        except (ValueError, KeyError, TypeError, OutputPathError):
            raise OutputPathError(f"{self.path / JOURNAL} was not written by derive (it is not "
                                  "a journal of renames); remove it") from None
        return entry

    def finish(self, entry: dict) -> None:
        """Complete a journal in its direction, then remove it."""
        if entry["direction"] == "forward":
            for hidden, final in entry["replace"]:
                if self.exists(hidden):
                    self.rename(hidden, final)
            self.sync()
            for _, backup in entry["backups"]:
                self.unlink(backup)
        else:
            for final, backup in entry["backups"]:
                if self.exists(backup):
                    self.rename(backup, final)
                    self.unlink(backup)   # a no-op rename when both name one file
            for final in entry["created"]:
                self.unlink(final)
            for hidden, _ in entry["replace"]:
                self.unlink(hidden)
        self.sync()
        self.unlink(JOURNAL)
        self.sync()

    def recover(self) -> None:
        """Finish an interrupted run's journal; remove leftover hidden files."""
        entry = self.read_journal()
        if entry is not None:
            self.finish(entry)
        for name in os.listdir(self.fd):
            if _LEFTOVER.match(name) and stat.S_ISREG(
                    os.stat(name, dir_fd=self.fd, follow_symlinks=False).st_mode):
                self.unlink(name)

    def check_target(self, name: str) -> None:
        """Refuse a directory, or a link leading outside ``OUT``, where a file goes."""
        info = _lstat(name, self.fd)
        if info is None:
            return
        if stat.S_ISDIR(info.st_mode):
            raise OutputPathError(f"{self.path / name} is a directory, not a file derive "
                                  "can replace")
        if stat.S_ISLNK(info.st_mode):
            target = Path(_link_target(self.path / name, self.fd, name))
            root = Path(os.path.realpath(self.out))
            if not (target == root or root in target.parents):
                raise OutputPathError(f"{self.path / name} is a symbolic link to {target}, "
                                      f"outside the output directory {root}")

    def backup(self, name: str) -> str | None:
        """A hidden hard link to the existing ``name`` (a copy where links fail)."""
        info = _lstat(name, self.fd)
        if info is None:
            return None
        while True:
            hidden = f".{name}.derive-{secrets.token_hex(4)}.old"
            try:
                os.link(name, hidden, src_dir_fd=self.fd, dst_dir_fd=self.fd,
                        follow_symlinks=False)
                return hidden
            except FileExistsError:
                continue
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.EMLINK, errno.ENOTSUP, errno.EXDEV):
                    raise
                if stat.S_ISLNK(info.st_mode):
                    os.symlink(os.readlink(name, dir_fd=self.fd), hidden, dir_fd=self.fd)
                    return hidden
                fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=self.fd)
                with os.fdopen(fd, "rb") as handle:
                    return self.new_file(name, handle.read(), "old")


def recover(out_dir: str | os.PathLike, model_name: str) -> None:
    """Finish or undo an interrupted :func:`write_files` into ``out_dir/model_name``."""
    _check_model_name(model_name)
    with _ModelDirectory(out_dir, model_name) as directory:
        try:
            directory.recover()
        except OSError as exc:
            raise _failure(directory.path, "recover the output directory", exc) from None


def write_files(out_dir: str | os.PathLike, model_name: str,
                files: Mapping[str, str]) -> list[Path]:
    """Write ``files`` ({file name: text}) into ``out_dir/model_name/``, replaced together.

    Returns the written paths, sorted by file name.  Raises OutputPathError for a
    model or file name that is not plain, a destination that is or passes through a
    symlink leading outside ``out_dir``, a directory where a file goes, or a
    directory that cannot be written (the message names the path).
    """
    for name in files:
        _check_name(name, "file name")
    _check_model_name(model_name)
    data = {name: files[name].encode("utf-8") for name in sorted(files)}
    with _ModelDirectory(out_dir, model_name) as directory:
        try:
            directory.recover()
            for name in data:
                directory.check_target(name)
            _replace_together(directory, data)
        except OSError as exc:
            raise _failure(directory.path, "write in", exc) from None
        return [directory.path / name for name in data]


def _replace_together(directory: _ModelDirectory, data: dict[str, bytes]) -> None:
    entry = {"direction": "forward", "replace": [], "backups": [], "created": []}
    try:
        for name, content in data.items():
            entry["replace"].append([directory.new_file(name, content), name])
        for name in data:
            saved = directory.backup(name)
            if saved is None:
                entry["created"].append(name)
            else:
                entry["backups"].append([name, saved])
    except BaseException:
        for hidden, _ in entry["replace"]:
            directory.unlink(hidden)
        for _, saved in entry["backups"]:
            directory.unlink(saved)
        raise
    directory.sync()
    directory.write_journal(entry)      # committed: a killed run is finished by the next
    try:
        for hidden, final in entry["replace"]:
            directory.rename(hidden, final)
    except BaseException:
        entry["direction"] = "back"
        directory.write_journal(entry)
        directory.finish(entry)
        raise
    directory.finish(entry)

