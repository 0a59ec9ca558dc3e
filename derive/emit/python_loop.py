"""The single-track Python run loop: the step's statements inline on local floats.

Calling ``step`` once per step costs a function call, a list per output and an index
per element; on one track that is most of the time.  Here the loop carries the state
in local variables (``x[1]`` becomes ``x_1``, ``P[3]`` becomes ``P_3``), reads each
per-step input element by element from an ``array('d')`` of its doubles (a float made
as it is read and freed with the step; an input of several elements through one zip
of its repeated iterator), runs the step's own statements (same printer, same
operations, same order, so the results are bitwise those of ``step``) and packs its new
elements into bytes at once (one ``Struct.pack`` per step: no tuple, no float kept
alive), appended to one ``bytearray`` and read as an array once at the end (a list of
one bytes object per step was as fast for 2,000 steps, 8 % slower at 20,000 and 25 %
at 100,000: each object its own allocation, out of cache).  Per step it names only what is
read twice: a temporary read once is printed inside its reader (unless a check lies
between them, so nothing divides by a value before it is checked), and a new state
element is written to its local where it is computed once the old value is dead.  A
failed check raises :class:`NumericalError` with the step's message and the step's
index (the bytes kept so far over a row's: no counter per step).
"""

from __future__ import annotations

from derive.emit.python_printer import PythonPrinter, presence_labels
from derive.lowering import MAX_DEPTH, LoweredAssign, LoweredCheck, LoweredProgram
from derive.program import PARAMETER_PORT
from derive.runs.loops import Call, Row, Run, Store, walk
from derive.trees import Op, Var, tree_vars


def local_name(port: str, index: int | str) -> str:
    """``x[1]`` -> ``x_1``: the local variable that holds one element."""
    return f"{port}_{index}"


def local_names(ports: set[str]):
    """The printer's name map: an element of one of ``ports`` is its local variable
    (``x[1]`` -> ``x_1``); every other variable keeps its name."""
    def name(var: Var) -> str:
        return local_name(var.base, var.index) if var.index is not None and \
            var.base in ports else var.name
    return name


def _unpack(names: list[str], source: str) -> list[str]:
    if len(names) == 1:
        return [f"{names[0]} = {source}[0]"]
    return [f"{', '.join(names)} = {source}"]


def _values(array: str) -> str:
    """The doubles of a float64 array, row-major, as an ``array('d')``."""
    return f'array("d", {array}.tobytes())'


def _loop_target(step_inputs, ports, read) -> str:
    """The loop's target: each element of each per-step input (``_`` if the step does not
    read it), in the order of the inputs."""
    names = [local_name(name, i) if i in read.get(name, ()) else "_"
             for name in step_inputs for i in range(ports[name].size)]
    return names[0] if len(names) == 1 else f"({', '.join(names)})"


def _loop_source(step_inputs, ports, arrays, out: list[str]) -> str:
    """What the loop iterates: one input of one element directly; otherwise one iterator
    per input (bound in ``out``), given to one zip as many times as the input has
    elements, so zip takes each step's elements in order."""
    if len(step_inputs) == 1 and ports[step_inputs[0]].size == 1:
        return _values(arrays[step_inputs[0]])
    iterators = []
    for name in step_inputs:
        out.append(f"{name}_values = iter({_values(arrays[name])})")
        size = ports[name].size
        iterators.append(f"{name}_values" if size == 1 else f"*[{name}_values] * {size}")
    return f"zip({', '.join(iterators)})"


def _read_indices(lowered: LoweredProgram) -> dict[str, set[int]]:
    """Element indices of every input port that the step reads."""
    read: dict[str, set[int]] = {}
    stack = [s.tree for s in lowered.body]
    stack += [leaf for _, leaves in lowered.results for leaf in leaves]
    while stack:
        tree = stack.pop()
        if isinstance(tree, Var):
            if tree.index is not None:
                read.setdefault(tree.base, set()).add(tree.index)
        else:
            stack.extend(getattr(tree, "args", ()))
    return read


def single_track_loop(run: Run, lowered: LoweredProgram, arrays: dict[str, str],
                      indent: str = "        ") -> tuple[str, ...]:
    """Lines of the single-track branch of ``run`` (indented for the run function's body)
    for a stepping :class:`Run` whose step is ``lowered`` (without its pattern checks):
    its carried state, the rows its step reads, the carried inputs it stores.

    ``arrays`` maps the step's ports to the run's array names (``x`` -> ``x0``,
    ``P`` -> ``P0``, ``z`` -> ``zs``, ``p`` -> ``p``). The branch returns the stored
    arrays exactly as the general branch does.

    A run the pass :func:`derive.runs.shared.share_blocks` marked (identical blocks whose
    carried elements that read no data start bitwise equal: the covariances of identical
    axes from equal P0 blocks) first tries a loop that computes those statements once for
    all blocks, under a test of the initial state; its rows are bitwise those of the full
    loop.
    """
    (step,) = (c for c in walk(run.loops) if isinstance(c, Call))
    step_inputs = tuple(port for port, source in step.args if isinstance(source, Row))
    carried = tuple((s.name, s.new) for s in run.states)
    shapes = {p.name: p.shape for p in lowered.inputs}
    stored = tuple((s.state, shapes[s.state]) for s in walk(run.loops) if isinstance(s, Store))
    lines = _loop_lines(lowered, step_inputs, arrays, carried, stored)
    shared = run.shared
    if shared is not None:
        tests = [f"{arrays[port]}.reshape(-1)[{list(later)}].tobytes() == "
                 f"{arrays[port]}.reshape(-1)[{list(firsts)}].tobytes()"
                 for port, later, firsts in shared.equal]
        starts = " and ".join(arrays[port] for port, _, _ in shared.equal)
        lines = [f"# identical blocks starting equal in {starts}: {shared.dropped} statements "
                 "of the step",
                 "# read no data and are computed once (derive.runs.shared)",
                 *_wrap(f"if {' and '.join(tests)}:")] + \
            [f"    {line}" for line in _loop_lines(shared.program, step_inputs, arrays, carried,
                                                   stored)] + lines
    return tuple(indent + line for line in lines)


def _loop_lines(lowered: LoweredProgram, step_inputs: tuple[str, ...],
                arrays: dict[str, str], carried: tuple[tuple[str, str], ...],
                stored: tuple[tuple[str, tuple[int, ...]], ...]) -> list[str]:
    """The single-track loop of ``lowered`` and its return (unindented lines)."""
    ports = {p.name: p for p in lowered.inputs}
    name_of = local_names(set(ports))
    printer = PythonPrinter(name_of)
    results = dict(lowered.results)
    carried = [(port, out) for port, out in carried if port in ports and out in results]
    read = _read_indices(lowered)

    def text(tree) -> str:
        return printer.expression(tree)

    out: list[str] = []
    # the initial state and the parameters: only the elements the step reads
    for port, _ in carried:
        idx = sorted(read.get(port, ()))
        if idx:
            source = f"{arrays[port]}.reshape(-1)"
            if len(idx) < ports[port].size:
                source += f"[{idx}]"
            out += _unpack([local_name(port, i) for i in idx], f"{source}.tolist()")
    if read.get(PARAMETER_PORT) and PARAMETER_PORT not in step_inputs:
        out += _unpack([local_name(PARAMETER_PORT, i) for i in range(ports[PARAMETER_PORT].size)],
                       f"{arrays[PARAMETER_PORT]}.tolist()")
    # what each step keeps: the state's new elements, each distinct leaf once
    kept: list[str] = []
    columns: dict[str, list[int]] = {}
    for port, result in carried:
        columns[port] = []
        for leaf in results[result]:
            if text(leaf) not in kept:
                kept.append(text(leaf))
            columns[port].append(kept.index(text(leaf)))
    # each step's row packed into bytes at once (its floats freed at once, none kept
    # alive), appended to one bytearray, read as an array at the end
    out += ["rows = bytearray()", "keep = rows.extend",
            f'pack = struct.Struct("{len(kept)}d").pack']
    # the per-step inputs as doubles in one array each, iterated element by element (a
    # float made as it is read, freed with the step; no list of rows): an input of size
    # s repeats its iterator s times in one zip, so each step unpacks its elements
    source = _loop_source(step_inputs, ports, arrays, out)
    out += _wrap(f"for {_loop_target(step_inputs, ports, read)} in {source}:")
    body: list[str] = []
    # the new state: every element the next step reads, from this step's leaves
    leaves = [(local_name(port, i), results[result][i])
              for port, result in carried for i in sorted(read.get(port, ()))]
    inlined = _single_use(lowered)
    direct = _direct_state(lowered, leaves, name_of, inlined)
    printer = PythonPrinter(lambda var: direct.get(var.name) or name_of(var))
    width = len(kept)
    where = f'f"step {{len(rows) // {8 * width}}}: "'
    presence = [st for st in lowered.body if isinstance(st, LoweredCheck) and st.is_presence]
    for st in lowered.body:
        if isinstance(st, LoweredAssign):
            if st.target not in inlined:
                tree = _substitute(st.tree, inlined)
                body.append(f"{direct.get(st.target, st.target)} = {printer.expression(tree)}")
        elif st.is_presence:  # a program's share one status: one test, at the first
            if st is presence[0]:
                values = [printer.expression(_substitute(c.tree.args[0], inlined))
                          for c in presence]
                test = " and ".join(c.passes(v) for c, v in zip(presence, values))
                body += [f"if not ({test}):  # noqa: PLR0124 (false for NaN only)",
                         f"    raise NumericalError({where} + _nan_named(({', '.join(values)},"
                         f"), {presence_labels(presence)!r}, {st.message!r}))"]
        else:
            value = printer.expression(_substitute(st.tree.args[0], inlined))
            named = f' + f", got {{{value}!r}}"' if st.parameter else ""  # a parameter's value
            body += [f"if not {st.passes(value)}:",
                     f"    raise NumericalError({where} + {st.message!r}{named})"]
    kept_now = [printer.expression(leaf) for leaf in _kept_leaves(carried, results, text)]
    body += _wrap(f"keep(pack({', '.join(kept_now)}))")
    # the rest of the state (a leaf that reads the old state is bound first, so no
    # assignment sees a new value early)
    olds = {t for t, _ in leaves}
    assigned, early = [], []
    for target_, leaf in leaves:
        value = printer.expression(leaf)
        if value == target_:
            continue
        if {name_of(v) for v in tree_vars(leaf)} & olds:
            early.append(f"n_{target_} = {value}")
            value = f"n_{target_}"
        assigned.append((target_, value))
    body += early + [f"{t} = {v}" for t, v in assigned]
    out += [f"    {line}" for line in body]
    out.append(f'table = np.frombuffer(rows).reshape(-1, {width})')
    ret = [f"table[:, {columns[port]}]" if len(shape) == 1 else
           f"table[:, {columns[port]}].reshape(-1, {', '.join(str(d) for d in shape)})"
           for port, shape in stored]
    out += _wrap(f"return {ret[0]}" if len(ret) == 1 else f"return ({', '.join(ret)})")
    return out


def _kept_leaves(carried, results, text) -> list:
    """The distinct leaves of the carried results, in the order ``kept`` lists them."""
    seen: dict[str, object] = {}
    for _, result in carried:
        for leaf in results[result]:
            seen.setdefault(text(leaf), leaf)
    return list(seen.values())


def _direct_state(lowered: LoweredProgram, leaves, name_of,
                  inlined: dict[str, object]) -> dict[str, str]:
    """``{temporary: state local}`` for the temporaries that can be assigned to the state's
    local directly: the leaf of one state element, defined after the last statement that
    reads that element's old value (so the old value is dead when it is overwritten; a
    read inside an inlined temporary happens where its reader is)."""
    position = {st.target: k for k, st in enumerate(lowered.body)
                if isinstance(st, LoweredAssign)}
    reader = {v.name: k for k, st in enumerate(lowered.body)
              for v in tree_vars(st.tree) if v.name in inlined}
    last_read: dict[str, int] = {}
    for k, st in enumerate(lowered.body):
        at, target = k, getattr(st, "target", None)
        while target in inlined:
            at = reader[target]
            target = getattr(lowered.body[at], "target", None)
        for v in tree_vars(st.tree):
            last_read[name_of(v)] = max(last_read.get(name_of(v), -1), at)
    leaf_reads = {name_of(v) for _, leaf in leaves for v in tree_vars(leaf)}
    direct: dict[str, str] = {}
    for target, leaf in leaves:
        if not isinstance(leaf, Var) or leaf.index is not None or leaf.name in direct or \
                leaf.name not in position or target in leaf_reads:
            continue
        if last_read.get(target, -1) <= position[leaf.name]:
            direct[leaf.name] = target
    return direct


def _single_use(lowered: LoweredProgram) -> dict[str, object]:
    """``{temporary: tree}`` of the temporaries read exactly once, by a later statement with
    no check between: printed inside their reader (same operations, same order, one
    name fewer)."""
    uses: dict[str, int] = {}
    reader: dict[str, int] = {}
    for k, st in enumerate(lowered.body):
        for v in _var_occurrences(st.tree):
            if v.index is None:
                uses[v.name] = uses.get(v.name, 0) + 1
                reader[v.name] = k
    for _, leaves in lowered.results:
        for leaf in leaves:
            for v in _var_occurrences(leaf):
                uses[v.name] = uses.get(v.name, 0) + 2     # kept: never inlined
    checks = [k for k, st in enumerate(lowered.body) if not isinstance(st, LoweredAssign)]
    inlined: dict[str, object] = {}
    for k, st in enumerate(lowered.body):
        if not isinstance(st, LoweredAssign) or uses.get(st.target) != 1:
            continue
        if any(k < c < reader[st.target] for c in checks):
            continue
        if not isinstance(lowered.body[reader[st.target]], LoweredAssign):
            continue
        inlined[st.target] = st.tree
    # no printed expression deeper than the lowering allows (derive.lowering.MAX_DEPTH):
    # a reader that would be keeps its deepest inlined temporaries as names
    depth: dict[str, int] = {}      # an inlined temporary's depth, with those inlined in it
    for st in lowered.body:
        if not isinstance(st, LoweredAssign):
            continue
        inner = {v.name for v in _var_occurrences(st.tree) if v.name in inlined}
        while inner and _depth(st.tree, {name: depth[name] for name in inner}) > MAX_DEPTH:
            deepest = max(inner, key=depth.__getitem__)
            del inlined[deepest]
            inner.discard(deepest)
        if st.target in inlined:
            depth[st.target] = _depth(st.tree, {name: depth[name] for name in inner})
    return inlined


def _depth(tree, inlined_depth: dict[str, int]) -> int:
    """How deep ``tree`` prints with the temporaries of ``inlined_depth`` (name: depth)
    printed inside it (iterative: the trees may be deep)."""
    deepest, stack = 0, [(tree, 0)]
    while stack:
        node, above = stack.pop()
        if isinstance(node, Op):
            stack.extend((a, above + 1) for a in node.args)
        else:
            below = inlined_depth.get(node.name, 0) if isinstance(node, Var) else 0
            deepest = max(deepest, above + below)
    return deepest


def _var_occurrences(tree) -> list[Var]:
    found, stack = [], [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, Var):
            found.append(node)
        else:
            stack.extend(getattr(node, "args", ()))
    return found


def _substitute(tree, inlined: dict[str, object]):
    """``tree`` with each inlined temporary replaced by its own tree (recursively)."""
    if isinstance(tree, Var):
        inner = inlined.get(tree.name) if tree.index is None else None
        return tree if inner is None else _substitute(inner, inlined)
    if isinstance(tree, Op):
        return Op(tree.kind, tuple(_substitute(a, inlined) for a in tree.args))
    return tree


def _wrap(line: str, width: int = 88) -> list[str]:
    """Break a long line of comma-separated names inside brackets (implicit joining)."""
    if len(line) <= width:
        return [line]
    parts = line.split(", ")
    pieces = [part + ", " for part in parts[:-1]] + parts[-1:]
    lines, current = [], ""
    for piece in pieces:
        if current and len(current) + len(piece) > width:
            lines.append(current.rstrip())
            current = "        "
        current += piece
    lines.append(current)
    return lines
