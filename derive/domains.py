"""Declared domains of a model's free parameters, and the check of their values.

A free symbol may declare that its values are nonnegative or positive: through sympy's
assumptions (``sympy.Symbol("dt", nonnegative=True)``, ``positive=True``) or, in a model
file, ``domain = "nonnegative"`` in its ``[parameters.NAME]`` table, which makes the
symbol with that assumption. Generated code checks each declared parameter it reads
(:meth:`derive.program.Program.bind`); the NumPy references and the models' numbers
refuse the same values (:func:`check_row`, :func:`check_rows`) with the same message.
Other assumptions (negative, nonzero, integer, ...) are not checked. The checks of
numbers need no SymPy (derive.build and the references import this module).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from derive.errors import DomainError

if TYPE_CHECKING:  # read from symbols' assumptions; this module itself needs no SymPy
    import sympy

NONNEGATIVE, POSITIVE = "nonnegative", "positive"
#: The domains a parameter may declare (a model file's ``domain`` key).
DOMAINS = (NONNEGATIVE, POSITIVE)


def declared_domain(symbol: sympy.Symbol) -> str | None:
    """``"positive"``, ``"nonnegative"`` or None: what ``symbol``'s assumptions declare."""
    if symbol.is_positive:
        return POSITIVE
    if symbol.is_nonnegative:
        return NONNEGATIVE
    return None


def domain_message(name: str, domain: str) -> str:
    """What a value of parameter ``name`` outside ``domain`` is told (the C status line;
    Python adds the value)."""
    return f"parameter {name} must be {domain}"


def holds(value: float, domain: str) -> bool:
    """True when ``value`` lies in ``domain`` (a NaN never does)."""
    return bool(value > 0) if domain == POSITIVE else bool(value >= 0)


def parameter_domains(parameters: Sequence[sympy.Symbol]) -> tuple[tuple[int, str, str], ...]:
    """``(index in p, name, domain)`` of each parameter that declares a domain."""
    return tuple((k, s.name, domain) for k, s in enumerate(parameters)
                 if (domain := declared_domain(s)) is not None)


def check_row(domains: Sequence[tuple[int, str, str]], row, where: str = "") -> None:
    """Raise DomainError unless every declared parameter of the row ``row`` of p lies in
    its domain: ``{where}parameter dt must be nonnegative, got -0.5``."""
    values = np.ravel(np.asarray(row, dtype=float))
    for index, name, domain in domains:
        value = float(values[index])
        if not holds(value, domain):
            raise DomainError(f"{where}{domain_message(name, domain)}, got {value!r}")


def check_rows(domains: Sequence[tuple[int, str, str]], rows) -> None:
    """:func:`check_row` of each row of ``rows`` (one row of p, or one per step), naming
    the step of the first that fails (``step 3: ...``)."""
    if not domains or rows is None:
        return
    array = np.asarray(rows, dtype=float)
    for k, row in enumerate(array if array.ndim == 2 else [array]):
        check_row(domains, row, f"step {k}: ")


def check_value(symbol: sympy.Symbol, value, what: str) -> None:
    """Raise DomainError when the number ``value`` given for ``symbol`` (``what``: where it
    was given) lies outside the domain the symbol declares."""
    domain = declared_domain(symbol)
    if domain is None:
        return
    try:
        number = float(value)
    except (TypeError, ValueError):  # symbolic: not a number to check
        return
    if not holds(number, domain):
        raise DomainError(f"{what}: {domain_message(symbol.name, domain)}, got {number!r}")


__all__ = ["DOMAINS", "NONNEGATIVE", "POSITIVE", "check_row", "check_rows", "check_value",
           "declared_domain", "domain_message", "holds",
           "parameter_domains"]
