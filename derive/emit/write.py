"""Atomic writing of generated files into ``OUT_DIR/MODEL/``.

Every file is first written in full to a temporary file in its destination
directory; only when all of them are written are they moved into place with
``os.replace``.  A failure or an interruption before that leaves the previous
files intact; render everything before calling :func:`write_files`.
"""

from __future__ import annotations

import keyword
import os
import secrets
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path

from derive.errors import OutputPathError


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


def _check_name(name: str, what: str) -> None:
    if (not isinstance(name, str) or not name or name in (".", "..") or "/" in name
            or "\\" in name or "\0" in name or os.sep in name
            or (os.altsep is not None and os.altsep in name)):
        raise OutputPathError(f"{what} {name!r} must be a plain file name (no path separators, "
                              "not '.' or '..')")


def _check_link(path: Path, root: Path) -> None:
    """Reject ``path`` if it is a symlink that leads outside ``root``."""
    if path.is_symlink() and not _inside(Path(os.path.realpath(path)), root):
        raise OutputPathError(f"{path} is a symbolic link to {os.path.realpath(path)}, "
                              f"outside the output directory {root}")


def destination(out_dir: str | os.PathLike, model_name: str) -> Path:
    """``out_dir/model_name`` after validating ``model_name`` and symlinks."""
    if not isinstance(model_name, str) or not model_name.isidentifier() or keyword.iskeyword(
            model_name):
        raise OutputPathError(f"model name {model_name!r} is not a plain identifier, so it "
                              "cannot name an output directory")
    _check_name(model_name, "model name")
    root = Path(os.path.realpath(out_dir))
    target = Path(out_dir) / model_name
    _check_link(target, root)
    return target


def write_files(out_dir: str | os.PathLike, model_name: str,
                files: Mapping[str, str]) -> list[Path]:
    """Write ``files`` ({file name: text}) into ``out_dir/model_name/`` atomically.

    Returns the written paths, sorted by file name.  Raises OutputPathError for a
    model or file name that is not plain, or a destination that is or passes
    through a symlink leading outside ``out_dir``.
    """
    for name in files:
        _check_name(name, "file name")
    target = destination(out_dir, model_name)
    root = Path(os.path.realpath(out_dir))
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"cannot create the output directory {target}: "
                              f"{exc.strerror or exc}") from None
    if not _inside(Path(os.path.realpath(target)), root):
        raise OutputPathError(f"{target} resolves outside the output directory {root}")
    for name in files:
        _check_link(target / name, root)
    pending: list[tuple[str, Path]] = []
    try:
        for name in sorted(files):
            fd, tmp = tempfile.mkstemp(dir=target, prefix=f".{name}.", suffix=".tmp")
            pending.append((tmp, target / name))
            with os.fdopen(fd, "wb") as handle:
                handle.write(files[name].encode("utf-8"))
                handle.flush()
                os.fsync(handle.fileno())
            os.chmod(tmp, 0o644)
    except BaseException:
        for tmp, _ in pending:
            Path(tmp).unlink(missing_ok=True)
        raise
    _replace_all(pending)
    return [final for _, final in pending]


def _replace_all(pending: list[tuple[str, Path]]) -> None:
    """Move every temporary into place; on any failure put the previous files back.

    Existing files are first kept as hard links (a copy where links fail), so an
    interruption between two renames cannot leave a mix of new and old files.
    """
    backups: list[tuple[Path, Path]] = []
    created: list[Path] = []
    try:
        for _, final in pending:
            if final.exists():
                saved = final.with_name(f".{final.name}.{secrets.token_hex(6)}.old")
                try:
                    os.link(final, saved)
                except OSError:
                    shutil.copy2(final, saved)
                backups.append((final, saved))
        for tmp, final in pending:
            existed = final.exists()
            os.replace(tmp, final)
            if not existed:
                created.append(final)
    except BaseException:
        for final, saved in backups:
            os.replace(saved, final)
            saved.unlink(missing_ok=True)
        for final in created:
            final.unlink(missing_ok=True)
        for tmp, _ in pending:
            Path(tmp).unlink(missing_ok=True)
        raise
    for _, saved in backups:
        saved.unlink(missing_ok=True)
