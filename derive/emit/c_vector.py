"""Vector chunks (derive.rows) printed as C vector statements, with their scalar lanes as
the fallback.

A chunk is printed twice, chosen by the preprocessor::

    #if DERIVE_VECTOR
        const derive_vd v_t57 = DERIVE_VFMA(((derive_vd){t3, t3, t3, t3}),
                                        ((derive_vd){P[16], P[17], P[18], P[19]}), v_t41);
        const double t57 = v_t57[0];
        ...
    #else
        const double t57 = DERIVE_FMA(t3, P[16], t41);
        ...
    #endif

``DERIVE_VECTOR`` is 1 under GCC and Clang (their vector extension, ``vector_size``) on a
target whose vector registers hold the vector (four doubles: x86 AVX; four floats: SSE or
NEON), 0 elsewhere (a Cortex-M, or x86-64 at its SSE2 baseline for doubles, gets the
scalar lanes, which leave out the lanes nothing reads), and a build may set it. It is the
one switch of C's one vector dialect (:func:`vector_macro_lines`): the block lanes of a
run (derive.emit.c_lanes) use the same switch, vector type and fused multiply-adds,
and the track lanes' vectorisation hint (derive.emit.c_loops) follows the switch. An
operand whose lanes are the lanes of an earlier chunk, in order, is that chunk's vector;
any other one is built from its lanes (a compound literal: consecutive elements of an
input are one load, a coefficient is a broadcast, lanes of other chunks are shuffles: the
compiler's choice). The vector fused multiply-adds round as the scalar ones do, lane by
lane (:func:`vector_macro_lines`), so the vector branch computes bitwise what the scalar
branch computes, and the counts of the header, which are the scalar lanes', are the
vector branch's, lane by lane (:func:`derive.flops.count_c_text` counts a vector
statement once per lane).
"""

from __future__ import annotations

from derive.lowering import LoweredAssign, LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.rows import VECTOR_LANES, VECTOR_TYPES, LoweredChunk
from derive.trees import Const, Tree, Var, tree_vars

#: The one switch of every vector form in C (chunks of vector rows, block lanes, the hint
#: on track lanes' loop): 1 under GCC and Clang on a target with vector registers for the
#: file's precision, 0 elsewhere; a build may set it (``-DDERIVE_VECTOR=0``: scalar C99).
SWITCH = "DERIVE_VECTOR"
#: The vector fused multiply-adds, ``a*b + c`` and ``c - a*b`` lane by lane, each lane
#: rounded as the file's DERIVE_FMA and DERIVE_FNMA round it.
VFMA = "DERIVE_VFMA"
VFNMA = "DERIVE_VFNMA"
#: Defined where Clang has its elementwise fma (Clang 14 and later).
ELEMENTWISE_FMA = "DERIVE_ELEMENTWISE_FMA"
#: The lines that open, split and close the two forms of a chunk (the C text counter
#: reads them: derive.flops).
OPEN, ELSE, CLOSE = f"#if {SWITCH}", "#else", "#endif"
#: x86's fused multiply-add of a vector of (precision, lanes) and the macro it needs.
_X86_FMA = {("double", 2): ("_mm_fmadd_pd", "__FMA__"),
            ("double", 4): ("_mm256_fmadd_pd", "__FMA__"),
            ("double", 8): ("_mm512_fmadd_pd", "__AVX512F__"),
            ("float", 4): ("_mm_fmadd_ps", "__FMA__"),
            ("float", 8): ("_mm256_fmadd_ps", "__FMA__"),
            ("float", 16): ("_mm512_fmadd_ps", "__AVX512F__")}
#: The targets whose vector registers hold a vector of so many bytes, by the precision of
#: its elements: x86's SSE (SSE2 for doubles), AVX and AVX-512; 16 bytes on AArch64 and
#: on 32-bit Arm with NEON (floats). Elsewhere (a Cortex-M, or a vector wider than the
#: registers) GCC would split each vector operation into narrower ones and the vectors'
#: registers would not fit: at -O2 on x86-64 without AVX (SSE2, two doubles a register),
#: a vector of four doubles measured slower than the scalar lanes, ins_gnss's
#: predict 780 ns against 432 ns, mpt3d_a's time-varying run 18.4 ns against 12.4 ns a
#: step, its steady run 13.2 against 3.5 ns; with -mavx 136 against 409, 11.1 against
#: 11.8 and 2.0 against 2.4 ns (Intel Xeon, docs/performance.md).
_TARGETS = {("double", 16): "defined(__SSE2__) || defined(__aarch64__)",
            ("float", 16): "defined(__SSE__) || defined(__ARM_NEON) || defined(__ARM_NEON__)",
            ("double", 32): "defined(__AVX__)", ("float", 32): "defined(__AVX__)",
            ("double", 64): "defined(__AVX512F__)", ("float", 64): "defined(__AVX512F__)"}


def vector_type(precision: Precision = DOUBLE) -> str:
    """The C name of the file's vector of ``precision`` (one per precision; its width is
    the file's, :func:`vector_macro_lines`)."""
    return VECTOR_TYPES[precision.name]


def switch_lines(precision: Precision = DOUBLE, lanes: int = VECTOR_LANES) -> list[str]:
    """The definition of :data:`SWITCH` unless the build gave it: 1 where a vector register
    of the target holds the file's vector of ``lanes`` elements of ``precision``."""
    size = precision.bits // 8 * lanes
    targets = _TARGETS.get((precision.name, size))
    if targets is None:
        raise ValueError(f"no target holds a vector of {lanes} elements of {precision.name}")
    return [f"#ifndef {SWITCH}",
            f"#if (defined(__GNUC__) || defined(__clang__)) && ({targets})",
            f"#define {SWITCH} 1",
            "#else",
            f"#define {SWITCH} 0",
            "#endif",
            "#endif"]


def vector_macro_lines(precision: Precision = DOUBLE, lanes: int = VECTOR_LANES,
                       fused: bool = True) -> list[str]:
    """The ``.c`` file's vector dialect (after the scalar fma macros,
    :func:`derive.emit.c_printer.fma_macro_lines`): :data:`SWITCH`, the vector type of
    ``lanes`` elements of ``precision`` (:func:`vector_type`, and its ``_unaligned``
    twin for stores at an element's alignment) and, where the file fuses (``fused``: it
    defines DERIVE_FMA), the fused multiply-adds.

    ``DERIVE_VFMA(a, b, c)`` is ``a*b + c`` lane by lane, rounded as ``DERIVE_FMA`` rounds:
    the product and the sum in the plain build (``DERIVE_FMA_PLAIN``), the x86 FMA
    instruction where ``DERIVE_FMA`` is the fused ``fma`` and the target has it, Clang's
    elementwise fma where it is fused elsewhere, else ``DERIVE_FMA`` of each lane (a build
    that defines DERIVE_FMA itself: correct, and as fast as the compiler makes it; its
    operands are named vectors or compound literals, never a nested chain, which each lane
    would copy again). ``DERIVE_VFNMA(a, b, c)`` is ``c - a*b`` likewise (x86's negative
    multiply-add, one rounding, as ``DERIVE_FNMA``'s ``fma(a, -b, c)``)."""
    vtype = vector_type(precision)
    element = precision.bits // 8
    x86, needs = _X86_FMA.get((precision.name, lanes), ("", ""))

    def each(scalar: str) -> str:
        return ", ".join(f"{scalar}((a)[{k}], (b)[{k}], (c)[{k}])" for k in range(lanes))

    types = switch_lines(precision, lanes) + [
        f"#if {SWITCH}",
        f"__extension__ typedef {precision.c_type} {vtype} "
        f"__attribute__((vector_size({element * lanes})));",
        f"__extension__ typedef {precision.c_type} {vtype}_unaligned "
        f"__attribute__((vector_size({element * lanes}), aligned({element}), may_alias));"]
    if not fused:
        return types + ["#endif"]
    lines = types + [
        "#if defined(__clang__) && defined(__has_builtin)",
        "#if __has_builtin(__builtin_elementwise_fma)",
        f"#define {ELEMENTWISE_FMA} 1",
        "#endif",
        "#endif",
        "#if defined(DERIVE_FMA_PLAIN)",
        f"#define {VFMA}(a, b, c) ((a) * (b) + (c))",
        f"#define {VFNMA}(a, b, c) ((c) - (a) * (b))"]
    if x86:
        lines += [f"#elif defined(DERIVE_FMA_FUSED) && defined({needs}) "
                  "&& (defined(__x86_64__) || defined(__i386__))",
                  "#include <immintrin.h>",
                  f"#define {VFMA}(a, b, c) (({vtype}){x86}((a), (b), (c)))",
                  f"#define {VFNMA}(a, b, c) (({vtype}){x86.replace('fmadd', 'fnmadd')}"
                  "((a), (b), (c)))"]
    return lines + [f"#elif defined(DERIVE_FMA_FUSED) && defined({ELEMENTWISE_FMA})",
                    f"#define {VFMA}(a, b, c) __builtin_elementwise_fma((a), (b), (c))",
                    f"#define {VFNMA}(a, b, c) __builtin_elementwise_fma((a), -(b), (c))",
                    "#else",
                    f"#define {VFMA}(a, b, c) (({vtype}){{{each('DERIVE_FMA')}}})",
                    f"#define {VFNMA}(a, b, c) (({vtype}){{{each('DERIVE_FNMA')}}})",
                    "#endif",
                    "#endif"]


def _is_one(leaf: Tree) -> bool:
    return isinstance(leaf, Const) and leaf.value == 1.0


class ChunkPrinter:
    """Prints the chunks of one lowered program: their vector expressions (computed when
    made, in order, so that an operand that is an earlier chunk is its vector), and which
    lanes each form needs as scalars (the lanes read one by one in the vector form; the
    live lanes of the scalar form, since a lane nothing reads is left out of it)."""

    def __init__(self, printer, precision: Precision, lowered: LoweredProgram) -> None:
        self.printer = printer
        self.precision = precision
        self.vtype = VECTOR_TYPES[precision.name]
        self.lanes = VECTOR_LANES
        for chunk in lowered.rows:
            if len(chunk.targets) != self.lanes:
                raise ValueError(f"a chunk of {len(chunk.targets)} lanes, whose vectors "
                                 f"hold {self.lanes}")
        self.vectors: dict[tuple[str, ...], str] = {}  # a chunk's lanes -> its vector
        self.single: set[str] = set()  # lanes the vector form reads one by one
        self.order = {t: k for k, chunk in enumerate(lowered.rows) for t in chunk.targets}
        self.first_lane = {t: chunk.targets[0] for chunk in lowered.rows
                           for t in chunk.targets}
        self.chunk_lanes = {chunk.targets[0]: tuple(chunk.targets) for chunk in lowered.rows}
        self.expressions = {chunk.targets[0]: self._vector_expression(chunk, lowered.use_fma)
                            for chunk in lowered.rows}
        self.results = dict(lowered.results)
        # what goes out right after a chunk (the vector stores it completes, with the
        # transpositions they need: no chunk of an output stays live to the end of the
        # function): ("line", text) or ("store", port, first index, vector)
        self.early: dict[str, list[tuple]] = {}
        self.stores: list[tuple[str, int]] = []  # written at the end, entry by entry
        symmetric = {p.name for p in lowered.outputs if p.symmetric}
        for port, leaves in lowered.results:
            done = self._symmetric_blocks(port, leaves) if port in symmetric else set()
            for first in range(0, len(leaves), self.lanes):
                run = leaves[first:first + self.lanes]
                left = [k for k in range(first, first + len(run)) if k not in done]
                if len(left) == self.lanes and all(isinstance(v, Var) and v.name in self.order
                                                   for v in run):
                    self._after([v.name for v in run],
                                [("store", port, first, self._operand(tuple(run)))])
                    continue
                if len(left) == len(run):  # no block store covers any of the run
                    self.stores += [(port, k) for k in left]
                    continue
                for k in left:  # the entries block stores left: each a lane after its chunk
                    leaf = leaves[k]
                    if isinstance(leaf, Var) and leaf.name in self.order:
                        chunk = self.chunk_lanes[self.first_lane[leaf.name]]
                        self._after([leaf.name], [("lane", port, k, self.vectors[chunk],
                                                   chunk.index(leaf.name))])
                    else:
                        self.stores.append((port, k))
        # the scalar form writes an output entry that is a chunk's lane right after the
        # lane's statement (at the end, every entry would stay live to the end of the
        # function: ins_fc24's update_baro spilled 300 of them)
        self.scalar_stores: dict[str, list[tuple[str, int]]] = {}
        for port, leaves in lowered.results:
            for k, leaf in enumerate(leaves):
                if isinstance(leaf, Var) and leaf.name in self.order:
                    self.scalar_stores.setdefault(leaf.name, []).append((port, k))
        self.scalar_early = {entry for entries in self.scalar_stores.values()
                             for entry in entries}
        self._liveness(lowered)

    def _liveness(self, lowered: LoweredProgram) -> None:
        """:attr:`vector_alias`: the lanes the vector form reads one by one (scalar
        statements, checks, entries written at the end, operands built from lanes);
        :attr:`scalar_live`: what the scalar form computes (a lane only when read)."""
        lanes = set(self.order)
        roots = {v.name for port, k in self.stores for v in tree_vars(self.results[port][k])}
        self.scalar_live = {v.name for leaves in self.results.values() for leaf in leaves
                            for v in tree_vars(leaf)}
        for st in reversed(lowered.body):
            reads = {v.name for v in tree_vars(st.tree)}
            if isinstance(st, LoweredAssign) and st.target in lanes:
                if st.target in self.scalar_live:
                    self.scalar_live |= reads
                continue
            roots |= reads  # a scalar statement or a check reads its lanes in either form
            self.scalar_live |= reads
        self.vector_alias = (roots | self.single) & lanes

    def _after(self, lanes: list[str], items: list[tuple]) -> None:
        """``items`` go out right after the last chunk of ``lanes``."""
        last = max(lanes, key=self.order.__getitem__)
        self.early.setdefault(self.first_lane[last], []).extend(items)

    def _transpose(self, rows: list[str]) -> tuple[list[str], list[tuple[str, str]]]:
        """The columns of the 4 x 4 block whose rows are the vectors ``rows``, and the
        eight shuffles that make them, as (name, line)."""
        base = f"tr_{rows[0]}"
        t = [f"{base}_{k}" for k in range(4)]
        c = [f"{base}_c{k}" for k in range(4)]
        pairs = [(t[0], rows[0], rows[1], "0, 4, 2, 6"), (t[1], rows[0], rows[1], "1, 5, 3, 7"),
                 (t[2], rows[2], rows[3], "0, 4, 2, 6"), (t[3], rows[2], rows[3], "1, 5, 3, 7"),
                 (c[0], t[0], t[2], "0, 1, 4, 5"), (c[1], t[1], t[3], "0, 1, 4, 5"),
                 (c[2], t[0], t[2], "2, 3, 6, 7"), (c[3], t[1], t[3], "2, 3, 6, 7")]
        return c, [(name, f"const {self.vtype} {name} = __builtin_shufflevector({a}, {b}, {m});")
                   for name, a, b, m in pairs]

    def _symmetric_blocks(self, port: str, leaves) -> set[int]:
        """A symmetric output whose upper triangle is rows of chunks, written in 4 x 4
        blocks: an upper block as its four chunks, the block below the diagonal as their
        transposition, a diagonal block as its chunks with the lanes below the diagonal
        taken from its transposition (the mirror, exactly: the same values). A block is
        written so only when the output's entries are those lanes, checked entry by entry
        (also where 4 does not divide n: the blocks whose rows' chunks line up, as a tangent
        space of 23 has them). Returns the entries written so; of a run of entries that a
        block store covers in part, the others are each a lane written after its chunk."""
        n = round(len(leaves) ** 0.5)
        if self.lanes != 4 or n * n != len(leaves) or n < 4:
            return set()

        def name(i: int, j: int) -> str | None:
            leaf = leaves[i * n + j]
            return leaf.name if isinstance(leaf, Var) else None

        done: set[int] = set()
        aligned = 4 * (n // 4)  # the columns of whole blocks; past them, a last block
        for bi in range(n // 4):
            rows = range(4 * bi, 4 * bi + 4)
            # the blocks' first columns: the aligned ones from the diagonal on, and where 4
            # does not divide n the last four columns (the rows' overlapping last chunks,
            # their lanes before `aligned` written already, with the same values)
            starts = list(range(4 * bi, aligned, 4)) + (
                [n - 4] if n % 4 and n - 4 >= 4 * bi + 3 else [])
            for c in starts:
                diagonal, last = c == 4 * bi, c % 4 != 0
                # the chunk of each row that holds its lanes in the block, on and above the
                # diagonal (those before it, in a diagonal block, are the mirror)
                chunks = [self.chunk_lanes.get(self.first_lane.get(
                    name(a, c + (r if diagonal else 3 if last else 0)), ""))
                          for r, a in enumerate(rows)]
                if None in chunks or not all(
                        (a * n + c + k in done and (c + k) * n + a in done) if c + k < aligned
                        and last else
                        name(a, c + k) == (chunks[r][k] if not diagonal or k >= r
                                           else chunks[k][r])
                        and (diagonal or name(c + k, a) == chunks[r][k])
                        for r, a in enumerate(rows) for k in range(4)):
                    continue
                vectors = [self.vectors[chunk] for chunk in chunks]
                columns, shuffles = self._transpose(vectors)
                lines = [("line", line) for column, line in shuffles
                         if not diagonal or column != columns[0]]  # a diagonal's row 0: none
                stores = ([(a * n + c, (vectors[r] if r == 0 else
                                        f"__builtin_shufflevector({vectors[r]}, {columns[r]}, "
                                        + ", ".join(str(4 + k if k < r else k) for k in range(4))
                                        + ")"))
                           for r, a in enumerate(rows)] if diagonal else
                          [(a * n + c, vectors[r]) for r, a in enumerate(rows)]
                          + [((c + k) * n + 4 * bi, columns[k]) for k in range(4)])
                for first, vector in stores:
                    lines.append(("store", port, first, vector))
                    done.update(range(first, first + 4))
                self._after([lane for chunk in chunks for lane in chunk], lines)
        return done

    def _operand(self, leaves: tuple[Tree, ...]) -> str:
        names = tuple(leaf.name if isinstance(leaf, Var) else "" for leaf in leaves)
        held = self.vectors.get(names)
        if held is not None and all(names):
            return held
        self.single.update(name for name in names if name)
        lanes = ", ".join(self.printer.expression(leaf) for leaf in leaves)
        return f"(({self.vtype}){{{lanes}}})"

    def _broadcast(self, leaf: Tree) -> str:
        return self._operand((leaf,) * self.lanes)

    def _vector_expression(self, chunk: LoweredChunk, use_fma: bool) -> list[str]:
        """The chunk's lanes as vector statements (the operations of
        :meth:`derive.rows.LaneSum.tree`, lane by lane): one statement per step of the
        chain, each reading the previous step's vector, the last one the chunk's."""
        name = f"v_{chunk.targets[0]}"
        steps: list[str] = []
        acc = None if chunk.base is None else self._operand(chunk.base)
        for sign, coef, sources in chunk.terms:
            source = self._operand(sources)
            if _is_one(coef):
                if acc is None:
                    value = source if sign > 0 else f"(-{source})"
                else:
                    value = f"({acc} {'+' if sign > 0 else '-'} {source})"
            else:
                c = self._broadcast(coef)
                if acc is None:
                    value = f"({c} * {source})" if sign > 0 else f"(-({c} * {source}))"
                elif use_fma:
                    value = f"{VFMA if sign > 0 else VFNMA}({c}, {source}, {acc})"
                else:
                    value = f"({acc} {'+' if sign > 0 else '-'} ({c} * {source}))"
            if acc is not None or value != source:  # a step that computes
                acc = f"{name}_{len(steps)}"
                steps.append((acc, value))
            else:
                acc = value
        self.vectors[tuple(chunk.targets)] = name
        last = steps.pop()[1] if steps else acc
        return ([f"const {self.vtype} {step} = {value};" for step, value in steps]
                + [f"const {self.vtype} {name} = {last};"])

    def store_lines(self, place) -> list[str]:
        """The results the vector form writes at the end (after :data:`OPEN`; the caller
        closes with the scalar stores): the entries that are not four lanes of chunks
        (those went out with their chunks, :meth:`lines`). ``place(port, index)``: the C
        text of an output element."""
        return [OPEN] + [f"{place(port, k)} = {self.printer.expression(self.results[port][k])};"
                         for port, k in self.stores]

    def _early_line(self, item: tuple, place) -> str:
        if item[0] == "line":
            return item[1]
        if item[0] == "lane":
            return f"{place(item[1], item[2])} = {item[3]}[{item[4]}];"
        return f"*({self.vtype}_unaligned *)&{place(item[1], item[2])} = {item[3]};"

    def lines(self, chunk: LoweredChunk, scalar_lines: list[str], place) -> list[str]:
        """The chunk in both forms: the vector statement, the lanes read one by one and
        the vector stores of outputs it completes, else ``scalar_lines`` (its live lanes'
        own statements) and the output entries that are its lanes (:attr:`scalar_early`:
        the caller's scalar stores at the end leave them out). ``place(port, index)``: the
        C text of an output element."""
        name = f"v_{chunk.targets[0]}"
        real = self.precision.c_type
        return ([OPEN, *self.expressions[chunk.targets[0]]]
                + [f"const {real} {t} = {name}[{k}];" for k, t in enumerate(chunk.targets)
                   if t in self.vector_alias]
                + [self._early_line(item, place) for item in self.early.get(chunk.targets[0], ())]
                + [ELSE] + scalar_lines
                + [f"{place(port, k)} = {t};" for t in chunk.targets
                   for port, k in self.scalar_stores.get(t, ())] + [CLOSE])


__all__ = ["CLOSE", "ChunkPrinter", "ELEMENTWISE_FMA", "ELSE", "OPEN", "SWITCH", "VFMA", "VFNMA",
           "switch_lines", "vector_macro_lines", "vector_type"]
