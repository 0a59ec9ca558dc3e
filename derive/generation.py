"""Generate filter code for a model: validate the options, derive, render, write atomically.

``generate(model, filters, lang, out)`` writes ``OUT/MODEL/FILTER.py`` and
``OUT/MODEL/FILTER.{c,h}`` for each filter; every option of the call is validated
(derive.options) and every file rendered before any is written, so a failure leaves the
output directory untouched.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TypeVar

from . import catalog, progress
from .background import Job, stopped_on_failure
from .emit.render import render_c, render_python
from .emit.write import write_files
from .errors import FilterError, ModelFileError
from .filters import available, check_before_deriving, derive_unit, kind
from .filters.blockwise import whole_size
from .filters.sensors import uses_sensor_run
from .flops import LANGUAGES
from .model import ModelRef
from .modelfile import MAX_BLOCK_SIZE, load_model_file
from .options import SharedOptions, per_filter, python_command, regenerate_command, validate
from .runs.unit import Unit

#: What ``--lang`` chooses: each choice's languages (derive.flops.LANGUAGES, or all of them).
LANG_CHOICES = {"python": ("python",), "c": ("c",), "all": LANGUAGES}

#: What a caller of :func:`generate_summaries` says of each unit.
T = TypeVar("T")

#: A unit of this many statements or more is rendered in a background process while a
#: core is spare (about half a second to lower and print; below it, forking costs about
#: what it saves).
BACKGROUND_STATEMENTS = 2000


def is_model_file(ref: str) -> bool:
    """True when the model reference ``ref`` names a model file (not a catalog model)."""
    return ref.endswith(".toml") or "/" in ref or "\\" in ref


def resolve_model(model):
    """A model object from a model, a catalog name or a model-file path."""
    if not isinstance(model, str):
        return model
    if is_model_file(model):
        return load_model_file(model)
    return catalog.load(model)


def file_bound_refusal(model, name: str, options: SharedOptions, model_ref: str | None
                       ) -> str | None:
    """Why filter ``name`` is refused for the model of file ``model_ref``: the part of it
    the filter derives at once is larger than a model file may ask for
    (derive.modelfile.MAX_BLOCK_SIZE); None for a model given as an object or a catalog
    name, or within the bound."""
    if model_ref is None or not is_model_file(model_ref):
        return None
    spec = kind(name)
    pattern = getattr(options, "P0_pattern", None)
    # the run kind sensors (predict and one update per sensor) derives the model whole
    sensor_run = spec.sensors and uses_sensor_run(model, options)
    size = max(model.n, model.m) if sensor_run else whole_size(model, spec, pattern)
    if size <= MAX_BLOCK_SIZE:
        return None
    why = ("its P0 pattern dense couples the blocks"
           if spec.blockwise and spec.covariance and not sensor_run
           else "it derives the model whole, not block by block")
    return (f"{model_ref}: filter {name!r} would derive {size} states or measurements at "
            f"once ({why}), more than the limit of {MAX_BLOCK_SIZE} for a model file")


def check_lang(lang: str) -> None:
    """FilterError unless ``lang`` is one of :data:`LANG_CHOICES`."""
    if lang not in LANG_CHOICES:
        raise FilterError(f"language {lang!r} is not one of {', '.join(LANG_CHOICES)}")


def command_unit(model, name: str, options: Mapping | SharedOptions | None = None,
                 model_ref: str | None = None, out_label: str = "generated",
                 lang: str = "all") -> Unit:
    """The Unit of one filter, its options validated, carrying the command that
    regenerates its files (``derive generate MODEL_REF ... --lang LANG --out OUT_LABEL``)."""
    typed = validate(name, options)
    refusal = file_bound_refusal(model, name, typed, model_ref)
    if refusal is not None:
        raise ModelFileError(refusal)
    unit = derive_unit(model, name, typed)
    command = (regenerate_command(model_ref, name, typed, out_label, lang) if model_ref
               else python_command(model, name, typed, out_label, lang))
    return dataclasses.replace(unit, command=command)


def render_unit(model, name: str, lang: str = "all",
                options: Mapping | SharedOptions | None = None, model_ref: str | None = None,
                out_label: str = "generated") -> tuple[Unit, dict[str, str]]:
    """(the Unit, ``{file name: text}``) of one filter; ``options``: those it takes."""
    check_lang(lang)
    unit = command_unit(model, name, options, model_ref, out_label, lang)
    return unit, _collected(_rendering(unit, lang, more=False))


def _rendering(unit: Unit, lang: str, more: bool) -> list[Job]:
    """The renderings of ``unit`` in ``lang``, started. For a unit of at least
    :data:`BACKGROUND_STATEMENTS` statements the first goes to a background process while
    a core is spare (derive.background) when this process has other work meanwhile: the
    second rendering, or (``more``) the next filter's derivation."""
    renderers = ([render_python] if lang in ("python", "all") else []) + \
        ([render_c] if lang in ("c", "all") else [])
    large = sum(len(program.body) for program in unit.programs.values()) \
        >= BACKGROUND_STATEMENTS
    return [Job(render, unit, background=large and k == 0 and (len(renderers) > 1 or more))
            for k, render in enumerate(renderers)]


def _collected(jobs: list[Job]) -> dict[str, str]:
    """``{file name: text}`` of the renderings ``jobs``, in their order; on any failure
    (or Ctrl-C) the background ones still running are stopped."""
    files: dict[str, str] = {}
    with stopped_on_failure(jobs):
        for job in jobs:
            files.update(job.result())
    return files


def render_filter(model, name: str, lang: str = "all",
                  options: Mapping | SharedOptions | None = None, model_ref: str | None = None,
                  out_label: str = "generated") -> dict[str, str]:
    """``{file name: text}`` for one filter (file names FILTER.py, FILTER.c, FILTER.h)."""
    return render_unit(model, name, lang, options, model_ref, out_label)[1]


def generate_units(model, filters: Iterable[str] | None = None, lang: str = "all",
                   out: str | Path = "generated", options: Mapping | None = None,
                   per_filter_options: Mapping[str, Mapping] | None = None
                   ) -> tuple[list[Path], list[Unit]]:
    """:func:`generate`, also returning the derived units (e.g. to report a FIR's order).
    The filters are derived here, one after the other; each one's renderings run beside
    the next one's derivation where a core is spare (derive.background)."""
    model, names, typed, ref = _planned(model, filters, lang, options, per_filter_options)
    units = []
    with stopped_on_failure([]) as jobs:
        for k, name in enumerate(names):
            unit = command_unit(model, name, typed[name], ref, str(out), lang)
            units.append(unit)
            jobs += _rendering(unit, lang, more=k < len(names) - 1)
    return write_files(out, model.name, _collected(jobs)), units


def generate_summaries(model, filters: Iterable[str] | None = None, lang: str = "all",
                       out: str | Path = "generated", options: Mapping | None = None,
                       per_filter_options: Mapping[str, Mapping] | None = None,
                       summary: Callable[[Unit], T] | None = None
                       ) -> tuple[list[Path], list[T | None]]:
    """:func:`generate`, also returning ``summary(unit)`` of each filter's unit (None
    without ``summary``). For a model of at least ``progress.LARGE_MODEL_STATES`` states
    each filter is derived and rendered in a background process while a core is spare
    (derive.background), so its filters derive side by side; a unit stays where it was
    derived, only its files and its summary come back (``summary``'s value must
    pickle)."""
    model, names, typed, ref = _planned(model, filters, lang, options, per_filter_options)
    large = model.n >= progress.LARGE_MODEL_STATES
    with stopped_on_failure([]) as jobs:
        for k, name in enumerate(names):   # the last here: this process has nothing else to do
            jobs.append(Job(_summarised_files, model, name, lang, typed[name], ref, str(out),
                            summary, background=large and k < len(names) - 1))
        done = [job.result() for job in jobs]
    files: dict[str, str] = {}
    for texts, _ in done:
        files.update(texts)
    return write_files(out, model.name, files), [said for _, said in done]


def _summarised_files(model, name: str, lang: str, options: SharedOptions,
                      model_ref: str | None, out_label: str,
                      summary: Callable[[Unit], T] | None) -> tuple[dict[str, str], T | None]:
    unit, files = render_unit(model, name, lang, options, model_ref, out_label)
    return files, summary(unit) if summary is not None else None


def _planned(model, filters: Iterable[str] | None, lang: str, options: Mapping | None,
             per_filter_options: Mapping[str, Mapping] | None):
    """(the model, the names of the filters to derive, their typed options, the model
    file's path or None), every name, option and refusal checked before any derivation."""
    ref = model if isinstance(model, str) else None
    model = resolve_model(model)
    check_lang(lang)
    if isinstance(filters, str):  # one name, not its characters
        filters = [filters]
    names = list(filters) if filters is not None else available(model)
    for name in names:
        kind(name)
    typed = per_filter(names, options, per_filter_options, named=filters is not None)
    if filters is None:  # all that apply: those within a model file's bound
        names = [name for name in names
                 if file_bound_refusal(model, name, typed[name], ref) is None]
    check_before_deriving(model, names, typed, named=filters is not None)
    return model, names, typed, ref


def generate(model: ModelRef, filters: Iterable[str] | None = None, lang: str = "all",
             out: str | Path = "generated", options: Mapping | None = None,
             per_filter_options: Mapping[str, Mapping] | None = None) -> list[Path]:
    """Generate ``filters`` (default: all that apply) for ``model``; return the written paths.

    ``filters``: names (``["kf", "rts"]``) or one name (``"kf"``); an unknown name is
    refused with the closest filter's name (case aside: ``"KF"``: did you mean 'kf'?).

    ``model`` is a model object, a catalog name or a model-file path. ``options`` apply
    to the call: each filter is given those it takes (``P0_pattern``, ``missing``,
    ``run_tracks``: False leaves ``MODEL_FILTER_run_tracks`` out of the C; ``joseph``
    (kf); ``eps``, ``order`` (fir); ``horizon`` (pred); ``alpha``, ``beta``, ``kappa``
    (ukf); see derive.options and ``derive generate --help``). When ``filters`` are
    named, an option none of them takes is refused. ``per_filter_options`` name one
    filter each, and every key must be one that filter takes. Unknown names, wrong
    types and values out of range raise derive.errors.OptionError.
    """
    return generate_summaries(model, filters, lang, out, options, per_filter_options)[0]
