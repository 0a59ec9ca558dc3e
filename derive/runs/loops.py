"""What a run does, as data: a few node types that each language's printer prints
(:mod:`derive.emit.c_run`, :mod:`derive.emit.python_run`).

A :class:`Run` starts its carried :class:`State` from run's arguments, then loops over
the steps (:class:`Steps`); each step calls the unit's programs (:class:`Call`) with
their ports bound to run's rows, the state or the columns of run's inputs, guards some
of them (:class:`Present`: row k of a measurement holds no NaN; :class:`AfterFirst`:
every step but the first) and stores rows of run's outputs (:class:`Store`,
:class:`Record`). The nodes name programs and ports, never a language's spelling: a
printer decides how an array is declared, how a call returns its outputs and how a
missing row keeps the state (a branch in C, a mask over the tracks in Python).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Row:
    """Row ``row`` (``k``, the step) of the run array ``array``, ``size`` elements a row;
    ``side``: a row is a square matrix of that side (read flat, row-major)."""

    array: str
    size: int
    row: str = "k"
    side: int = 0


@dataclass(frozen=True)
class Columns:
    """The columns ``columns`` of row k of run's inputs ``array`` (``width`` a row): a
    program's share of the model's inputs; all of them in order is the row itself."""

    array: str
    columns: tuple[int, ...]
    width: int

    @property
    def whole(self) -> bool:
        return list(self.columns) == list(range(self.width))


#: What a program's input port is bound to: a carried state's (or a local array's) name,
#: a row of a run array, or columns of the inputs.
Source = str | Row | Columns


@dataclass(frozen=True)
class Call:
    """A call of the unit's program ``program``, each input port read from its binding in
    ``args`` (a port not bound: the array of its own name). ``carry``: the carried state
    becomes the program's outputs of the same names with ``_new`` (x from x_new, P from
    P_new)."""

    program: str
    args: tuple[tuple[str, Source], ...] = ()
    carry: bool = False


@dataclass(frozen=True)
class Record:
    """Step k's element of the per-step output ``array`` (``steps`` elements; run's caller
    may leave it out) is the first element of the output port ``value`` of the call
    before it, or, with ``fill``, the array's fill value (where the call did not run)."""

    array: str
    value: str = ""
    fill: bool = False


@dataclass(frozen=True)
class Present:
    """``body`` when row k of the per-step input ``array`` (``size`` elements) holds no NaN
    (a measurement of ``sensor``); the tracks or the steps without it keep their state,
    and their ``missing`` records are filled."""

    array: str
    size: int
    sensor: str
    body: tuple[Node, ...]
    missing: tuple[Record, ...] = ()


@dataclass(frozen=True)
class AfterFirst:
    """``body`` at every step but the first (an update-first run predicts from step 1)."""

    body: tuple[Node, ...]


@dataclass(frozen=True)
class Store:
    """Row k of run's output ``array`` is the carried state ``state`` (``size`` elements);
    ``optional``: the caller may leave the array out."""

    array: str
    state: str
    size: int
    optional: bool = False


@dataclass(frozen=True)
class Steps:
    """The loop over the steps, k from 0."""

    body: tuple[Node, ...]


@dataclass(frozen=True)
class State:
    """A carried array: ``size`` elements started from run's argument ``start``; ``whole``:
    a symmetric matrix of side ``side`` read whole by the programs, started from the upper
    triangle of ``start`` mirrored (run reads a symmetric argument's upper triangle)."""

    name: str
    size: int
    start: str
    whole: bool = False
    side: int = 0


@dataclass(frozen=True)
class Output:
    """A per-step output of run that the loop records (:class:`Record`): ``fill`` is what a
    step without its value holds (``nan`` or ``zero``)."""

    array: str
    fill: str


@dataclass(frozen=True)
class Run:
    """A whole run: its carried state, the outputs it records, the step loop; ``returns``:
    run's outputs in order, with the shape each is returned in (Python)."""

    states: tuple[State, ...]
    loop: Steps
    records: tuple[Output, ...] = ()
    returns: tuple[tuple[str, tuple[int, ...]], ...] = ()


Node = Call | Record | Present | AfterFirst | Store | Steps


def walk(nodes: tuple[Node, ...]):
    """Every node of ``nodes``, depth first, the nodes inside a guard or a loop included."""
    for node in nodes:
        yield node
        if isinstance(node, (Present, AfterFirst, Steps)):
            yield from walk(node.body)
        if isinstance(node, Present):
            yield from walk(node.missing)
