"""Generate filter code for a model: derive, render, write atomically.

``generate(model, filters, lang, out)`` writes ``OUT/MODEL/FILTER.py`` and
``OUT/MODEL/FILTER.{c,h}`` for each filter; every file of one call is rendered
before any is written, so a failure leaves the output directory untouched.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

from .emit.render import render_c, render_python
from .emit.write import write_files
from .errors import FilterError
from .filters import available, derive_unit

LANGS = ("python", "c", "all")


def resolve_model(model):
    """A model object from a model, a catalog name or a model-file path."""
    if not isinstance(model, str):
        return model
    from . import catalog

    if model.endswith(".toml") or "/" in model or "\\" in model:
        from .modelfile import load_model_file

        return load_model_file(model)
    return catalog.load(model)


def regenerate_command(model_ref: str, name: str, options: Mapping, out: str) -> str:
    """The command line that regenerates one filter's files."""
    parts = ["derive generate", model_ref, f"--filter {name}", "--lang all", f"--out {out}"]
    if options.get("eps") is not None and name == "fir":
        parts.append(f"--eps {options['eps']}")
    if options.get("N") is not None and name in ("fir", "pred"):
        parts.append(f"--horizon {options['N']}" if name == "pred" else f"--order {options['N']}")
    for key in ("alpha", "beta", "kappa"):
        if options.get(key) is not None and name == "ukf":
            parts.append(f"--{key} {options[key]}")
    if options.get("missing"):
        parts.append("--missing")
    if options.get("joseph") and name == "kf":
        parts.append("--joseph")
    if options.get("P0_pattern"):
        parts.append(f"--P0-pattern {options['P0_pattern']}")
    if options.get("run_tracks") is False:
        parts.append("--no-run-tracks")
    return " ".join(parts)


def render_filter(model, name: str, lang: str = "all", options: Mapping | None = None,
                  model_ref: str | None = None, out_label: str = "generated") -> dict[str, str]:
    """``{file name: text}`` for one filter (file names FILTER.py, FILTER.c, FILTER.h)."""
    if lang not in LANGS:
        raise FilterError(f"language {lang!r} is not one of {', '.join(LANGS)}")
    opts = dict(options or {})
    opts["command"] = regenerate_command(model_ref or model.name, name, opts, out_label)
    unit = derive_unit(model, name, opts)
    files: dict[str, str] = {}
    if lang in ("python", "all"):
        files.update(render_python(unit))
    if lang in ("c", "all"):
        files.update(render_c(unit))
    return files


def generate(model, filters: Iterable[str] | None = None, lang: str = "all",
             out: str | Path = "generated", options: Mapping | None = None,
             per_filter_options: Mapping[str, Mapping] | None = None) -> list[Path]:
    """Generate ``filters`` (default: all that apply) for ``model``; return the written paths.

    ``model`` is a model object, a catalog name or a model-file path. ``options``
    apply to every filter (``P0_pattern``, ``joseph``, ``eps``, ``N``, ``run_tracks``:
    False leaves ``MODEL_FILTER_run_tracks`` out of the C);
    ``per_filter_options`` override them per filter name.
    """
    ref = model if isinstance(model, str) else None
    model = resolve_model(model)
    names = list(filters) if filters is not None else available(model)
    files: dict[str, str] = {}
    for name in names:
        opts = {**dict(options or {}), **dict((per_filter_options or {}).get(name, {}))}
        files.update(render_filter(model, name, lang, opts, ref, str(out)))
    return write_files(out, model.name, files)
