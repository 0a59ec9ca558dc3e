"""Two steps per pass for the run loop of an affine step with constant coefficients.

A steady-state filter's step is ``x(k+1) = A x(k) + B z(k)``; in a run loop each step
waits for the previous one, so the loop runs at the latency of that chain (two
dependent fmas for a two-state axis), however wide the machine.  Composing the step
with itself gives the two-step map

    x(k+2) = A² x(k) + A B z(k) + B z(k+1)

whose chain from x(k) is as deep as one step's: a run loop that computes x(k+1) with the
step (exactly as ``step`` does, bit for bit) and x(k+2) with the two-step map carries
only x(k+2) from pass to pass, halving the latency per step (the classic look-ahead of
recursive digital filters).

The derivation builds the map from its exact A and B (derive.filters.steady.
two_step_program: the products of the baked doubles taken exactly, rounded once when
printed) and hands it over as ``Unit.lookahead``; nothing here recovers it from the
step's expressions.
"""

from __future__ import annotations

from derive.program import Program
from derive.runs.unit import LOOKAHEAD_NEXT, Unit

#: The port of the second measurement row (z is row k, ZNEXT row k + 1).
ZNEXT = LOOKAHEAD_NEXT


def run_pass(unit: Unit) -> tuple[Program, int]:
    """(program, steps) of the carried chain of one pass of the generated C run loop of
    ``unit``: its two-step map (x(k+1) beside it is not carried), else the step itself."""
    if unit.lookahead is not None:
        return unit.lookahead, 2
    return unit.programs["step"], 1
