"""The models of the papers (MPT3D, GSM2D, MDKF, SSPRED, GNSS), shipped as model files
(see derive.modelfile).

The files are package data; derive.catalog_files finds and reads them (names, label,
read_text, path, gathered here), this package loads them as models.
"""

from __future__ import annotations

from derive.catalog_files import label, names, path, read_text
from derive.modelfile import loads_model


def load(name: str):
    """The model `name` of the catalog, as a LinearModel or NonlinearModel."""
    return loads_model(read_text(name), source=label(name))


__all__ = ["label", "load", "names", "path", "read_text"]
