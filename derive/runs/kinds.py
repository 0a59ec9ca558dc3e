"""One builder per run kind: the :class:`~derive.runs.loops.Run` of a unit, in no
language (the printers: :mod:`derive.emit.c_run`, :mod:`derive.emit.python_run`)."""

from __future__ import annotations

from collections.abc import Mapping

from derive.lowering import LoweredProgram
from derive.program import PARAMETER_PORT
from derive.runs.loops import (
    AfterFirst,
    Call,
    Columns,
    Output,
    Present,
    Record,
    Row,
    Run,
    State,
    Steps,
    Store,
)
from derive.runs.unit import Unit


def _parameters(unit: Unit) -> tuple:
    """p bound to its row k (run's p: one row for every step, or one per step)."""
    return ((PARAMETER_PORT, Row(PARAMETER_PORT, len(unit.parameters))),) \
        if unit.parameters else ()


def reads_whole(lowered: Mapping[str, LoweredProgram]) -> bool:
    """True when a program reads its symmetric P below the diagonal (vector rows): run then
    mirrors P0's upper triangle, so that P0 is read as everywhere else (upper triangle)."""
    return any(lp.reads_below_diagonal(port) for lp in lowered.values()
               for port in lp.inputs if port.symmetric)


def sensors(unit: Unit, lowered: Mapping[str, LoweredProgram]) -> Run:
    """The run kind ``sensors``: per step k, ``predict`` with u(k) (not at k = 0 with
    update-first), then each sensor's ``update_<sensor>`` in declaration order where its
    row k holds no NaN; x and P stored after the step and, for a gated sensor, its NIS
    (NaN where absent) and whether the update applied (1, else 0). The loop calls the
    unit's own functions, whose counts the header states; it adds no arithmetic."""
    n, nn = unit.n, unit.n * unit.n
    p = _parameters(unit)
    u = ((("u", Columns("u", unit.predict_inputs, unit.n_inputs)),)
         if unit.predict_inputs else ())
    predict = Call("predict", u + p, carry=True)
    body = [AfterFirst((predict,)) if unit.update_first else predict]
    records = []
    for s in unit.sensors:
        args = [("z", Row(f"z_{s.name}", s.m))]
        if s.R_argument:
            args.append(("R", Row(f"R_{s.name}", s.m * s.m, side=s.m)))
        if s.inputs:
            args.append(("u", Columns("u", s.inputs, unit.n_inputs)))
        inner = [Call(f"update_{s.name}", tuple(args) + p, carry=True)]
        missing = ()
        if s.gated:
            inner += [Record(f"nis_{s.name}", "nis"), Record(f"applied_{s.name}", "applied")]
            missing = (Record(f"nis_{s.name}", fill=True),
                       Record(f"applied_{s.name}", fill=True))
            records += [Output(f"nis_{s.name}", "nan"), Output(f"applied_{s.name}", "zero")]
        body.append(Present(f"z_{s.name}", s.m, s.name, tuple(inner), missing))
    body += [Store("xs", "x", n), Store("Ps", "P", nn, optional=True)]
    returns = [("xs", (n,)), ("Ps", (n, n))] + [(r.array, ()) for r in records]
    return Run((State("x", n, "x0"), State("P", nn, "P0", whole=reads_whole(lowered), side=n)),
               Steps(tuple(body)), tuple(records), tuple(returns))
