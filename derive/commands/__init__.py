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


def add_filter_options(parser) -> None:
    """The filter options' flags (derive.options), for the commands that take them; their
    help names the filters that take each option, from the registry (derive.filters)."""
    # here, not at the top: the registry loads SymPy and every filter family, which only
    # the commands that take filter options need, and only when their parser is built
    from .. import filters  # noqa: F401  (builds the registry the options' help reads)
    from ..options import add_arguments

    add_arguments(parser)


def load_model(ref: str):
    """A model by catalog name or model-file path (both errors are ModelErrors)."""
    from ..generation import resolve_model  # here: only the commands that load a model

    return resolve_model(ref)
