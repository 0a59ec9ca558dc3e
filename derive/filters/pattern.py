"""The sparsity pattern of P: declared for P0, closed under the filter's recursion.

Entries outside the pattern are structurally zero at every step: generated code
never reads them and writes them as zero. The pattern is the least fixed point
containing P0's declared pattern: derive one step symbolically with P masked to
the current pattern, add every entry of P_new that did not fold to zero, repeat.
"""

from __future__ import annotations

Pattern = tuple[tuple[bool, ...], ...]


def declared(model, name: str | None = None) -> Pattern:
    """P0's pattern: ``dense``, ``zero``, ``diagonal`` or ``block`` (independent blocks)."""
    return model.pattern_mask(name)


def union(a: Pattern, b: Pattern) -> Pattern:
    return tuple(tuple(x or y for x, y in zip(ra, rb)) for ra, rb in zip(a, b))


def closure(step_pattern, start: Pattern) -> Pattern:
    """Least fixed point of ``p -> p | step_pattern(p)`` above ``start``.

    ``step_pattern(p)`` returns the pattern of P_new when P has pattern ``p``.
    Patterns only grow, so this ends after at most n*n rounds; a dense ``start`` is its
    own closure (no step is derived for it).
    """
    if all(all(row) for row in start):
        return start
    current = start
    while True:
        nxt = union(current, step_pattern(current))
        if nxt == current:
            return current
        current = nxt


def of_matrix(mat) -> Pattern:
    """The structural pattern of a sympy matrix: entries that are not literally zero."""
    return tuple(tuple(mat[i, j] != 0 for j in range(mat.cols)) for i in range(mat.rows))
