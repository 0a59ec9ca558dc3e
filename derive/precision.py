"""The floating-point precision of generated C: ``double`` (the default) or ``float``.

One :class:`Precision` says everything that depends on it, so that no emitter names a
type, a literal suffix or a math.h function of its own: the C element type, the suffix of
literals and of the math.h functions (``sqrtf``, ``sinf``), the macro that says a fast
fused multiply-add exists (``FP_FAST_FMA`` / ``FP_FAST_FMAF``), the least positive normal
number (a pivot floor: DBL_MIN / FLT_MIN), the unit roundoff u (2^-53 / 2^-24) and the
NumPy dtype of the arrays a compiled kernel takes.

A constant of the generated code is the double nearest its exact value (derive.lowering),
printed as itself in double code and rounded once more, to the nearest float, in float
code (:meth:`Precision.literal`); a constant that is not a normal float (zero after the
rounding, subnormal, or infinite) is refused rather than printed, so a double-specific
constant can never slip silently into float code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ModelError


class PrecisionError(ModelError):
    """A constant that the asked precision cannot hold (it would become 0, a subnormal or
    infinite), or an unknown precision name."""


@dataclass(frozen=True)
class Precision:
    """What generated C depends on in one precision (see the module docstring)."""

    name: str
    c_type: str
    suffix: str
    fast_fma: str
    least_normal: float
    c_least_normal: str
    unit_roundoff: float
    dtype: type
    bits: int

    @property
    def words(self) -> str:
        """``float32`` / ``float64``: the IEEE format, as headers and messages name it."""
        return f"float{self.bits}"

    def math(self, name: str) -> str:
        """The C99 math.h function ``name`` of this precision (``sqrt`` -> ``sqrtf``)."""
        return name + self.suffix

    def literal(self, value: float) -> str:
        """``value`` as a C floating constant of this type: the shortest decimal that reads
        back as the same number (``repr`` of the double; NumPy's shortest round trip of the
        float, with the ``f`` suffix), always with a ``.`` or an exponent."""
        if self.bits == 64:
            return repr(float(value))
        with np.errstate(over="ignore"):
            rounded = np.float32(value)
        if not np.isfinite(rounded) or (value != 0.0 and abs(rounded) < self.least_normal):
            raise PrecisionError(f"the constant {float(value)!r} is not a normal {self.words} "
                                 f"number (it rounds to {float(rounded)!r}): the model's "
                                 f"numbers must lie within [{self.least_normal!r}, "
                                 f"{float(np.finfo(np.float32).max)!r}] in magnitude for "
                                 f"--precision {self.name}")
        text = str(rounded)
        if "." not in text and "e" not in text and "inf" not in text:
            text += ".0"
        return text + self.suffix

    def zero(self) -> str:
        """The literal 0 of this type (``0.0`` / ``0.0f``)."""
        return "0.0" + self.suffix


DOUBLE = Precision(name="double", c_type="double", suffix="", fast_fma="FP_FAST_FMA",
                   least_normal=2.0**-1022, c_least_normal="DBL_MIN", unit_roundoff=2.0**-53,
                   dtype=np.float64, bits=64)
FLOAT = Precision(name="float", c_type="float", suffix="f", fast_fma="FP_FAST_FMAF",
                  least_normal=2.0**-126, c_least_normal="FLT_MIN", unit_roundoff=2.0**-24,
                  dtype=np.float32, bits=32)

PRECISIONS = {p.name: p for p in (DOUBLE, FLOAT)}
"""The precisions by the name the ``--precision`` option takes."""

NAMES = tuple(PRECISIONS)


def precision(name: str) -> Precision:
    """The :class:`Precision` named ``name`` (``double`` or ``float``)."""
    try:
        return PRECISIONS[name]
    except KeyError:
        raise PrecisionError(f"unknown precision {name!r}; expected one of "
                             f"{', '.join(NAMES)}") from None


__all__ = ["DOUBLE", "FLOAT", "NAMES", "PRECISIONS", "Precision", "PrecisionError",
           "precision"]
