"""The models of the papers (MPT3D, GSM2D, MDKF, SSPRED, GNSS), shipped as model files
(see derive.modelfile).

The files are package data read with importlib.resources, so an installed (non-editable)
package works too.
"""

from __future__ import annotations

import difflib
from importlib import resources
from pathlib import Path

from derive.errors import ModelError
from derive.modelfile import loads_model


def names() -> list[str]:
    """The catalog's model names, sorted."""
    return sorted(
        entry.name[: -len(".toml")]
        for entry in resources.files(__name__).iterdir()
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
    return resources.files(__name__).joinpath(f"{name}.toml").read_text(encoding="utf-8")


def path(name: str) -> Path:
    """The file of catalog model `name` (a real path when the package is installed as
    files, which is what pip does)."""
    read_text(name)  # validates the name
    return Path(str(resources.files(__name__).joinpath(f"{name}.toml")))


def load(name: str):
    """The model `name` of the catalog, as a LinearModel or NonlinearModel."""
    return loads_model(read_text(name), source=label(name))
