"""Render the report's sections as ``index.md`` and a self-contained ``index.html``."""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from pathlib import Path

from .document import Figure, Preformatted, Section, Table, Text, Todo

_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*([^*]+)\*\*")

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 72rem; margin: 2rem auto;
       padding: 0 1rem; line-height: 1.45; color: #222; }
table { border-collapse: collapse; margin: 0.5rem 0 1.2rem; font-size: 0.9rem; }
th, td { border: 1px solid #bbb; padding: 0.2rem 0.5rem; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
caption { caption-side: top; text-align: left; font-weight: 600; padding: 0.3rem 0; }
figure { margin: 1rem 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9rem; color: #444; }
pre { background: #f6f6f6; padding: 0.6rem; overflow-x: auto; font-size: 0.8rem; }
.todo { background: #fff3cd; border-left: 4px solid #e0a800; padding: 0.5rem; }
nav li { margin: 0.1rem 0; }
"""


def _inline_html(text: str) -> str:
    out = html.escape(text, quote=False)
    out = _CODE.sub(lambda m: f"<code>{m.group(1)}</code>", out)
    return _BOLD.sub(lambda m: f"<strong>{m.group(1)}</strong>", out)


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown(title: str, intro: Sequence[str], sections: Sequence[Section]) -> str:
    """The report as Markdown."""
    lines = [f"# {title}", ""]
    for paragraph in intro:
        lines += [paragraph, ""]
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
                lines += ["```", b.text.rstrip("\n"), "```", ""]
            elif isinstance(b, Figure):
                lines += [f"![{b.caption}]({b.path})", "", f"*{b.caption}*", ""]
            elif isinstance(b, Table):
                if b.caption:
                    lines += [f"**{b.caption}**", ""]
                lines.append("| " + " | ".join(_md_cell(c) for c in b.columns) + " |")
                lines.append("|" + "|".join("---" for _ in b.columns) + "|")
                lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows]
                lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def _html_table(b: Table) -> list[str]:
    out = ["<table>"]
    if b.caption:
        out.append(f"<caption>{_inline_html(b.caption)}</caption>")
    out.append("<thead><tr>" + "".join(f"<th>{_inline_html(c)}</th>" for c in b.columns)
               + "</tr></thead><tbody>")
    for row in b.rows:
        out.append("<tr>" + "".join(f"<td>{_inline_html(c)}</td>" for c in row) + "</tr>")
    out.append("</tbody></table>")
    return out


def to_html(title: str, intro: Sequence[str], sections: Sequence[Section]) -> str:
    """The report as one HTML page (figures referenced by relative path)."""
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           f"<title>{html.escape(title)}</title>", f"<style>{STYLE}</style>", "</head>",
           "<body>", f"<h1>{html.escape(title)}</h1>"]
    out += [f"<p>{_inline_html(p)}</p>" for p in intro]
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
                out.append(f"<pre>{html.escape(b.text)}</pre>")
            elif isinstance(b, Figure):
                out.append(f'<figure><img src="{html.escape(b.path)}" '
                           f'alt="{html.escape(b.caption)}"><figcaption>'
                           f"{_inline_html(b.caption)}</figcaption></figure>")
            elif isinstance(b, Table):
                out += _html_table(b)
        out.append("</section>")
    out += ["</body>", "</html>"]
    return "\n".join(out) + "\n"


def write_page(out: Path, title: str, intro: Sequence[str],
               sections: Sequence[Section]) -> tuple[Path, Path]:
    """Write ``index.md`` and ``index.html`` into ``out``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    md, page = out / "index.md", out / "index.html"
    md.write_text(markdown(title, intro, sections), encoding="utf-8")
    page.write_text(to_html(title, intro, sections), encoding="utf-8")
    return md, page
