"""Subcommands of `derive`: one module each, discovered in name order.

A command module defines ``NAME``, ``HELP``, ``EXAMPLE`` (one or more example lines),
``add_arguments(parser)`` and ``run(args) -> int``; raising ModelError gives exit 2,
VerificationError exit 1 (see derive.cli).
"""

from __future__ import annotations

import importlib
import pkgutil


def modules():
    """The command modules, in the order the help lists them."""
    found = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        found.append(importlib.import_module(f"{__name__}.{info.name}"))
    return sorted(found, key=lambda m: (getattr(m, "ORDER", 50), m.NAME))


def load_model(ref: str):
    """A model by catalog name or model-file path (both errors are ModelErrors)."""
    from ..generation import resolve_model

    return resolve_model(ref)
