"""Render the report's sections as ``index.md`` and a self-contained ``index.html``.

Both open with the summary (one row per outcome, each linking to its section), then the
sections in order, then the provenance footer. In HTML the figures are embedded as
``data:`` URIs (the page alone is the unit to copy; ``index.md`` needs ``figures/``
beside it), long reference tables and console dumps are folded in ``<details>``, text
columns are left-aligned and numeric columns right-aligned and never wrapped.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Sequence
from pathlib import Path

from .document import (
    DIFFERS,
    MATCHED,
    NOT_COMPARABLE,
    Figure,
    Outcome,
    Preformatted,
    Section,
    Table,
    Text,
    Todo,
)
from .provenance import Provenance

_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*([^*]+)\*\*")
# A number, a range or a list of numbers, optionally signed, scientific, with a short unit.
_NUMBER = re.compile(r"[-−+]?\d[\d.,]*(e[-−+]?\d+)?"
                     r"(\s*([-−–×x/]|,\s)\s*[-−+]?\d[\d.,]*(e[-−+]?\d+)?)*"
                     r"(\s?(m|s|ns|%|m/s))?")
_EMPTY = {"", "–", "-"}
# A number in scientific notation inside text: kept on one line ("1e-⏎06" never).
_SCIENTIFIC = re.compile(r"(?<![\w.])[-−]?\d+(\.\d+)?e[-−+]?\d+\b")

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 72rem; margin: 2rem auto;
       padding: 0 1rem; line-height: 1.45; color: #222; }
table { border-collapse: collapse; margin: 0.5rem 0 1.2rem; font-size: 0.9rem; }
th, td { border: 1px solid #bbb; padding: 0.2rem 0.5rem; text-align: left;
         vertical-align: top; }
th { background: #eee; }
.nb { white-space: nowrap; }
td.num, th.num { text-align: right; white-space: nowrap;
                 font-variant-numeric: tabular-nums; }
caption { caption-side: top; text-align: left; font-weight: 600; padding: 0.3rem 0; }
figure { margin: 1rem 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9rem; color: #444; }
pre { background: #f6f6f6; padding: 0.6rem; overflow-x: auto; font-size: 0.75rem;
      max-width: 100%; }
details { margin: 0.5rem 0 1rem; } summary { cursor: pointer; font-weight: 600; }
.todo { background: #fff3cd; border-left: 4px solid #e0a800; padding: 0.5rem; }
.matched { color: #1a6b1a; font-weight: 600; } .differs { color: #a40000; font-weight: 600; }
.not-comparable { color: #8a5a00; font-weight: 600; }
.matched, .differs, .not-comparable { white-space: nowrap; }
nav ol { columns: 2; } nav li { margin: 0.1rem 0; }
footer { margin-top: 3rem; border-top: 1px solid #bbb; font-size: 0.85rem; color: #444; }
footer dt { font-weight: 600; float: left; width: 6rem; } footer dd { margin-left: 6.5rem; }
"""

SUMMARY_COLUMNS = ("paper", "claim or number", "verdict", "measured / why", "section")


def _inline_html(text: str, keep_numbers_whole: bool = True) -> str:
    out = html.escape(text, quote=False)
    if keep_numbers_whole:   # (a numeric table cell is unwrapped as a whole)
        out = _SCIENTIFIC.sub(lambda m: f'<span class="nb">{m.group(0)}</span>', out)
    out = _CODE.sub(lambda m: f"<code>{m.group(1)}</code>", out)
    return _BOLD.sub(lambda m: f"<strong>{m.group(1)}</strong>", out)


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def is_number(cell: str) -> bool:
    """A cell that holds a number, a range or list of numbers (bold or not), or a dash."""
    text = cell.replace("**", "").strip()
    return text in _EMPTY or _NUMBER.fullmatch(text) is not None


def numeric_columns(table: Table) -> list[bool]:
    """Per column: every cell a number (and at least one that is not a dash)."""
    return [bool(table.rows)
            and all(is_number(row[i]) for row in table.rows)
            and any(row[i].replace("**", "").strip() not in _EMPTY for row in table.rows)
            for i in range(len(table.columns))]


def outcomes(sections: Sequence[Section]) -> list[tuple[Section, Outcome]]:
    return [(s, o) for s in sections for o in s.outcomes]


def tally(sections: Sequence[Section]) -> dict[str, int]:
    """{verdict: how many outcomes}."""
    counts = {MATCHED: 0, DIFFERS: 0, NOT_COMPARABLE: 0}
    for _, o in outcomes(sections):
        counts[o.verdict] += 1
    return counts


def tally_text(sections: Sequence[Section]) -> str:
    c = tally(sections)
    return (f"{c[MATCHED]} matched, {c[DIFFERS]} differ, {c[NOT_COMPARABLE]} not comparable "
            "(the papers' data or settings unknown)")


def summary_table(sections: Sequence[Section], link: bool = True) -> Table:
    """The summary: one row per outcome, each naming (and linking to) its section."""
    rows = tuple((s.paper or "derive", o.what, o.verdict, o.evidence,
                  f"[{s.short}](#{s.key})" if link else s.short)
                 for s, o in outcomes(sections))
    return Table(SUMMARY_COLUMNS, rows, "Summary: what was reproduced and what matched the "
                 "papers")


def _md_table(b: Table) -> list[str]:
    lines = [f"**{b.caption}**", ""] if b.caption else []
    lines.append("| " + " | ".join(_md_cell(c) for c in b.columns) + " |")
    lines.append("|" + "|".join("--:" if num else "---" for num in numeric_columns(b)) + "|")
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows]
    return lines + [""]


def _md_footer(prov: Provenance) -> list[str]:
    return ["---", ""] + [f"- **{label}:** `{value}`" if label == "command" else
                          f"- **{label}:** {value}" for label, value in prov.lines()] + [""]


def markdown(title: str, intro: Sequence[str], sections: Sequence[Section],
             prov: Provenance) -> str:
    """The report as Markdown (figures by relative path: keep ``figures/`` beside it)."""
    lines = [f"# {title}", ""]
    for paragraph in intro:
        lines += [paragraph, ""]
    lines += [f"Outcomes: {tally_text(sections)}.", ""]
    lines += _md_table(summary_table(sections))
    lines += ["## Contents", ""]
    lines += [f"{i}. [{s.title}](#{s.key})" for i, s in enumerate(sections, 1)]
    lines.append("")
    for s in sections:
        lines += [f'<a id="{s.key}"></a>', "", f"## {s.title}", ""]
        for b in s.blocks:
            if isinstance(b, Text):
                lines += [b.text, ""]
            elif isinstance(b, Todo):
                lines += [f"> **TODO (lead):** {b.text}", ""]
            elif isinstance(b, Preformatted):
                lines += [f"*{b.caption}:*", "", "```", b.text.rstrip("\n"), "```", ""]
            elif isinstance(b, Figure):
                lines += [f"![{b.caption}]({b.path})", "", f"*{b.caption}*", ""]
            elif isinstance(b, Table):
                lines += _md_table(b)
    lines += _md_footer(prov)
    return "\n".join(lines).rstrip("\n") + "\n"


def results_markdown(title: str, intro: str, sections: Sequence[Section],
                     prov: Provenance) -> str:
    """``docs/results.md``: the summary of a run, with its command and date."""
    lines = [f"# {title}", "", intro, "", f"Outcomes: {tally_text(sections)}.", ""]
    lines += _md_table(summary_table(sections, link=False))
    lines += _md_footer(prov)
    return "\n".join(lines).rstrip("\n") + "\n"


def _verdict_html(text: str) -> str:
    cls = {MATCHED: "matched", DIFFERS: "differs", NOT_COMPARABLE: "not-comparable"}
    return f'<span class="{cls[text]}">{html.escape(text)}</span>'


_LINK = re.compile(r"\[([^\]]+)\]\(#([\w-]+)\)")


def _cell_html(text: str, column: str, numeric: bool) -> str:
    if column == "verdict" and text in (MATCHED, DIFFERS, NOT_COMPARABLE):
        return _verdict_html(text)
    link = _LINK.fullmatch(text)
    if link:
        return f'<a href="#{link.group(2)}">{html.escape(link.group(1))}</a>'
    return _inline_html(text, keep_numbers_whole=not numeric)


def _html_table(b: Table) -> list[str]:
    nums = numeric_columns(b)
    cls = [' class="num"' if n else "" for n in nums]
    out = []
    if b.collapsed:
        out.append(f"<details><summary>{_inline_html(b.caption or 'table')} "
                   f"({len(b.rows)} rows)</summary>")
    out.append("<table>")
    if b.caption:
        out.append(f"<caption>{_inline_html(b.caption)}</caption>")
    out.append("<thead><tr>" + "".join(f"<th{c}>{_inline_html(h)}</th>"
                                       for h, c in zip(b.columns, cls))
               + "</tr></thead><tbody>")
    for row in b.rows:
        out.append("<tr>" + "".join(f"<td{c}>{_cell_html(v, h, n)}</td>"
                                    for v, h, c, n in zip(row, b.columns, cls, nums))
                   + "</tr>")
    out.append("</tbody></table>")
    if b.collapsed:
        out.append("</details>")
    return out


def _img_src(root: Path, fig: Figure) -> str:
    """The figure as a data: URI (PNG or SVG), read from ``root / fig.path``."""
    path = root / fig.path
    kind = "image/svg+xml" if path.suffix == ".svg" else "image/png"
    return f"data:{kind};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _html_footer(prov: Provenance) -> list[str]:
    items = "".join(f"<dt>{html.escape(label)}</dt><dd>"
                    + (f"<code>{html.escape(value)}</code>" if label == "command"
                       else html.escape(value)) + "</dd>"
                    for label, value in prov.lines())
    return [f"<footer><dl>{items}</dl><p>This page is self-contained (figures embedded); "
            "<code>index.md</code> needs the <code>figures/</code> folder beside it.</p>"
            "</footer>"]


def to_html(title: str, intro: Sequence[str], sections: Sequence[Section],
            prov: Provenance, root: Path) -> str:
    """The report as one HTML page; figures embedded from the files under ``root``."""
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           f"<title>{html.escape(title)}</title>", f"<style>{STYLE}</style>", "</head>",
           "<body>", f"<h1>{html.escape(title)}</h1>"]
    out += [f"<p>{_inline_html(p)}</p>" for p in intro]
    out.append(f'<section id="summary"><p>Outcomes: {html.escape(tally_text(sections))}.</p>')
    out += _html_table(summary_table(sections))
    out.append("</section>")
    out.append("<nav><h2>Contents</h2><ol>")
    out += [f'<li><a href="#{s.key}">{html.escape(s.title)}</a></li>' for s in sections]
    out.append("</ol></nav>")
    for s in sections:
        out.append(f'<section id="{s.key}"><h2>{html.escape(s.title)}</h2>')
        for b in s.blocks:
            if isinstance(b, Text):
                out.append(f"<p>{_inline_html(b.text)}</p>")
            elif isinstance(b, Todo):
                out.append(f'<p class="todo"><strong>TODO (lead):</strong> '
                           f"{_inline_html(b.text)}</p>")
            elif isinstance(b, Preformatted):
                out.append(f"<details><summary>{_inline_html(b.caption)}</summary>"
                           f"<pre>{html.escape(b.text)}</pre></details>")
            elif isinstance(b, Figure):
                out.append(f'<figure><img src="{_img_src(root, b)}" '
                           f'alt="{html.escape(b.caption)}"><figcaption>'
                           f"{_inline_html(b.caption)}</figcaption></figure>")
            elif isinstance(b, Table):
                out += _html_table(b)
        out.append("</section>")
    out += _html_footer(prov)
    out += ["</body>", "</html>"]
    return "\n".join(out) + "\n"


def write_page(out: Path, title: str, intro: Sequence[str], sections: Sequence[Section],
               prov: Provenance) -> tuple[Path, Path]:
    """Write ``index.md`` and ``index.html`` into ``out``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    md, page = out / "index.md", out / "index.html"
    md.write_text(markdown(title, intro, sections, prov), encoding="utf-8")
    page.write_text(to_html(title, intro, sections, prov, out), encoding="utf-8")
    return md, page
