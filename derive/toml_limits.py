"""Bounds on the shape of TOML text, checked in one linear pass before it is parsed.

Python's TOML parser recurses once per nested array or inline table (200,000 ``[`` raise
RecursionError), takes time quadratic in the parts of a dotted key (150,000 parts ran
for minutes), and converts integers of any length (5,000 digits raise ValueError). This
scanner finds those shapes first and names their line and column. It understands just
enough TOML to do so: comments and the four kinds of strings are skipped, since their
text may hold any characters.
"""

from __future__ import annotations

import re

MAX_NESTING = 32
"""Deepest nesting of arrays and inline tables (a matrix is 2 deep)."""
MAX_KEY_PARTS = 32
"""Most dot-separated parts in one key (``a.b.c`` has 3)."""
MAX_DIGITS = 1000
"""Longest run of digits in a number (exact numbers are bounded to 2048 bits, about 617
decimal digits, when they are read)."""

_TOKEN = re.compile(
    r"#[^\n]*"  # a comment
    r"""|(?P<string>"(?:[^"\\\n]|\\.)*"(?!")|'[^'\n]*'(?!'))"""  # a one-line string: skipped
    r"""|["']"""  # a multi-line or unterminated string: see _string_end
    r"|(?:[0-9]_?){" + str(MAX_DIGITS + 1) + r",}"  # a too long digit run
    r"|[\[\]{}.=,\n]"  # brackets and key breaks
)
"""What the scan looks at."""


def toml_shape_problem(text: str) -> str | None:
    """None, or ``'line L, column C: what'`` for the first shape beyond the bounds."""
    depth = 0
    dots = 0
    line, line_start = 1, 0
    index = 0
    while True:
        token = _TOKEN.search(text, index)
        if token is None:
            return None
        start = token.start()
        char = token.group()[0]
        index = token.end()
        if char == "#" or token.lastgroup == "string":
            continue
        if char in "\"'":
            index, newlines, last_newline = _string_end(text, start)
            if newlines:
                line += newlines
                line_start = last_newline + 1
            continue
        if char.isdigit():
            return _at(line, start - line_start, f"a number with more than {MAX_DIGITS} digits")
        if char in "[{":
            depth += 1
            if depth > MAX_NESTING:
                return _at(line, start - line_start, "arrays and inline tables nested more "
                                                     f"than {MAX_NESTING} deep")
        elif char in "]}":
            depth = max(0, depth - 1)
        if char == ".":
            dots += 1
            if dots >= MAX_KEY_PARTS:
                return _at(line, start - line_start, f"a key of more than {MAX_KEY_PARTS} "
                                                     "dotted parts")
            continue
        dots = 0  # = , [ ] { } and newline end a key
        if char == "\n":
            line += 1
            line_start = index


def _at(line: int, offset: int, what: str) -> str:
    return f"line {line}, column {offset + 1}: {what}"


def _string_end(text: str, start: int) -> tuple[int, int, int]:
    """(index after the string starting at ``start``, newlines in it, index of its last
    newline); an unterminated string ends the text (the parser reports it)."""
    quote = text[start]
    triple = text.startswith(quote * 3, start)
    delimiter = quote * 3 if triple else quote
    index = start + len(delimiter)
    escapes = quote == '"'
    while True:
        end = text.find(delimiter, index)
        if not triple:
            newline = text.find("\n", index)
            if newline >= 0 and (end < 0 or newline < end):
                return newline, 0, -1  # a single-line string cannot hold a newline
        if end < 0:
            end = len(text)
            break
        if escapes and _escaped(text, end, start + len(delimiter)):
            index = end + 1
            continue
        if triple:  # up to two more quotes belong to the string: """a"""" is 'a"'
            extra = 0
            while extra < 2 and text.startswith(quote, end + 3 + extra):
                extra += 1
            end += extra
        end += len(delimiter)
        break
    body = text[start:end]
    newlines = body.count("\n")
    return end, newlines, start + body.rfind("\n") if newlines else -1


def _escaped(text: str, index: int, floor: int) -> bool:
    """Whether the character at ``index`` follows an odd number of backslashes."""
    count = 0
    while index - 1 - count >= floor and text[index - 1 - count] == "\\":
        count += 1
    return count % 2 == 1
