"""What a run does, as data: a few node types that each language's printer prints
(:mod:`derive.emit.c_run`, :mod:`derive.emit.python_run`).

A :class:`Run` starts its carried :class:`State` from run's arguments, then loops over
the steps (:class:`Steps`, up or down, one loop after another); each step calls the
unit's programs (:class:`Call`) with their ports bound to run's rows (:class:`Row`), the
state a loop carries (:class:`Carried`) or columns of run's inputs (:class:`Columns`),
guards some of them (:class:`Present`: row k of a measurement holds no NaN;
:class:`AfterFirst`: every step but the first) and stores rows of run's outputs
(:class:`Store`, :class:`Copy`, :class:`Record`). The nodes name programs and ports,
never a language's spelling: a printer decides how an array is declared, how a call
returns its outputs and how a missing row keeps the state (a branch in C, a mask over
the tracks in Python).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Row:
    """Row ``row`` (``k``, the step; ``k + 1``, ``steps - 1``; ``""``: the whole argument,
    as a flat array) of the run array ``array``:
    ``size`` elements from ``offset`` in rows of ``stride`` elements (0: rows of ``size``);
    ``side``: a row is a square matrix of that side (read flat, row-major)."""

    array: str
    size: int
    row: str = "k"
    side: int = 0
    offset: int = 0
    stride: int = 0


@dataclass(frozen=True)
class Carried:
    """The state ``name`` a loop carries from one step to the next, kept at ``row`` (the
    previous step's row), and at the loop's first step run's argument ``start`` (none: the
    loop starts from ``name`` as it stands)."""

    name: str
    row: Row
    start: str = ""


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


@dataclass(frozen=True)
class Window:
    """The last ``window`` rows of the run array ``array`` up to row k (``size`` elements a
    row), newest first, as one flat array; rows before the first are zero."""

    array: str
    size: int
    window: int


#: What a program's input port is bound to: a carried state's (or a local array's) name,
#: a row of a run array, the state a loop carries, columns of the inputs, or a window.
Source = str | Row | Carried | Columns | Window


@dataclass(frozen=True)
class Call:
    """A call of the unit's program ``program``, each input port read from its binding in
    ``args`` (a port not bound: the array of its own name). ``carry``: the carried state
    becomes the program's outputs of the same names with ``_new`` (x from x_new, P from
    P_new; :attr:`State.out`). ``into``: output ports written to rows of run's arrays, or
    (a row ``""``) to a local array, each (port, row, the name of the state it becomes)."""

    program: str
    args: tuple[tuple[str, Source], ...] = ()
    carry: bool = False
    into: tuple[tuple[str, Row, str], ...] = ()
    #: the program's statements inline over run's local arrays (its body), not a call
    body: bool = False


@dataclass(frozen=True)
class Copy:
    """Row ``target`` is row ``source``: the state ``name``."""

    target: Row
    source: Row
    name: str


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
    """Row ``row`` of run's output ``array`` is the carried state ``state`` (``size``
    elements), or with ``program`` that program's output from the carried state (P from
    its factors); ``optional``: the caller may leave the array out."""

    array: str
    state: str
    size: int
    optional: bool = False
    row: str = "k"
    program: str = ""


@dataclass(frozen=True)
class Steps:
    """The loop over the steps, k from 0 up (``down``: from ``steps - down`` down to 0),
    ``by`` steps a pass (the last steps, fewer, are left to the next loop, which goes on
    from where this one stopped: ``rest``); ``first``: step 0 alone (when there is one);
    ``start``: k from ``start`` up (the loop after a ``first`` one: an update-first run of
    a step that fuses the prediction and the update calls its update alone at step 0);
    ``note``: what the loop is, for a reader of the generated code."""

    body: tuple[Node, ...]
    down: int = 0
    note: str = ""
    by: int = 1
    rest: bool = False
    first: bool = False
    start: int = 0


@dataclass(frozen=True)
class AnySteps:
    """``body`` when there is at least one step."""

    body: tuple[Node, ...]
    note: str = ""


@dataclass(frozen=True)
class Work:
    """A scratch array of one row per step, holding the output ports ``ports`` (name,
    size) in order (C: the caller's; Python: run's own); ``note``: what a row holds."""

    array: str
    ports: tuple[tuple[str, int], ...]
    note: str = ""

    @property
    def row(self) -> int:
        return sum(size for _, size in self.ports)

    def slot(self, port: str, row: str) -> Row:
        """Where row ``row`` holds ``port``."""
        offset = 0
        for name, size in self.ports:
            if name == port:
                return Row(self.array, size, row, offset=offset, stride=self.row)
            offset += size
        raise KeyError(port)


@dataclass(frozen=True)
class State:
    """A carried array: ``size`` elements started from run's argument ``start`` (a matrix
    of side ``side``); ``whole``: a symmetric matrix read whole by the programs, started
    from the upper triangle of ``start`` mirrored (run reads a symmetric argument's upper
    triangle); ``out``: the output port of the step that becomes it (``NAME_new``)."""

    name: str
    size: int
    start: str
    whole: bool = False
    side: int = 0
    out: str = ""

    @property
    def new(self) -> str:
        return self.out or f"{self.name}_new"


@dataclass(frozen=True)
class Output:
    """A per-step output of run that the loop records (:class:`Record`): ``fill`` is what a
    step without its value holds (``nan`` or ``zero``)."""

    array: str
    fill: str


@dataclass(frozen=True)
class InLanes:
    """A run's identical blocks in the lanes of one vector of ``width`` elements (the pass
    :func:`derive.runs.blocks.in_lanes`): ``blocks``, each called program's split into
    blocks (a :class:`derive.runs.blocks.Lanes`); ``carried``, the vectors the loop carries
    (a carried port and the element of it each lane holds); ``sources``, per program, the
    output that becomes each carried vector (its port and the block's local index)."""

    width: int
    blocks: tuple[tuple[str, object], ...]
    carried: tuple[tuple[str, tuple[int, ...]], ...]
    sources: tuple[tuple[str, tuple[tuple[str, int], ...]], ...]


@dataclass(frozen=True)
class Run:
    """A whole run: its carried state, the outputs it records, the loops; ``returns``:
    run's outputs in order, with the shape each is returned in (Python); ``work``: its
    scratch rows."""

    states: tuple[State, ...]
    loops: tuple[Node, ...]
    records: tuple[Output, ...] = ()
    returns: tuple[tuple[str, tuple[int, ...]], ...] = ()
    work: Work | None = None
    #: the call whose outputs start the carried state (an init or enter program), if any
    enter: Call | None = None
    #: the identical blocks carried in the lanes of one vector, where a pass put them
    lanes: InLanes | None = None
    #: the step with what identical blocks starting equal share computed once
    #: (derive.runs.shared.SharedStep), where the pass found some
    shared: object = None


Node = Call | Copy | Record | Present | AfterFirst | Store | Steps | AnySteps


def walk(nodes: tuple[Node, ...]):
    """Every node of ``nodes``, depth first, the nodes inside a guard or a loop included."""
    for node in nodes:
        yield node
        if isinstance(node, (Present, AfterFirst, Steps, AnySteps)):
            yield from walk(node.body)
        if isinstance(node, Present):
            yield from walk(node.missing)
