"""The report as data: sections of text, tables, figures and preformatted text.

Sections are rendered twice from the same blocks (:mod:`derive.apps.report.page`): as
Markdown (``index.md``) and as HTML (``index.html``), so the two never disagree.
Inline markup in text and table cells is limited to ``code`` and **bold**.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Text:
    """A paragraph."""

    text: str


@dataclass(frozen=True)
class Table:
    """A table: column heads, rows of cells (strings), an optional caption above it."""

    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""
    collapsed: bool = False     # long reference tables: folded in HTML (<details>)

    def __post_init__(self):
        for row in self.rows:
            if len(row) != len(self.columns):
                raise ValueError(f"table {self.caption!r}: row {row!r} has {len(row)} cells, "
                                 f"expected {len(self.columns)}")


@dataclass(frozen=True)
class Figure:
    """A PNG figure; ``path`` is relative to the report directory."""

    path: str
    caption: str


@dataclass(frozen=True)
class Preformatted:
    """Text shown as is (command output, tables printed by other tools); ``caption`` names
    it, and the HTML page folds it (a raw dump is reference material, not a result)."""

    text: str
    caption: str = "console output"


MATCHED = "matched"
DIFFERS = "differs"
NOT_COMPARABLE = "not comparable"


@dataclass(frozen=True)
class Outcome:
    """One line of the report's summary: a claim or number of a paper, whether this run
    matched it (``MATCHED``, ``DIFFERS`` or ``NOT_COMPARABLE``), and the measured evidence
    or the reason, computed by the run."""

    what: str
    verdict: str
    evidence: str

    def __post_init__(self):
        if self.verdict not in (MATCHED, DIFFERS, NOT_COMPARABLE):
            raise ValueError(f"outcome {self.what!r}: unknown verdict {self.verdict!r}")


@dataclass(frozen=True)
class Todo:
    """Work that is not done yet, shown prominently (never a number in its place)."""

    text: str


Block = Text | Table | Figure | Preformatted | Todo


@dataclass
class Section:
    """A titled part of the report; ``key`` names it in summaries and file names."""

    key: str
    title: str
    blocks: list[Block] = field(default_factory=list)
    outcomes: list[Outcome] = field(default_factory=list)
    paper: str = ""          # the paper the section reproduces ("" for derive's own checks)

    def add(self, *blocks: Block) -> None:
        self.blocks.extend(blocks)

    @property
    def short(self) -> str:
        """The title up to its colon ("MPT3D", "Appendix"): the summary's link text."""
        return self.title.split(":")[0]

    def outcome(self, what: str, verdict: str, evidence: str) -> None:
        """Record a line for the summary (see :class:`Outcome`)."""
        self.outcomes.append(Outcome(what, verdict, evidence))

    @property
    def figures(self) -> list[Figure]:
        return [b for b in self.blocks if isinstance(b, Figure)]

    @property
    def tables(self) -> list[Table]:
        return [b for b in self.blocks if isinstance(b, Table)]

    @property
    def todos(self) -> list[Todo]:
        return [b for b in self.blocks if isinstance(b, Todo)]


def fmt(value: float, digits: int = 3) -> str:
    """A number for a table cell: fixed for moderate magnitudes, else scientific."""
    if value != value:  # NaN
        return "–"
    if value == 0:
        return "0"
    if 1e-3 <= abs(value) < 1e5:
        return f"{value:.{digits}f}"
    return f"{value:.{max(digits - 1, 1)}e}"


def sci(value: float, digits: int = 1) -> str:
    """Scientific notation for differences and errors."""
    return "–" if value != value else f"{value:.{digits}e}"
