"""The generated C run loops, built on the step's statements printed once per file.

The step's statements (without its pattern check) are printed once, in a static
function of the file, the *step body* (:func:`body_function`): every element of a port
is read and written at ``[i * s]``, ``s`` the body's last argument, so that one copy
serves one track (``s`` = 1: the public ``step``, ``run``'s loop with the state in local
arrays) and a lane of a block of tracks (``s`` = the block's width, the state laid out
structure-of-arrays: ``run_tracks``).  A failed check of the body sets its status and
the statements run to the end: no branch leaves them, so the loop over a block's lanes
is one basic block the compiler vectorises (:func:`tracks_parts`), and each lane runs
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
from derive.runs.unit import LOOKAHEAD_NEXT, Unit
from derive.trees import Op, Tree, Var

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
        f"#define {PREFETCH}(address, write) __builtin_prefetch((address), (write), 0)",
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


def _rows(unit: Unit) -> tuple[str, ...]:
    """The step's inputs read one row per step: the per-step inputs, then ``p``."""
    return unit.step_inputs + ((PARAMETER_PORT,) if unit.parameters else ())


def _row(name: str) -> str:
    """The run loop's pointer to row k of a per-step input (``zk``)."""
    return f"{name}k"


def _row_names(unit: Unit, body: LoweredProgram) -> dict[str, str]:
    """run's names of the body's per-step inputs: row k (``zk``; ``pk`` when the body
    reads p, else p itself, which the body does not read)."""
    names = {name: _row(name) for name in unit.step_inputs}
    if unit.parameters:
        names[PARAMETER_PORT] = (_row(PARAMETER_PORT) if PARAMETER_PORT in body.used_inputs()
                                 else PARAMETER_PORT)
    return names


def fused_body(unit: Unit, body: LoweredProgram, prefix: str, name: str | None = None
               ) -> list[str]:
    """run's step: the body over run's local arrays (the state, the step's outputs: held
    in registers once the body is inlined), reading the per-step inputs at row k;
    ``name``: the body function called (default the step's)."""
    return checked_call(body, name or body_name(prefix), _row_names(unit, body),
                        "step_status")


def two_step_body(unit: Unit, body: LoweredProgram, two: LoweredProgram,
                  prefix: str) -> list[str]:
    """run's pass: the step body writing x(k+1) to ``x_mid``, then the two-step map's body
    writing x(k+2) to ``x_new``; rows k and k + 1 are read as ``zk`` and ``znk``."""
    rows = _row_names(unit, body)
    return (checked_call(body, body_name(prefix), {**rows, "x_new": "x_mid"}, "step_status")
            + checked_call(two, body_name(prefix, "pass"),
                           {"z": _row("z"), LOOKAHEAD_NEXT: _row(LOOKAHEAD_NEXT)},
                           "pass_status"))


def _block(name: str) -> str:
    """A block's array of a port: ``x_b`` (element i of lane j at [i * LANES + j])."""
    return f"{name}_b"


def tracks_parts(unit: Unit, body: LoweredProgram, state: list[dict],
                 optional_stores: list[dict], prefix: str, run_call: str,
                 two: LoweredProgram | None = None, real: Precision = DOUBLE) -> dict:
    """The pieces of run_tracks: blocks of :data:`LANES` tracks, structure-of-arrays.

    The caller's arrays stay track after track (track t's z, x0, P0, xs, Ps laid out
    exactly as for run); each block copies its tracks' state and each step's inputs into
    block arrays (element i of lane j at ``[i * LANES + j]``), runs the step body over
    the lanes in one loop (``LANES`` as the stride), and copies the results back to the
    tracks' rows. ``state``: the carried state (derive.emit.render.carried_state);
    ``optional_stores``: run's outputs that may be NULL; ``run_call``: the call of run on
    track t's arrays, for the last tracks (fewer than a block); ``two``: the two-step map
    (the lanes take two steps per pass, as run does).
    """
    if not inlined(body) or (two is not None and not inlined(two)):  # run on every track
        return {"lanes": None, "status": False, "macros": [], "run_call": run_call}
    lanes = LANES
    names = {port: _block(port) for port, _ in unit.carried}
    names.update({out: _block(out) for _, out in unit.carried})
    names.update({name: _block(name) for name in unit.step_inputs})
    if unit.parameters:
        names[PARAMETER_PORT] = (_row(PARAMETER_PORT) if PARAMETER_PORT in body.used_inputs()
                                 else PARAMETER_PORT)
    # the carried state in two block arrays each, the step reading one and writing the other,
    # which then swap (pointers): no copy of the state from step to step
    pairs = [{"pair": f"{_block(s['name'])}_pair", "array": _block(s["name"]),
              "source": _block(s["out"]), "size": s["size"]} for s in state]
    arrays = [f"{_block(name)}[{unit.step_input_size(name)} * {lanes}]"
              for name in unit.step_inputs]
    load = [{"array": _block(s["name"]), "source": s["start"], "size": s["size"]}
            for s in state]
    per_lane = 2 * sum(s["size"] for s in state) + sum(
        unit.step_input_size(name) for name in unit.step_inputs) + (
        unit.n + unit.m if two is not None else 0)

    def gather(row: str, names_of: dict[str, str]) -> list[dict]:
        """Row ``row`` of each per-step input of the block's tracks into its block array."""
        return [{"array": _block(names_of.get(name, name)), "source": name,
                 "size": unit.step_input_size(name), "row": row}
                for name in unit.step_inputs]

    # every array a block reads or writes a row of each step: its tracks' rows are
    # contiguous there, the next block's prefetched while this one runs (AHEAD_BYTES)
    streamed = ([{"array": name, "size": unit.step_input_size(name), "write": 0,
                  "optional": False} for name in unit.step_inputs]
                + [{"array": s["store"], "size": s["size"], "write": 1, "optional": False}
                   for s in state if s["store"]]
                + [{"array": s["array"], "size": s["size"], "write": 1, "optional": True}
                   for s in optional_stores])
    for a in streamed:
        a["lines"] = f"{a['array']}_lines"
    track_step = " + ".join(f"({a['array']} ? {a['size']}u : 0u)" if a["optional"]
                            else f"{a['size']}u" for a in streamed) or "0u"

    def prefetch(row: str) -> list[dict]:
        """The rows AHEAD steps after ``row`` of the per-step inputs (read) and the stored
        outputs (written)."""
        ahead = f"{row} + {AHEAD}"
        return ([{"array": name, "size": unit.step_input_size(name), "row": ahead,
                  "write": 0} for name in unit.step_inputs]
                + [{"array": s["store"], "size": s["size"], "row": ahead, "write": 1}
                   for s in state if s["store"]])

    def stores(row: str, values: dict[str, str]) -> list[dict]:
        """The rows ``row`` of run's stored outputs from the block arrays ``values``."""
        out = [{"array": s["store"], "source": values[s["out"]], "size": s["size"],
                "row": row, "optional": False} for s in state if s["store"]]
        out += [{"array": s["array"], "source": values[s["out"]], "size": s["size"],
                 "row": row, "optional": True} for s in optional_stores if s["out"] in values]
        return out

    status = bool(body.checks) or (two is not None and bool(two.checks))
    step_call = _call(body, body_name(prefix), {port: f"{block} + j" if port != PARAMETER_PORT
                                                else block for port, block in names.items()},
                      lanes)
    news = {s["out"]: _block(s["out"]) for s in state}
    parts = {
        "lanes": lanes, "simd": SIMD, "arrays": arrays, "load": load,
        "macros": tracks_macro_lines(interleave(per_lane, real.bits // 8), real.bits // 8),
        "pairs": pairs, "streamed": streamed, "track_step": track_step,
        "ahead_bytes": AHEAD_BYTES, "line": LINE, "next_row": "k + 1",
        "status": status,
        "p_row": (f"const {real.c_type} *restrict {_row(PARAMETER_PORT)} = {PARAMETER_PORT} + k * "
                  "p_stride;" if unit.parameters and PARAMETER_PORT in body.used_inputs()
                  else ""),
        "gather": gather("k", {}),
        "prefetch": prefetch("k"), "ahead": AHEAD, "prefetch_macro": PREFETCH,
        "lane": [(f"status_b[j] = {step_call};" if body.checks else f"{step_call};")],
        "store": stores("k", news),
        "run_call": run_call,
        "pass": None,
    }
    if two is not None:
        mid = _block("x_mid")
        parts["arrays"] += [f"{mid}[{unit.n} * {lanes}]",
                            f"{_block(LOOKAHEAD_NEXT)}[{unit.m} * {lanes}]"]
        first = _call(body, body_name(prefix), {**{p: f"{b} + j" for p, b in names.items()},
                                                "x_new": f"{mid} + j"}, lanes)
        second = _call(two, body_name(prefix, "pass"),
                       {"x": f"{_block('x')} + j", "z": f"{_block('z')} + j",
                        LOOKAHEAD_NEXT: f"{_block(LOOKAHEAD_NEXT)} + j",
                        "x_new": f"{_block('x_new')} + j"}, lanes)
        lane = [f"const int step_status = {first};" if body.checks else f"{first};",
                f"const int pass_status = {second};" if two.checks else f"{second};"]
        held = [name for name, checks in (("step_status", body.checks),
                                          ("pass_status", two.checks)) if checks]
        if held:  # the step's failed check first, as in run
            lane.append("status_b[j] = " + (" ? step_status : ".join(held)) + ";")
        parts["pass"] = {
            "next_row": "k + 2",
            "gather": gather("k", {}) + [{"array": _block(LOOKAHEAD_NEXT), "source": "z",
                                          "size": unit.m, "row": "k + 1"}],
            "prefetch": prefetch("k"),
            "lane": lane,
            "store": stores("k", {"x_new": mid}) + stores("k + 1", news),
        }
    return parts


def tracks_lines(signature: str, tracks: dict, unused: list[str], checks: list[str],
                 tail: list[str], real: Precision = DOUBLE) -> list[str]:
    """``run_tracks`` whole (its comment, signature and body) from :func:`tracks_parts`:
    blocks of ``tracks["lanes"]`` tracks (element i of lane j at ``[i * LANES + j]``),
    the step body over the lanes in one loop, the last tracks by run; ``checks``: every
    track's check of its start arguments, before any step."""
    t, n = real.c_type, tracks["lanes"]
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
        body += _blocks(tracks, t)
        body.append("/* the last tracks, fewer than a block: run on each */")
    body += ["for (; t < tracks; ++t) {"] + ["    " + line for line in tracks["run_call"]]
    body += ["}"] + list(tail)
    return lines + ["    " + line for line in body] + ["}"]


def _blocks(tracks: dict, t: str) -> list[str]:
    """The loop over the blocks of run_tracks (its tracks' state loaded, the steps, the
    state swapped between its two arrays)."""
    n, line, ahead = tracks["lanes"], tracks["line"], tracks["ahead_bytes"]
    macro = tracks["prefetch_macro"]
    out = ["/* a block's tracks are contiguous in each array: while one block runs, the "
           "next one's",
           f" * cache lines are prefetched, a share each step, when they fit {ahead};",
           f" * else (and for the first block) each lane's rows {tracks['ahead']} steps on */",
           f"const int next_fits = steps * {n} * sizeof({t}) * ({tracks['track_step']}) <= "
           f"{ahead};"]
    out += [f"const size_t {a['lines']} = ({n} * steps * {a['size']} * sizeof({t}) + {line} "
            f"- 1) / {line};" for a in tracks["streamed"]]
    block = [f"const int prefetch_next = next_fits && t + 2 * {n} <= tracks;",
             "const int prefetch_rows = !next_fits || t == 0;"]
    for a in tracks["pairs"]:
        block += [f"{t} {a['pair']}[2][{a['size']} * {n}];", f"{t} *{a['array']} = {a['pair']}[0];",
                  f"{t} *{a['source']} = {a['pair']}[1];"]
    block += [f"{t} {array};" for array in tracks["arrays"]]
    if tracks["status"]:
        block.append(f"int status_b[{n}];")
    block.append(f"for (j = 0; j < {n}; ++j) {{")
    for a in tracks["load"]:
        block += [f"    for (i = 0; i < {a['size']}; ++i) {{",
                  f"        {a['array']}[i * {n} + j] = {a['source']}[(t + j) * {a['size']} + i];",
                  "    }"]
    block.append("}")
    parts = ([tracks["pass"]] if tracks["pass"] else []) + [tracks]
    for part in parts:
        if part is tracks["pass"]:
            head = "for (k = 0; k + 2 <= steps; k += 2) {"
        elif tracks["pass"]:
            head = "for (; k < steps; ++k) {"
        else:
            head = "for (k = 0; k < steps; ++k) {"
        step = [tracks["p_row"]] if tracks["p_row"] else []
        step.append("if (prefetch_next) {")
        for a in tracks["streamed"]:
            fetch = [f"for (i = {a['lines']} * k / steps; i < {a['lines']} * ({part['next_row']})"
                     f" / steps; ++i) {{",
                     f"    {macro}((const char *)({a['array']} + (t + {n}) * steps * "
                     f"{a['size']}) + {line} * i, {a['write']});", "}"]
            step += (["    " + f"if ({a['array']}) {{"] + ["        " + x for x in fetch]
                     + ["    }"] if a["optional"] else ["    " + x for x in fetch])
        step += ["}", f"if (prefetch_rows && k + {tracks['ahead']} < steps) {{",
                 f"    for (j = 0; j < {n}; ++j) {{"]
        step += [f"        {macro}(&{a['array']}[((t + j) * steps + {a['row']}) * {a['size']}], "
                 f"{a['write']});" for a in part["prefetch"]]
        step += ["    }", "}", f"for (j = 0; j < {n}; ++j) {{"]
        for a in part["gather"]:
            step += [f"    for (i = 0; i < {a['size']}; ++i) {{",
                     f"        {a['array']}[i * {n} + j] = {a['source']}[((t + j) * steps + "
                     f"{a['row']}) * {a['size']} + i];", "    }"]
        step += ["}", tracks["simd"], f"for (j = 0; j < {n}; ++j) {{"]
        step += ["    " + x for x in part["lane"]] + ["}"]
        if tracks["status"]:
            step += ["{", "    int failed = 0;", f"    for (j = 0; j < {n}; ++j) {{",
                     "        failed |= status_b[j];", "    }", "    if (failed) {",
                     f"        for (j = 0; j < {n}; ++j) {{", "            if (status_b[j]) {",
                     "                return status_b[j];", "            }", "        }", "    }",
                     "}"]
        step.append(f"for (j = 0; j < {n}; ++j) {{")
        for a in part["store"]:
            store = [f"for (i = 0; i < {a['size']}; ++i) {{",
                     f"    {a['array']}[((t + j) * steps + {a['row']}) * {a['size']} + i] = "
                     f"{a['source']}[i * {n} + j];", "}"]
            step += (["    " + f"if ({a['array']}) {{"] + ["        " + x for x in store]
                     + ["    }"] if a["optional"] else ["    " + x for x in store])
        step.append("}")
        for a in tracks["pairs"]:
            step += ["{", f"    {t} *const swap = {a['array']};",
                     f"    {a['array']} = {a['source']};", f"    {a['source']} = swap;", "}"]
        block += [head] + ["    " + x for x in step] + ["}"]
    return out + [f"for (; t + {n} <= tracks; t += {n}) {{"] + ["    " + x for x in block] + ["}"]
