"""The catalog's model files: their names, how errors name them, their text and path.

The files are package data of derive/catalog/, read with importlib.resources through the
``derive`` package, so an installed (non-editable) package works too. This module sits
below both derive.catalog (which loads the files as models) and derive.modelfile (whose
``[compose]`` blocks name catalog models): it imports neither.
"""

from __future__ import annotations

import difflib
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from derive.errors import ModelError


def _folder() -> Traversable:
    return resources.files("derive").joinpath("catalog")


def names() -> list[str]:
    """The catalog's model names, sorted."""
    return sorted(
        entry.name[: -len(".toml")]
        for entry in _folder().iterdir()
        if entry.name.endswith(".toml") and entry.is_file()
    )


def label(name: str) -> str:
    """How a catalog model is named in error messages."""
    return f"<catalog>/{name}.toml"


def read_text(name: str) -> str:
    """The model file text of catalog model `name`."""
    available = names()
    if name not in available:
        close = difflib.get_close_matches(str(name), available, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ModelError(f"unknown catalog model {name!r}{hint}; available: "
                         f"{', '.join(available)}")
    return _folder().joinpath(f"{name}.toml").read_text(encoding="utf-8")


def path(name: str) -> Path:
    """The file of catalog model `name` (a real path when the package is installed as
    files, which is what pip does)."""
    read_text(name)  # validates the name
    return Path(str(_folder().joinpath(f"{name}.toml")))


__all__ = ["label", "names", "path", "read_text"]
