"""The generated C run loops, built on the step's statements printed once per file.

The step's statements (without its pattern check) are printed once, in a static
function of the file, the *step body* (:func:`body_function`): every element of a port
is read and written at ``[i * s]``, ``s`` the body's last argument, so that one copy
serves one track (``s`` = 1: the public ``step``, ``run``'s loop with the state in local
arrays) and a lane of a block of tracks (``s`` = the block's width, the state laid out
structure-of-arrays: ``run_tracks``).  A failed check of the body sets its status and
the statements run to the end: no branch leaves them, so the loop over a block's lanes
is one basic block the compiler vectorises (:func:`tracks_lines`), and each lane runs
exactly the operations of one track's ``run``, in the same order.

A small body is inlined into each caller (:data:`INLINE_STATEMENTS`; always_inline where
GCC and Clang take it), so run keeps the state in registers and the lane loop is
vectorised; a large one stays one function that every caller calls, so the file
compiles it once.  A unit with a two-step map (``Unit.lookahead``) has a second body for
the map (derive.runs.kinds.two_step_map); its run takes two steps per pass, and so do the lanes.
"""

from __future__ import annotations

from dataclasses import replace

from derive.emit import c_printer
from derive.emit.c_vector import SWITCH
from derive.lowering import LoweredAssign, LoweredProgram
from derive.precision import DOUBLE, Precision
from derive.program import PARAMETER_PORT
from derive.runs.loops import Call, Row, Run, Steps, Store, walk
from derive.trees import Op, Tree, Var

#: C run's stride of p: 0 when p is one row for every step, NP when one row per step.
P_STRIDE = "p_stride"
#: The step body's stride argument: element i of a port is at [i * STRIDE].
STRIDE = "s"
#: The status a step body's failed check sets (the first failed check's).
STATUS = "status"
#: The lane count of run_tracks' blocks: :func:`interleave` vector registers' worth of
#: elements (AVX-512: 64 bytes a register, 8 doubles or 16 floats; AVX: 32 bytes; else 16),
#: unless the build defines it.
LANES = "DERIVE_LANES"
#: Bytes of a vector register: AVX-512, AVX (and AVX2), else (SSE2, NEON).
REGISTER_BYTES = (("__AVX512F__", 64), ("__AVX__", 32), (None, 16))
#: The most registers a block's statement spans: independent chains that hide the latency
#: of a division (4 was fastest of 1, 2, 4, 8 on AVX-512, AVX2 and SSE2: docs/performance.md).
INTERLEAVE = 4
#: The most bytes of a block's arrays at the widest lanes (AVX-512): in L1 and on the stack.
BLOCK_BYTES = 64 * 1024
#: Prefetch a block's tracks' rows this many steps ahead (``DERIVE_PREFETCH``: GCC's and
#: Clang's __builtin_prefetch, else nothing) when the next block does not fit
#: :data:`AHEAD_BYTES`: a block reads and writes as many streams as it has lanes, more
#: than the hardware prefetchers follow (the batch of the bench: 3.2e8 track-steps/s on
#: one core with it, 1.3e8 to 2.0e8 without; 8 of 8, 16, 32 best).
AHEAD = 8
PREFETCH = "DERIVE_PREFETCH"
#: The locality of the prefetches (__builtin_prefetch's third argument): 2, into the L2
#: and the caches beyond it (x86 prefetcht1). 0 (prefetchnta) fills only the L1 on Intel
#: cores: the next block's lines, fetched up to a block ahead, left the 48 kB L1 before
#: their use and came from memory again (Sapphire Rapids, 1,000,000 tracks x 100 steps, 2
#: threads: 5.0e8 track-steps/s with 0, 8.6e8 with 2, 8.6e8 with 3; 1,000 steps, each
#: lane's rows: 2.9e8, 8.5e8, 3.0e8; docs/performance.md).
PREFETCH_LOCALITY = 2
#: A block's tracks are contiguous in every array of run_tracks: while a block runs, the
#: next block's arrays are prefetched, a share of their cache lines each step, when they
#: hold at most this many bytes (``DERIVE_AHEAD_BYTES``, a quarter of a 1 MB L2), else each
#: lane's rows :data:`AHEAD` steps on. The bench's batch, 100 steps (77 kB a block), CPU time
#: per core out of cache: 3.6e8 to 4.0e8 track-steps/s against 2.4e8 to 2.9e8 with the
#: rows; at 1,000 steps (768 kB) as fast as the rows, at 10,000 slower (docs/performance.md).
AHEAD_BYTES = "DERIVE_AHEAD_BYTES"
AHEAD_BYTES_DEFAULT = 256 * 1024
#: The cache line the next block's prefetches step by (``DERIVE_LINE``, bytes).
LINE = "DERIVE_LINE"
#: Put before the loop over a block's lanes: ``omp simd`` under OpenMP (``-fopenmp``),
#: ``GCC ivdep`` / Clang's ``loop vectorize(assume_safety)`` else (no lane depends on
#: another: ivdep's meaning; GCC vectorises it at -O3, or at -O2 with -ftree-vectorize,
#: Clang at -O2); a build may define it, e.g. ``-D'DERIVE_SIMD=_Pragma("omp simd")'`` with
#: ``-fopenmp-simd``; a build that sets the file's vector switch ``DERIVE_VECTOR`` to 0 gets
#: no hint (derive.emit.c_vector). Both compilers take it as a hint: GCC never reports a
#: loop it did not vectorise, and the file tells Clang not to either (``-Wpass-failed``:
#: Clang 14 does not vectorise the lanes of mpt3d_a's steady filters, whose loop calls the
#: step and the two-step bodies, and would fail a -Werror build of correct code).
SIMD = "DERIVE_SIMD"
#: How a step body small enough to inline is declared.
INLINE = "DERIVE_INLINE"
#: Bodies of at most this many statements are inlined into their callers (run, the lane
#: loop; every catalog filter's, 386 the largest); larger ones are compiled
#: once and called, unstrided (no lanes: run_tracks runs run on each track): a file's
#: compile time and memory grow with one copy of the step, not one per caller (a dense
#: 12-state filter, 730 statements: gcc -O2 5.8 s CPU inlined into step, run and lanes,
#: 1.7 s called).
INLINE_STATEMENTS = 500


def interleave(elements_per_lane: int, element_bytes: int = 8) -> int:
    """Registers per statement of a block (:data:`INTERLEAVE`, halved until the block of
    ``elements_per_lane`` elements a lane fits :data:`BLOCK_BYTES` at the widest
    registers, as many lanes as a 64-byte register holds elements of ``element_bytes``)."""
    registers = INTERLEAVE
    lanes_per_register = 64 // element_bytes
    while registers > 1 and (elements_per_lane * element_bytes * registers
                             * lanes_per_register > BLOCK_BYTES):
        registers //= 2
    return registers


def lanes(registers: int, element_bytes: int = 8) -> dict[str | None, int]:
    """:data:`LANES` for each target macro of :data:`REGISTER_BYTES` (None: the others):
    ``registers`` registers' worth of elements of ``element_bytes`` (float32 has twice the
    lanes of float64 in the same registers)."""
    return {macro: registers * size // element_bytes for macro, size in REGISTER_BYTES}


def tracks_macro_lines(registers: int, element_bytes: int = 8) -> list[str]:
    """The .c file's definitions of :data:`LANES`, the prefetch macros and :data:`SIMD`
    (each unless defined)."""
    lane_lines = []
    for macro, count in lanes(registers, element_bytes).items():
        test = (f"#elif defined({macro})" if lane_lines else f"#if defined({macro})") \
            if macro else "#else"
        lane_lines += [test, f"#define {LANES} {count}"]
    return [
        f"#ifndef {LANES}",
        *lane_lines,
        "#endif",
        "#endif",
        f"#ifndef {AHEAD_BYTES}",
        f"#define {AHEAD_BYTES} {AHEAD_BYTES_DEFAULT}",
        "#endif",
        f"#ifndef {LINE}",
        f"#define {LINE} 64",
        "#endif",
        f"#ifndef {PREFETCH}",
        "#if defined(__GNUC__)",
        f"#define {PREFETCH}(address, write) __builtin_prefetch((address), (write), "
        f"{PREFETCH_LOCALITY})",
        "#else",
        f"#define {PREFETCH}(address, write) ((void)(address))",
        "#endif",
        "#endif",
        f"#ifndef {SIMD}",
        # the file's one vector switch (derive.emit.c_vector) set to 0 by the build: no hint
        f"#if defined({SWITCH}) && !{SWITCH}",
        f"#define {SIMD}",
        "#elif defined(_OPENMP)",
        f'#define {SIMD} _Pragma("omp simd")',
        "#elif defined(__clang__)",
        # a hint, as GCC's ivdep: Clang reports a loop it was asked to vectorise and could
        # not (mpt3d_a's steady ones: two bodies a lane) as a warning, an error under -Werror
        '#pragma clang diagnostic ignored "-Wpass-failed"',
        f'#define {SIMD} _Pragma("clang loop vectorize(assume_safety)")',
        "#elif defined(__GNUC__)",
        f'#define {SIMD} _Pragma("GCC ivdep")',
        "#else",
        f"#define {SIMD}",
        "#endif",
        "#endif",
    ]


#: Every file keeps a*b + c as two roundings whatever -ffp-contract says (GCC's default in
#: its GNU modes is to fuse them): the code fuses what it means to itself (DERIVE_FMA), so
#: the operations executed are those the header counts, and a statement the compiler
#: if-converts in the vectorised lanes (a missing measurement's select) rounds as in run.
CONTRACT_LINES = [
    "#if defined(__clang__)",
    "#pragma STDC FP_CONTRACT OFF",
    "#elif defined(__GNUC__)",
    '#pragma GCC optimize ("fp-contract=off")',
    "#endif",
]
INLINE_LINES = [
    f"#ifndef {INLINE}",
    "#if defined(__GNUC__)",
    f"#define {INLINE} static inline __attribute__((always_inline))",
    "#else",
    f"#define {INLINE} static inline",
    "#endif",
    "#endif",
]


def body_name(prefix: str, program: str = "step") -> str:
    """The step body's C name: ``PREFIX_step_body`` (the two-step map's: ``PREFIX_pass_body``)."""
    return f"{prefix}_{program}_body"


def inlined(body: LoweredProgram) -> bool:
    """True when the body is small enough to inline into its callers."""
    return len(body.body) + sum(len(leaves) for _, leaves in body.results) \
        <= INLINE_STATEMENTS


def _element(port: str, index: int) -> str:
    """Element ``index`` of a port in a step body: strided, except the parameters ``p``
    (one row that every lane shares)."""
    if port == PARAMETER_PORT or index == 0:
        return f"{port}[{index}]"
    return f"{port}[{index} * {STRIDE}]"


def body_function(body: LoweredProgram, name: str, real: Precision = DOUBLE) -> dict:
    """The step body as a function (``signature``, ``body`` lines): the program's ports as
    pointers, then the stride (a body too large to inline has none: its elements are at
    ``[i]``, and run_tracks runs it track by track); returns the status of the first failed
    check (int), or nothing when the program has no check."""
    status = bool(body.checks)
    strided = inlined(body)
    params = c_printer.parameters(body, precision=real) + (
        [f"const size_t {STRIDE}"] if strided else [])
    qualifier = INLINE if strided else "static"
    lines = [f"(void){p.name};" for p in body.inputs if p.name not in body.used_inputs()]
    if status:
        lines.append(f"int {STATUS} = 0;")
    statements = c_printer.statements(body, real, _element if strided else None,
                                       STATUS if status else None)
    if strided and not any(f"* {STRIDE}]" in line for line in statements):  # element 0 only
        lines.append(f"(void){STRIDE};")
    lines += statements
    if status:
        lines.append(f"return {STATUS};")
    return {"signature": f"{qualifier} {'int' if status else 'void'} {name}({', '.join(params)})",
            "body": lines}


#: A body too large to inline is printed in parts of at most this many statements, each a
#: function of its own (the temporaries one part leaves to a later one in a local array):
#: the compiler's time and memory grow faster than the size of a function (a dense
#: 24-state filter, gcc -O2: in one function 45 s CPU and 1.4 GB; in parts of 500, 100, 200
#: statements 26.9 s and 482 MB, 13.5 s and 359 MB, 16.3 s and 382 MB).
PART_STATEMENTS = 200
#: The local array of a parted body that carries temporaries from part to part.
PART_CARRY = "w"


def _temporaries(tree: Tree, found: set[str]) -> set[str]:
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, Op):
            stack.extend(node.args)
        elif isinstance(node, Var) and node.index is None:
            found.add(node.name)
    return found


def parted_functions(body: LoweredProgram, name: str, real: Precision = DOUBLE) -> list[dict]:
    """A large body as its parts (``NAME_partK``) and the body calling them in order, each
    part taking every port, the array of carried temporaries and (with checks) the status
    so far; the statements are the body's, printed once, in order."""
    statements = list(body.body)
    chunks = [statements[i:i + PART_STATEMENTS]
              for i in range(0, len(statements), PART_STATEMENTS)] or [[]]
    # the results go with the last part
    defined_in = {s.target: k for k, chunk in enumerate(chunks) for s in chunk
                  if isinstance(s, LoweredAssign)}
    used_in: list[set[str]] = []
    for k, chunk in enumerate(chunks):
        used: set[str] = set()
        for s in chunk:
            _temporaries(s.tree, used)
        if k == len(chunks) - 1:
            for _, leaves in body.results:
                for leaf in leaves:
                    _temporaries(leaf, used)
        used_in.append({t for t in used if defined_in.get(t, k) != k})
    crossing = sorted(set().union(*used_in), key=lambda t: (defined_in[t], int(t[1:])))
    slot = {t: i for i, t in enumerate(crossing)}
    status = bool(body.checks)
    params = c_printer.parameters(body, precision=real)
    args = ", ".join(c_printer.argument_order(body))
    functions, calls = [], []
    for k, chunk in enumerate(chunks):
        last = k == len(chunks) - 1
        part = replace(body, body=tuple(chunk), results=body.results if last else ())
        here = used_in[k]
        part = part.renamed({}, lambda t, here=here: f"{PART_CARRY}[{slot[t]}]" if t in here
                            else t)
        lines = [f"(void){p};" for p in c_printer.argument_order(body)
                 if p not in part.used_inputs()
                 and not (last and p in {o.name for o in body.outputs})]
        lines += c_printer.statements(part, real, None, STATUS if status else None)
        lines += [f"{PART_CARRY}[{slot[s.target]}] = {s.target};" for s in chunk
                  if isinstance(s, LoweredAssign) and s.target in slot]
        part_name = f"{name}_part{k}"
        signature = (f"static {'int' if status else 'void'} {part_name}("
                     f"{', '.join(params + [f'{real.c_type} *restrict {PART_CARRY}'])}"
                     + (f", int {STATUS})" if status else ")"))
        if status:
            lines.append(f"return {STATUS};")
        functions.append({"signature": signature, "body": lines})
        call = f"{part_name}({args}, {PART_CARRY}" + (f", {STATUS})" if status else ")")
        calls.append(f"{STATUS} = {call};" if status else f"{call};")
    head = [f"{real.c_type} {PART_CARRY}[{max(1, len(crossing))}];"]
    if status:
        head.append(f"int {STATUS} = 0;")
    body_lines = head + calls + ([f"return {STATUS};"] if status else [])
    functions.append({"signature": f"static {'int' if status else 'void'} {name}("
                                    f"{', '.join(params)})", "body": body_lines})
    return functions


def body_functions(body: LoweredProgram, name: str, real: Precision = DOUBLE) -> list[dict]:
    """The body's function(s): one (:func:`body_function`), or a large body in parts
    (:func:`parted_functions`)."""
    if inlined(body) or len(body.body) <= PART_STATEMENTS:
        return [body_function(body, name, real)]
    return parted_functions(body, name, real)


def _call(body: LoweredProgram, name: str, names: dict[str, str], stride: str) -> str:
    args = [names.get(port, port) for port in c_printer.argument_order(body)]
    return f"{name}({', '.join(args + ([stride] if inlined(body) else []))})"


def checked_call(body: LoweredProgram, name: str, names: dict[str, str], result: str,
                 stride: str = "1") -> list[str]:
    """The body called with its ports named by ``names``; a non-zero status returned at
    once (held in the const int ``result``)."""
    call = _call(body, name, names, stride)
    if not body.checks:
        return [f"{call};"]
    return [f"const int {result} = {call};", f"if ({result}) {{", f"    return {result};",
            "}"]


def step_function_body(step: LoweredProgram, body: LoweredProgram, name: str,
                       real: Precision = DOUBLE) -> list[str]:
    """The public step's statements: its pattern check of the inputs, then the body over
    its own arrays (stride 1)."""
    lines = []
    for check in step.pattern_checks:
        lines += c_printer.pattern_check_lines(check, precision=real)
    call = _call(body, name, {}, "1")
    if body.checks:
        return lines + [f"return {call};"]
    return lines + [f"{call};"] + (["return 0;"] if step.has_checks else [])


def row_pointer(name: str) -> str:
    """The run loop's pointer to row k of a per-step input (``zk``)."""
    return f"{name}k"


def loop_head(loop: Steps) -> str:
    """The C loop over a stepping run's steps: from 0, two a pass, or on from where the
    loop before stopped (``rest``); step 0 alone (``first``) or from ``start``."""
    if loop.by == 2:
        return "for (k = 0; k + 2 <= steps; k += 2) {"
    if loop.rest:
        return "for (; k < steps; ++k) {"
    if loop.first:
        return "for (k = 0; k < steps && k < 1; ++k) { /* update-first: step 0 alone */"
    return f"for (k = {loop.start}; k < steps; ++k) {{"


def _block(name: str) -> str:
    """A block's array of a port: ``x_b`` (element i of lane j at [i * LANES + j])."""
    return f"{name}_b"


def _call_names(run: Run, call: Call, reads_p: bool) -> dict[str, str]:
    """A lane's names of a call's ports: lane j of their block arrays (p's row as it is)."""
    names = {}
    for state in run.states:  # a port not bound is the carried state's
        names.update({state.name: f"{_block(state.name)} + j",
                      state.new: f"{_block(state.new)} + j"})
    for port, source in call.args:
        names[port] = ((row_pointer(PARAMETER_PORT) if reads_p else PARAMETER_PORT)
                       if isinstance(source, Row) and source.array == PARAMETER_PORT
                       else f"{_block(port)} + j")
    names.update({port: f"{_block(name)} + j" for port, _, name in call.into})
    return names


def _gathered(loop: Steps) -> list[tuple[str, Row]]:
    """The rows of run's arrays a loop's calls read (not p's), each (port, row) once."""
    found: dict[str, Row] = {}
    for call in (c for c in loop.body if isinstance(c, Call)):
        for port, source in call.args:
            if isinstance(source, Row) and source.array != PARAMETER_PORT:
                found.setdefault(port, source)
    return list(found.items())


def _block_arrays(run: Run) -> dict[str, int]:
    """The block arrays of a step's rows: the rows the loops read, the local arrays they
    write (x_mid), by name: elements a lane."""
    arrays: dict[str, int] = {}
    for loop in run.loops:
        for call in (c for c in loop.body if isinstance(c, Call)):
            for port, source in call.args:
                if isinstance(source, Row) and source.array != PARAMETER_PORT:
                    arrays.setdefault(port, source.size)
            arrays.update({name: row.size for _, row, name in call.into})
    return arrays


def _step_outputs(run: Run, lowered: dict[str, LoweredProgram]) -> dict[str, int]:
    """The outputs of the loops' calls that no carried state or local array holds (the
    log-likelihood ``ll`` and its gradient ``dll``, which run stores): their block arrays,
    by name: elements a lane."""
    held = {s.new for s in run.states} | {s.name for s in run.states}
    found: dict[str, int] = {}
    for call in (c for c in walk(run.loops) if isinstance(c, Call)):
        held |= {port for port, _, _ in call.into}
        for port in lowered[call.program].outputs:
            if port.name not in held:
                found.setdefault(port.name, port.size)
    return found


def tracks_inlined(run: Run, lowered: dict[str, LoweredProgram]) -> bool:
    """True when run_tracks runs blocks of tracks in lanes: every body its loops call is
    inlined (else it runs run on every track)."""
    return all(inlined(lowered[c.program]) for c in walk(run.loops) if isinstance(c, Call))


def tracks_macros(run: Run, lowered: dict[str, LoweredProgram], real: Precision) -> list[str]:
    """The macros of run_tracks' blocks (:func:`tracks_macro_lines`), their registers from
    the elements a lane holds: the carried state twice, the block arrays."""
    if not tracks_inlined(run, lowered):
        return []
    per_lane = (2 * sum(s.size for s in run.states) + sum(_block_arrays(run).values())
                + sum(_step_outputs(run, lowered).values()))
    return tracks_macro_lines(interleave(per_lane, real.bits // 8), real.bits // 8)


def tracks_lines(signature: str, run: Run, lowered: dict[str, LoweredProgram], prefix: str,
                 unused: list[str], checks: list[str], run_call: list[str],
                 tail: list[str], real: Precision = DOUBLE) -> list[str]:
    """``run_tracks`` whole (its comment, signature and body), from the stepping
    :class:`Run`: blocks of :data:`LANES` tracks, structure-of-arrays (element i of lane j
    at ``[i * LANES + j]``), each loop's calls over the lanes in one loop, the last tracks
    by ``run_call`` (run on track t's arrays), then ``tail``; ``checks``: every track's
    check of its start arguments, before any step; ``lowered``: the bodies the loops
    call."""
    t = real.c_type
    n = LANES if tracks_inlined(run, lowered) else None
    lines = ["", "/* Run many independent tracks: each array holds one run's array per track, "
             "one track after",
             " * another (z[tracks][steps*m], x0[tracks][n], xs[tracks][steps*n], ...; Ps may "
             "be NULL)."]
    if n:
        lines += [f" * Tracks go in blocks of {n} (a few vector registers wide), copied into",
                  f" * block arrays here, element i of lane j at [i * {n} + j]: the step body "
                  "runs",
                  " * over the lanes in one loop the compiler vectorises, each lane the "
                  "operations of its own",
                  " * run in the same order; the last tracks, fewer than a block, by run "
                  "itself."]
    else:
        lines.append(" * The step body is too large to inline: run on each track.")
    lines += [" * A non-zero status stops the whole run. */", signature, "{"]
    body = ["size_t t = 0;"] + (["size_t k, i, j;"] if n else []) + list(unused)
    if checks:
        body += ["/* every track's P0 must be zero outside P's pattern; checked before any "
                 "step */", "for (t = 0; t < tracks; ++t) {"]
        body += ["    " + line for line in checks] + ["}", "t = 0;"]
    if n:
        body += _blocks(run, lowered, prefix, t)
        body.append("/* the last tracks, fewer than a block: run on each */")
    body += ["for (; t < tracks; ++t) {"] + ["    " + line for line in run_call]
    body += ["}"] + list(tail)
    return lines + ["    " + line for line in body] + ["}"]


def _blocks(run: Run, lowered: dict[str, LoweredProgram], prefix: str, t: str) -> list[str]:
    """The loop over the blocks of run_tracks (its tracks' state loaded, each loop of the
    run over the lanes, the state swapped between its two arrays)."""
    n, line, ahead = LANES, LINE, AHEAD_BYTES
    states = {s.name: s for s in run.states}
    step = lowered["step"]
    reads_p = PARAMETER_PORT in step.used_inputs()
    p_row = reads_p and any(port == PARAMETER_PORT for c in walk(run.loops)
                            if isinstance(c, Call) for port, _ in c.args)
    last = run.loops[-1]
    stores = sorted((s for s in last.body if isinstance(s, Store)), key=lambda s: s.optional)
    # every array a block reads or writes a row of each step: its tracks' rows are
    # contiguous there, the next block's prefetched while this one runs (AHEAD_BYTES)
    streamed = ([(row.array, row.size, 0, False) for _, row in _gathered(last)]
                + [(s.array, s.size, 1, s.optional) for s in stores])
    track_step = " + ".join(f"({a} ? {size}u : 0u)" if optional else f"{size}u"
                            for a, size, _, optional in streamed) or "0u"
    checked = [c for c in walk(run.loops) if isinstance(c, Call) and lowered[c.program].checks]
    out = ["/* a block's tracks are contiguous in each array: while one block runs, the "
           "next one's",
           f" * cache lines are prefetched, a share each step, when they fit {ahead};",
           f" * else (and for the first block) each lane's rows {AHEAD} steps on */",
           f"const int next_fits = steps * {n} * sizeof({t}) * ({track_step}) <= "
           f"{ahead};"]
    out += [f"const size_t {a}_lines = ({n} * steps * {size} * sizeof({t}) + {line} "
            f"- 1) / {line};" for a, size, _, _ in streamed]
    block = [f"const int prefetch_next = next_fits && t + 2 * {n} <= tracks;",
             "const int prefetch_rows = !next_fits || t == 0;"]
    for s in run.states:  # two block arrays each, the step reading one and writing the
        # other, which then swap (pointers): no copy of the state from step to step
        block += [f"{t} {_block(s.name)}_pair[2][{s.size} * {n}];",
                  f"{t} *{_block(s.name)} = {_block(s.name)}_pair[0];",
                  f"{t} *{_block(s.new)} = {_block(s.name)}_pair[1];"]
    outputs = _step_outputs(run, lowered)
    block += [f"{t} {_block(name)}[{size} * {n}];"
              for name, size in {**_block_arrays(run), **outputs}.items()]
    if checked:
        block.append(f"int status_b[{n}];")
    enter = lowered.get("enter") if run.enter is not None and run.enter.program == "enter" \
        else None
    if enter is not None:  # each lane's state from its track's start arguments
        block += [f"{t} {s.name}_e[{s.size}];" for s in run.states]
        if enter.has_checks:
            block.append("int status;")
    block.append(f"for (j = 0; j < {n}; ++j) {{")
    if enter is not None:
        names = {port: f"{row.array} + (t + j) * {row.size}" for port, row in run.enter.args}
        names.update({s.name: f"{s.name}_e" for s in run.states})
        block += ["    " + line for line in call_lines(prefix, enter, names)]
    for s in run.states:
        start = f"{s.name}_e[i]" if enter is not None else f"{s.start}[(t + j) * {s.size} + i]"
        block += [f"    for (i = 0; i < {s.size}; ++i) {{",
                  f"        {_block(s.name)}[i * {n} + j] = {start};",
                  "    }"]
    block.append("}")
    for loop in run.loops:
        step_lines = [f"const {t} *restrict {row_pointer(PARAMETER_PORT)} = {PARAMETER_PORT} + k * "
                      f"{P_STRIDE};"] if p_row else []
        step_lines.append("if (prefetch_next) {")
        for a, size, write, optional in streamed:
            fetch = [f"for (i = {a}_lines * k / steps; i < {a}_lines * (k + {loop.by})"
                     f" / steps; ++i) {{",
                     f"    {PREFETCH}((const char *)({a} + (t + {n}) * steps * "
                     f"{size}) + {line} * i, {write});", "}"]
            step_lines += (["    " + f"if ({a}) {{"] + ["        " + x for x in fetch]
                           + ["    }"] if optional else ["    " + x for x in fetch])
        step_lines += ["}", f"if (prefetch_rows && k + {AHEAD} < steps) {{",
                       f"    for (j = 0; j < {n}; ++j) {{"]
        ahead_rows = ([(row.array, row.size, 0) for _, row in _gathered(last)]
                      + [(s.array, s.size, 1) for s in stores if not s.optional])
        step_lines += [f"        {PREFETCH}(&{a}[((t + j) * steps + k + {AHEAD}) * {size}], "
                       f"{write});" for a, size, write in ahead_rows]
        step_lines += ["    }", "}", f"for (j = 0; j < {n}; ++j) {{"]
        for port, row in _gathered(loop):
            step_lines += [f"    for (i = 0; i < {row.size}; ++i) {{",
                           f"        {_block(port)}[i * {n} + j] = {row.array}[((t + j) * "
                           f"steps + {row.row}) * {row.size} + i];", "    }"]
        step_lines += ["}", SIMD, f"for (j = 0; j < {n}; ++j) {{"]
        step_lines += ["    " + x for x in _lane(run, loop, lowered, prefix, reads_p,
                                                  outputs)] + ["}"]
        if checked:
            step_lines += ["{", "    int failed = 0;", f"    for (j = 0; j < {n}; ++j) {{",
                           "        failed |= status_b[j];", "    }", "    if (failed) {",
                           f"        for (j = 0; j < {n}; ++j) {{",
                           "            if (status_b[j]) {",
                           "                return status_b[j];", "            }", "        }",
                           "    }", "}"]
        step_lines.append(f"for (j = 0; j < {n}; ++j) {{")
        made = {s: _block(states[s].new) for s in states}
        made.update({name: _block(name) for c in loop.body if isinstance(c, Call)
                     for _, _, name in c.into})
        made.update({name: _block(name) for name in outputs})
        for s in sorted((s for s in loop.body if isinstance(s, Store)),
                        key=lambda s: s.optional):
            if s.state not in made:
                continue
            store = [f"for (i = 0; i < {s.size}; ++i) {{",
                     f"    {s.array}[((t + j) * steps + {s.row}) * {s.size} + i] = "
                     f"{made[s.state]}[i * {n} + j];", "}"]
            step_lines += (["    " + f"if ({s.array}) {{"] + ["        " + x for x in store]
                           + ["    }"] if s.optional else ["    " + x for x in store])
        step_lines.append("}")
        for s in run.states:
            step_lines += ["{", f"    {t} *const swap = {_block(s.name)};",
                           f"    {_block(s.name)} = {_block(s.new)};",
                           f"    {_block(s.new)} = swap;", "}"]
        block += [loop_head(loop)] + ["    " + x for x in step_lines] + ["}"]
    return out + [f"for (; t + {n} <= tracks; t += {n}) {{"] + ["    " + x for x in block] + ["}"]


def call_lines(prefix: str, lp: LoweredProgram, names: dict[str, str]) -> list[str]:
    """The C call of ``PREFIX_NAME`` with its ports named by ``names`` (else their names);
    a non-zero status is returned at once."""
    args = ", ".join(names.get(name, name) for name in c_printer.argument_order(lp))
    if not lp.has_checks:
        return [f"{prefix}_{lp.name}({args});"]
    return [f"status = {prefix}_{lp.name}({args});", "if (status) {", "    return status;",
            "}"]


def _lane(run: Run, loop: Steps, lowered: dict[str, LoweredProgram], prefix: str,
          reads_p: bool, outputs: dict[str, int]) -> list[str]:
    """Lane j of a loop's calls; a failed check's status kept, the earliest call's first;
    ``outputs``: the calls' outputs held in block arrays of their own."""
    calls = [c for c in loop.body if isinstance(c, Call)]
    texts = [(_call(lowered[c.program], body_name(prefix, "step" if c.program == "step"
                                                   else "pass"),
                    {**{name: f"{_block(name)} + j" for name in outputs},
                     **_call_names(run, c, reads_p)}, LANES), bool(lowered[c.program].checks),
              "step_status" if c.program == "step" else "pass_status") for c in calls]
    if len(texts) == 1:
        text, checks, _ = texts[0]
        return [f"status_b[j] = {text};" if checks else f"{text};"]
    lane = [f"const int {held} = {text};" if checks else f"{text};"
            for text, checks, held in texts]
    held = [held for _, checks, held in texts if checks]
    if held:  # the step's failed check first, as in run
        lane.append("status_b[j] = " + (" ? step_status : ".join(held)) + ";")
    return lane
