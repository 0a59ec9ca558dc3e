"""Building a program whose dense products are vector rows (derive.rows).

A :class:`RowBuilder` starts from an optimised *prologue* (the scalar work of a step: f,
the non-zero entries of F, Q; h, H), appends scalar statements and rows, and assembles the
final program without optimising it again (its rows are already minimal and the optimiser
would reorder their lanes):

- :meth:`RowBuilder.row` computes a row ``base + sum sign * coef * sources`` over all its
  lanes, chunk by chunk (:data:`~derive.rows.VECTOR_LANES` lanes; where that does not divide
  the row, the last chunk ends at the row's end and overlaps the one before it, whose
  lanes it recomputes and counts; a row shorter than a chunk is scalar statements);
- :meth:`RowBuilder.finish` keeps what the outputs and checks read: a scalar statement
  when it is read, a chunk when any of its lanes is (all its lanes are then computed, and
  counted: a vector computes them all), the prologue's statements when they are read, a
  parameter's domain check when the parameter is read (as the optimiser does); then names
  the temporaries ``t0, t1, ...`` in order.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace

import sympy

from derive.program import Program
from derive.rows import LaneSum, RowChunk, chunk_bounds
from derive.statements import Assign, Check, Statement, Temporary, is_atom

Lanes = Sequence[sympy.Expr]
Term = tuple[int, sympy.Expr, Lanes]


class RowBuilder:
    """See the module docstring. ``shell``: a new program with the final ports (never
    built on: the result is assembled from it); ``prologue``: an optimised program with
    the same inputs, whose statements come first; ``lanes``: the vector width."""

    def __init__(self, shell: Program, prologue: Program, lanes: int) -> None:
        self.shell = shell
        self.lanes = lanes
        self.items: list[Statement | RowChunk] = list(prologue.body)
        self.counter = sum(isinstance(st, Assign) for st in prologue.body)

    def _temp(self) -> Temporary:
        name = Temporary(f"t{self.counter}_row")
        self.counter += 1
        return name

    def scalar(self, expr: sympy.Expr) -> sympy.Expr:
        """``expr`` as an atom: a new statement unless it is one."""
        expr = sympy.sympify(expr)
        if is_atom(expr):
            return expr
        target = self._temp()
        self.items.append(Assign(target, expr))
        return target

    def check(self, value: sympy.Expr, message: str) -> None:
        """The runtime check ``value > 0`` (an atom)."""
        self.items.append(Check(value, message))

    def row(self, base: Lanes | None, terms: Sequence[Term],
            read: Collection[int] | None = None) -> list[sympy.Expr]:
        """The lanes ``base[l] + sum sign * coef * sources[l]`` (see LaneSum), chunk by
        chunk; a row that is its base alone is the base's atoms.

        ``read``: the lanes anything reads (None: all of them; a row of a symmetric
        result's upper triangle starts at its diagonal, and the EKF predict takes the
        entries of F's unit rows otherwise): a chunk that holds lanes read and lanes not
        read is scalar statements instead (a chunk computes and counts every lane; the
        lanes not read are then left out with what nothing reads). ins_gnss: predict
        2574 -> 2249 flops, update_gnss 2840 -> 2552, the same time."""
        terms = [(sign, coef, tuple(src)) for sign, coef, src in terms if coef != 0]
        if not terms:
            return list(base)
        length = len(terms[0][2])
        wanted = set(range(length)) if read is None else set(read)
        out: list[sympy.Expr] = []
        for start, stop in chunk_bounds(length, self.lanes):
            # the new lanes of a chunk: all of them but in a last chunk that overlaps the one
            # before it (lanes does not divide length), which recomputes that one's last lanes
            first = len(out)
            lanes = None if base is None else tuple(base[start:stop])
            if lanes is not None and all(a == 0 for a in lanes):
                lanes = None  # nothing to add in this chunk
            form = LaneSum(lanes, tuple((s, c, src[start:stop]) for s, c, src in terms))
            some = len(wanted.intersection(range(first, stop)))
            if stop - start < self.lanes or 0 < some < stop - first:
                # a row shorter than a chunk, or new lanes read in part: scalar statements
                out += [self.scalar(form.expr(lane)) for lane in range(first - start,
                                                                       stop - start)]
                continue
            targets = tuple(self._temp() for _ in range(start, stop))
            chunk = RowChunk(targets, form)
            self.items.append(chunk)
            out += targets[first - start:]
        return out

    def finish(self, results: dict[str, Sequence[sympy.Expr]]) -> Program:
        """The program: live statements and chunks, temporaries renumbered."""
        live = {a for values in results.values() for a in values if isinstance(a, sympy.Symbol)}
        kept: list[Statement | RowChunk] = []
        for item in reversed(self.items):
            if isinstance(item, RowChunk):
                if not live.intersection(item.targets):
                    continue
                live.update(item.targets)
                for lane in range(len(item.targets)):
                    live.update(item.form.reads(lane))
            elif isinstance(item, Assign):
                if item.target not in live:
                    continue
                live.update(item.expr.free_symbols)
            elif item.parameter and item.value not in live:
                continue  # a parameter's domain check, where nothing reads the parameter
            else:
                live.update(item.value.free_symbols)
            kept.append(item)
        kept.reverse()
        names: dict[sympy.Symbol, sympy.Symbol] = {}
        for item in kept:
            for target in (item.targets if isinstance(item, RowChunk) else
                           (item.target,) if isinstance(item, Assign) else ()):
                names[target] = Temporary(f"t{len(names)}")
        body: list[Statement] = []
        chunks: list[RowChunk] = []
        for item in kept:
            if isinstance(item, RowChunk):
                chunk = item.renamed(names)
                chunks.append(chunk)
                body += [Assign(t, chunk.form.expr(lane)) for lane, t in enumerate(chunk.targets)]
            elif isinstance(item, Assign):
                body.append(Assign(names[item.target], item.expr.xreplace(names)))
            else:
                body.append(replace(item, value=item.value.xreplace(names)))
        renamed = {name: tuple(sympy.sympify(v).xreplace(names) for v in values)
                   for name, values in results.items()}
        return self.shell.assembled(body, renamed, optimize=False, rows=chunks)


__all__ = ["RowBuilder"]
