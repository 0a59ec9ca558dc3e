"""Render, write, load: generated filters from their units to code that can be called.

Every caller that wants to run a generated filter (derive verify, the report, the
benchmark, the GNSS applications, paper mode, the tests) goes through this one pipeline:

1. the units are rendered (derive.emit.render) in the languages asked for, all before
   any file is written;
2. the files are written into ``DIRECTORY/MODEL/`` (derive.emit.write), one call per
   model, so they are replaced together;
3. each Python file is loaded as a fresh module (:func:`derive.build.load_python`) and
   the C files of one call are compiled into one cffi extension (:func:`derive.build.
   build_c`, strict flags plus ``extra_cflags``, by ``compiler``: default CC, else gcc).

Without a directory the files go to a temporary one, removed once loaded (the Python is
executed and the C library cached, so nothing needs the files afterwards).
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType, ModuleType

from .build import FilterModule, build_c, load_python
from .emit.render import render_files
from .emit.write import write_files
from .errors import FilterError
from .generation import LANG_CHOICES, check_lang, command_unit, resolve_model
from .model import ModelRef
from .options import SharedOptions
from .runs.unit import Unit

#: The languages of each ``lang`` argument.


@dataclass(frozen=True)
class Generated:
    """One generated filter, loaded: the Python module and the C wrappers (None for a
    language not asked for), and where its files were written (``{suffix: path}``;
    empty when they were written to a temporary directory)."""

    unit: Unit
    python: ModuleType | None
    c: FilterModule | None
    paths: Mapping[str, Path]

    def module(self, lang: str):
        """The loaded module of ``lang`` ("python" or "c")."""
        loaded = {"python": self.python, "c": self.c}.get(lang)
        if loaded is None:
            raise FilterError(f"{self.unit.prefix} was not loaded in {lang!r} "
                              "(ask load_generated for it)")
        return loaded


def load_units(units: Sequence[Unit], lang: str = "all", directory: str | Path | None = None,
               *, extra_cflags: Sequence[str] = (), compiler: str | None = None,
               cache: str | Path | None = None) -> list[Generated]:
    """Render, write and load ``units`` (see the module docstring); one
    :class:`Generated` per unit, in order. The C of all units is one extension, compiled
    by ``compiler`` (build_c's: default CC, else gcc) into the compiled-module cache
    ``cache`` (build_c's ``tmpdir``: default the user's)."""
    check_lang(lang)
    files: dict[str, dict[str, str]] = {}
    for unit in units:
        files.setdefault(unit.model, {}).update(render_files(unit, LANG_CHOICES[lang]))
    if directory is not None:
        return _write_and_load(units, files, Path(directory), extra_cflags, compiler, cache,
                               keep=True)
    with tempfile.TemporaryDirectory(prefix="derive-") as scratch:
        return _write_and_load(units, files, Path(scratch), extra_cflags, compiler, cache,
                               keep=False)


def _write_and_load(units: Sequence[Unit], files: Mapping[str, Mapping[str, str]],
                    directory: Path, extra_cflags: Sequence[str], compiler: str | None,
                    cache: str | Path | None, keep: bool) -> list[Generated]:
    written: dict[tuple[str, str], Path] = {}
    for model, texts in files.items():
        for name, path in zip(sorted(texts), write_files(directory, model, texts)):
            written[model, name] = path

    def path(unit: Unit, suffix: str) -> Path | None:
        return written.get((unit.model, unit.filter + suffix))

    c_files = [path(u, ".c") for u in units if path(u, ".c") is not None]
    extension = build_c(c_files, extra_cflags=extra_cflags, compiler=compiler,
                        tmpdir=cache) if c_files else None
    loaded = []
    for unit in units:
        python = path(unit, ".py")
        paths = {s: path(unit, s) for s in (".py", ".c", ".h") if path(unit, s) is not None}
        loaded.append(Generated(
            unit,
            load_python(python) if python is not None else None,
            extension[unit.prefix] if path(unit, ".c") is not None else None,
            MappingProxyType(paths if keep else {})))
    return loaded


def load_generated(model: ModelRef, filter: str, options: Mapping | SharedOptions | None = None,
                   lang: str = "all", directory: str | Path | None = None, *,
                   model_ref: str | None = None, out_label: str = "generated",
                   extra_cflags: Sequence[str] = (), compiler: str | None = None,
                   cache: str | Path | None = None) -> Generated:
    """Generate filter ``filter`` of ``model`` (a model, a catalog name or a model file)
    and load it: ``.python`` the module, ``.c`` the compiled wrappers.

    ``options`` are validated as by :func:`derive.generate`; ``model_ref`` and
    ``out_label`` name the model and output directory in the files' regenerate command;
    ``directory``: where ``MODEL/FILTER.*`` are written (default: a temporary one);
    ``extra_cflags``, ``compiler`` and ``cache`` (its ``tmpdir``): as
    :func:`derive.build.build_c` takes them.
    """
    check_lang(lang)
    if isinstance(model, str):
        model_ref = model_ref or model
        model = resolve_model(model)
    unit = command_unit(model, filter, options, model_ref, out_label)
    return load_units([unit], lang, directory, extra_cflags=extra_cflags,
                      compiler=compiler, cache=cache)[0]


__all__ = ["Generated", "load_generated", "load_units"]
