"""Vector rows: chunks of lanes that one vector operation computes.

A row of a dense product of a filter step (a row of ``F P``, of ``F (F P)^T``, of the
rank-k update of P) is a run of scalar values that the same operations compute from
lane-wise operands::

    lane l = base[l] + s_1 c_1 src_1[l] + s_2 c_2 src_2[l] + ...

with coefficients ``c_k`` shared by the lanes (a temporary, an input element, a number),
signs ``s_k`` = ±1, and per-lane operands (``src_k[l]``, ``base[l]``: input elements,
temporaries, numbers).  A :class:`LaneSum` holds that form for the lanes of one *chunk*
(:data:`VECTOR_LANES` lanes, the width of one vector).  In a program every lane is still
an ordinary scalar statement ``tK = expr`` (Python prints it, the counter counts it, the
reference semantics are those of the lanes), and the program's :attr:`~derive.program.
Program.rows` say which statements are the lanes of which chunk: the C printer prints a
chunk as one vector statement (:mod:`derive.emit.c_vector`), whose lanes are the same
operations in the same order, so the vector code is bitwise the scalar code.

The lowering of a lane is the form's own (:meth:`LaneSum.tree`), not sympy's order of the
terms (which depends on the names, so differs from lane to lane): the chain runs through
the terms in the order given, each product an fma (``fma(c, src, acc)``, ``fnma`` for a
negative sign) in the C lowering, a product and a sum in Python's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import sympy

from derive import monomials
from derive.expression_lowering import constant_value
from derive.statements import Temporary
from derive.trees import Const, Op, Tree, Var

#: Lanes of one vector chunk: a program's rows are the same in every precision; the C type
#: that holds them per precision (four doubles: one AVX register, two NEON or SSE2
#: registers; four floats: one SSE or NEON register).
VECTOR_LANES = 4
VECTOR_TYPES = {"double": "derive_vd", "float": "derive_vf"}


def _leaf(atom: sympy.Expr) -> Tree:
    if atom.is_number:
        return Const(constant_value(atom))
    return Var(atom.name)


@dataclass(frozen=True)
class LaneSum:
    """``lane l = base[l] + sum_k sign_k * coef_k * sources_k[l]`` (see the module docstring).

    ``base``: per-lane atoms, or None (the chain starts at the first term); ``terms``:
    ``(sign, coef, sources)`` with ``sign`` ±1, ``coef`` an atom shared by the lanes (the
    number 1: the source itself is added), ``sources`` one atom per lane."""

    base: tuple[sympy.Expr, ...] | None
    terms: tuple[tuple[int, sympy.Expr, tuple[sympy.Expr, ...]], ...]

    @property
    def lanes(self) -> int:
        return len(self.base) if self.base is not None else len(self.terms[0][2])

    def expr(self, lane: int) -> sympy.Expr:
        """The lane's value as a sympy expression (what the program's statement holds)."""
        return self._exprs[lane]

    @cached_property
    def _exprs(self) -> tuple[sympy.Expr, ...]:
        """Every lane's expression, built once (a program's assembly checks its chunks
        against the statements it was built from): one Add of the base and the products,
        the same canonical expression as adding the terms one by one, without flattening
        the growing sum again at each term."""
        out = []
        for lane in range(self.lanes):
            parts = [] if self.base is None else [self.base[lane]]
            for sign, coef, sources in self.terms:
                product = monomials.product(coef, sources[lane])
                parts.append(product if sign > 0 else -product)
            out.append(sympy.Add(*parts))
        return tuple(out)

    def reads(self, lane: int) -> set[sympy.Symbol]:
        """The symbols lane ``lane`` reads."""
        atoms = [] if self.base is None else [self.base[lane]]
        for _, coef, sources in self.terms:
            atoms += [coef, sources[lane]]
        return {a for a in atoms if isinstance(a, sympy.Symbol)}

    def tree(self, lane: int, use_fma: bool) -> Tree:
        """The lane's operations, in the order of the terms (the module docstring)."""
        acc = None if self.base is None else _leaf(self.base[lane])
        for sign, coef, sources in self.terms:
            source = _leaf(sources[lane])
            if coef == 1:
                if acc is None:
                    acc = source if sign > 0 else Op("neg", (source,))
                else:
                    acc = Op("add" if sign > 0 else "sub", (acc, source))
                continue
            product = Op("mul", (_leaf(coef), source))
            if acc is None:
                acc = product if sign > 0 else Op("neg", (product,))
            elif use_fma:
                acc = Op("fma" if sign > 0 else "fnma", (_leaf(coef), source, acc))
            else:
                acc = Op("add" if sign > 0 else "sub", (acc, product))
        return acc

    def renamed(self, names: dict) -> LaneSum:
        """The form with its symbols replaced by ``names`` (symbol -> symbol)."""
        def one(a):
            return names.get(a, a)
        return LaneSum(None if self.base is None else tuple(one(a) for a in self.base),
                       tuple((s, one(c), tuple(one(a) for a in src))
                             for s, c, src in self.terms))


@dataclass(frozen=True)
class RowChunk:
    """The lanes of one vector chunk: the temporaries they assign, in lane order, and
    their form."""

    targets: tuple[Temporary, ...]
    form: LaneSum

    def renamed(self, names: dict) -> RowChunk:
        return RowChunk(tuple(names.get(t, t) for t in self.targets), self.form.renamed(names))

    def lowered(self) -> LoweredChunk:
        """The chunk as the printers see it: names and leaves."""
        form = self.form
        return LoweredChunk(tuple(t.name for t in self.targets),
                            None if form.base is None else tuple(_leaf(a) for a in form.base),
                            tuple((s, _leaf(c), tuple(_leaf(a) for a in src))
                                  for s, c, src in form.terms))


@dataclass(frozen=True)
class LoweredChunk:
    """A :class:`RowChunk` with names and leaves (:class:`~derive.trees.Var`,
    :class:`~derive.trees.Const`) instead of symbols: what the C printer prints as one
    vector statement (:mod:`derive.emit.c_vector`)."""

    targets: tuple[str, ...]
    base: tuple[Tree, ...] | None
    terms: tuple[tuple[int, Tree, tuple[Tree, ...]], ...]

    def renamed(self, temp: Callable[[str], str], var: Callable[[Var], str]) -> LoweredChunk:
        """Targets renamed by ``temp``, leaves by ``var`` (as LoweredProgram.renamed)."""
        def leaf(t: Tree) -> Tree:
            return Var(var(t)) if isinstance(t, Var) else t
        return LoweredChunk(tuple(temp(t) for t in self.targets),
                            None if self.base is None else tuple(leaf(a) for a in self.base),
                            tuple((s, leaf(c), tuple(leaf(a) for a in src))
                                  for s, c, src in self.terms))


def chunk_bounds(length: int, lanes: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of the chunks of a row of ``length`` values, ``lanes`` each; when
    ``lanes`` does not divide ``length`` the last one ends at ``length`` and overlaps the
    one before it (a 23-wide row of P: 5 chunks, the last over lanes 19-22, rather than a
    remainder of 3 scalar statements); one shorter chunk when ``length < lanes``."""
    if length <= lanes:
        return [(0, length)] if length else []
    return [(k, k + lanes) for k in range(0, length - lanes + 1, lanes)] + (
        [(length - lanes, length)] if length % lanes else [])


def check_chunks(chunks: Sequence[RowChunk]) -> None:
    """ValueError unless every chunk's form has one lane per target."""
    for chunk in chunks:
        if chunk.form.lanes != len(chunk.targets):
            raise ValueError(f"a chunk of {len(chunk.targets)} targets has a form of "
                             f"{chunk.form.lanes} lanes")


__all__ = ["LaneSum", "LoweredChunk", "RowChunk", "VECTOR_LANES", "VECTOR_TYPES",
           "check_chunks", "chunk_bounds"]
