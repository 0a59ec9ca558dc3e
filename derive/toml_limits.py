"""Bounds on the shape of TOML text, checked in one linear pass before it is parsed.

Python's TOML parser recurses once per nested array or inline table (200,000 ``[`` raise
RecursionError), takes time quadratic in the parts of a dotted key (150,000 parts ran
for minutes), and converts integers of any length (5,000 digits raise ValueError). This
scanner finds those shapes first and names their line and column. It understands just
enough TOML to do so: comments and the four kinds of strings are skipped, since their
text may hold any characters.
"""

from __future__ import annotations

MAX_NESTING = 32
"""Deepest nesting of arrays and inline tables (a matrix is 2 deep)."""
MAX_KEY_PARTS = 32
"""Most dot-separated parts in one key (``a.b.c`` has 3)."""
MAX_DIGITS = 1000
"""Longest run of digits in a number (exact numbers are bounded to 2048 bits, about 617
decimal digits, when they are read)."""

_DIGITS = frozenset("0123456789")
_KEY_BREAKS = frozenset("=,[]{}\n")


def toml_shape_problem(text: str) -> str | None:
    """None, or ``'line L, column C: what'`` for the first shape beyond the bounds."""
    depth = 0
    dots = 0
    digits = 0
    index = 0
    line, line_start = 1, 0
    length = len(text)
    while index < length:
        char = text[index]
        where = f"line {line}, column {index - line_start + 1}"
        if char == "#":
            end = text.find("\n", index)
            index = length if end < 0 else end
            continue
        if char in "\"'":
            end, newlines, last_newline = _string_end(text, index)
            if newlines:
                line += newlines
                line_start = last_newline + 1
            index = end
            digits = 0
            continue
        if char in _DIGITS:
            digits += 1
            if digits > MAX_DIGITS:
                return f"{where}: a number with more than {MAX_DIGITS} digits"
        elif char != "_":
            digits = 0
        if char in "[{":
            depth += 1
            if depth > MAX_NESTING:
                return (f"{where}: arrays and inline tables nested more than {MAX_NESTING} "
                        "deep")
        elif char in "]}":
            depth = max(0, depth - 1)
        if char == ".":
            dots += 1
            if dots >= MAX_KEY_PARTS:
                return f"{where}: a key of more than {MAX_KEY_PARTS} dotted parts"
        elif char in _KEY_BREAKS:
            dots = 0
        if char == "\n":
            line += 1
            line_start = index + 1
        index += 1
    return None


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
