"""Straight-line programs: the form between a derivation and the printers.

A :class:`Program` is one generated function with no loops and no branches
except runtime checks.  It has input and output :class:`Port` s (flat,
row-major arrays), a body of assignments ``tK = expr`` to temporaries, runtime
checks ``expr > 0`` (and ``P[k] == 0`` for inputs outside a pattern, ``p[k] >= 0`` or
``p[k] > 0`` for a parameter's declared domain, added by :meth:`Program.bind`) and, per
output port, the list of atoms (temporaries, input elements, numbers) written to
it.  Every expression is a sympy expression over *input elements* (symbols named
as generated code reads them, ``x[0]``, ``P[3]``) and earlier temporaries.

A derivation stages its algebra with :mod:`derive.staging`, so that every
matrix entry of every stage is one temporary (sympy stays fast, and zeros and
ones fold as they appear).  A worked example, one Kalman measurement update
of a 2-state model with a scalar measurement ``z = x[0] + v``, ``v ~ N(0, r)``::

    import sympy
    from derive.program import Port, Program
    from derive import staging

    prog = Program("update",
                   inputs=[Port("x", (2,)), Port("P", (2, 2), symmetric=True),
                           Port("z", (1,)), Port("p", (1,), doc="r")],
                   outputs=[Port("x_new", (2,)), Port("P_new", (2, 2), symmetric=True)])
    x, P, z = prog.matrix("x"), prog.matrix("P"), prog.matrix("z")
    model = prog.bind("p", [sympy.Symbol("r")])       # model symbol -> p[0]
    H = sympy.Matrix([[1, 0]])
    R = sympy.Matrix([[sympy.Symbol("r")]]).xreplace(model)
    PHt = staging.matmul(prog, P, H.T)                 # (2x1): the atoms P[0], P[1]
    S = staging.add(prog, staging.matmul(prog, H, PHt), R)
    Kt = staging.spd_solve(prog, S, PHt.T)             # K^T = S^-1 H P: two divisions
    K = staging.transpose(Kt)
    innovation = staging.sub(prog, z, staging.matmul(prog, H, x))
    prog.set_output("x_new", staging.add(prog, x, staging.matmul(prog, K, innovation)))
    KHP = staging.matmul(prog, K, PHt.T, symmetric_result=True)
    prog.set_output("P_new", staging.sub(prog, P, KHP, symmetric_result=True))
    step = prog.optimize()       # fold, propagate copies, share, drop dead code, renumber

``step`` is what :func:`derive.flops.count` counts and what the printers in
:mod:`derive.emit` print; ``derive.flops.count(step, "python")`` is exactly the
number of operations the printed Python executes.  ``spd_solve`` adds the
runtime check ``S > 0``: generated C returns a non-zero status, generated
Python raises :class:`derive.errors.NumericalError`, when it fails.

Conventions: a port named ``p`` holds the free parameters of the model and
must be the last input; C signatures list the other inputs, then the outputs,
then ``p``.  Programs never depend on ``PYTHONHASHSEED``: nothing iterates a
set, every ordering is by :func:`sympy.default_sort_key` or by position.
"""

from __future__ import annotations

import keyword
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from math import prod

import sympy
from sympy import default_sort_key

from derive.domains import DOMAINS, declared_domain, domain_message
from derive.domains import POSITIVE as DOMAIN_POSITIVE
from derive.errors import MatrixPropertyError, ShapeError
from derive.optimise import optimize_body
from derive.rows import RowChunk, check_chunks
from derive.sort_keys import SortKeys
from derive.statements import (
    NON_FINITE,
    NONNEGATIVE,
    POSITIVE,
    PRESENT,
    ZERO,
    Assign,
    Check,
    InputElement,
    Statement,
    Temporary,
    is_atom,
)

PARAMETER_PORT = "p"

_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if "
    "inline int long register restrict return short signed sizeof static struct switch typedef "
    "union unsigned void volatile while _Bool _Complex _Imaginary".split()
)
_RESERVED = frozenset({"np", "abs", "status", "steps", "track", "k", "i", "j", "NumericalError",
                       "x_next", "P_next", "P_work", "x_init", "padded"})
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_TEMP_LIKE = re.compile(r"^t\d+(_\w*)?$")


class ProgramError(RuntimeError):
    """A program built wrongly (unknown port, bad shape, unbound symbol, reuse): a bug in
    a derivation, not bad input, so not a :class:`derive.errors.ModelError` (the CLI
    reports it as an internal error, exit status 70)."""


@dataclass(frozen=True)
class Port:
    """One array argument of a generated function, stored flat and row-major.

    ``symmetric`` (square ``(n, n)`` ports only): an input reads only its upper
    triangle; an output is written mirrored.
    """

    name: str
    shape: tuple[int, ...]
    symmetric: bool = False
    doc: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ProgramError(f"port name {self.name!r} is not a plain identifier")
        if (keyword.iskeyword(self.name) or self.name in _C_KEYWORDS
                or self.name in _RESERVED or _TEMP_LIKE.match(self.name)):
            raise ProgramError(f"port name {self.name!r} is reserved in generated code")
        shape = tuple(self.shape)
        if not shape or len(shape) > 2 or not all(
                isinstance(d, int) and not isinstance(d, bool) and d >= 1 for d in shape):
            raise ShapeError(f"port {self.name!r}: shape must be (n,) or (n, k) with positive "
                             f"integers, got {self.shape!r}")
        object.__setattr__(self, "shape", shape)
        if self.symmetric and (len(shape) != 2 or shape[0] != shape[1]):
            raise ShapeError(f"port {self.name!r}: only a square (n, n) port can be symmetric, "
                             f"got shape {shape}")

    @property
    def size(self) -> int:
        """Number of doubles the port holds (flat)."""
        return prod(self.shape)

    def flat_index(self, i: int, j: int | None = None) -> int:
        """Flat row-major index of element ``(i,)`` or ``(i, j)``."""
        if j is None:
            if len(self.shape) != 1:
                raise ProgramError(f"port {self.name!r} has shape {self.shape}: give (i, j)")
            index = (i,)
        else:
            if len(self.shape) != 2:
                raise ProgramError(f"port {self.name!r} has shape {self.shape}: give i only")
            index = (i, j)
        for k, dim in zip(index, self.shape):
            if not isinstance(k, int) or not 0 <= k < dim:
                raise ProgramError(f"index {index} out of range for port {self.name!r} "
                                   f"of shape {self.shape}")
        return index[0] if j is None else index[0] * self.shape[1] + index[1]


class Program:
    """One straight-line generated function; see the module docstring."""

    def __init__(self, name: str, inputs: Sequence[Port], outputs: Sequence[Port],
                 doc: str = "") -> None:
        if not isinstance(name, str) or not _NAME.match(name) or keyword.iskeyword(name):
            raise ProgramError(f"program name {name!r} is not a plain identifier")
        self.name = name
        self.doc = doc
        self.inputs: tuple[Port, ...] = tuple(inputs)
        self.outputs: tuple[Port, ...] = tuple(outputs)
        seen: set[str] = set()
        for port in self.inputs + self.outputs:
            if not isinstance(port, Port):
                raise ProgramError(f"program {name!r}: {port!r} is not a Port")
            if port.name in seen:
                raise ProgramError(f"program {name!r}: port name {port.name!r} used twice")
            seen.add(port.name)
        names = [p.name for p in self.inputs]
        if PARAMETER_PORT in names and names[-1] != PARAMETER_PORT:
            raise ProgramError(f"program {name!r}: the parameter port {PARAMETER_PORT!r} must be "
                               f"the last input, got inputs {names}")
        if PARAMETER_PORT in [p.name for p in self.outputs]:
            raise ProgramError(f"program {name!r}: {PARAMETER_PORT!r} cannot be an output")
        self._elements: dict[str, list[InputElement]] = {}
        self._lower: dict[tuple[str, int], InputElement] = {}  # below a symmetric diagonal
        self._owner: dict[sympy.Symbol, str] = {}
        for port in self.inputs:
            if port.symmetric:  # (j, i) reads (i, j), the upper triangle's element
                cols = port.shape[1]
                flat = [None] * port.size
                for i in range(port.shape[0]):
                    for j in range(i, cols):
                        flat[i * cols + j] = flat[j * cols + i] = InputElement(
                            f"{port.name}[{i * cols + j}]")
            else:
                flat = [InputElement(f"{port.name}[{k}]") for k in range(port.size)]
            self._elements[port.name] = flat
            for sym in flat:
                self._owner[sym] = port.name
        self._body: list[Statement] = []
        self._defined: dict[Temporary, int] = {}
        self._results: dict[str, tuple[sympy.Expr, ...]] = {}
        self._counter = 0
        self._optimized = False
        self._order_names: dict[sympy.Symbol, sympy.Symbol] = {}
        self._rows: tuple[RowChunk, ...] = ()
        self._sort_keys: SortKeys | None = None

    # -- reading the program -------------------------------------------------------------

    @property
    def body(self) -> tuple[Statement, ...]:
        """The statements in order."""
        return tuple(self._body)

    @property
    def order_names(self) -> dict[sympy.Symbol, sympy.Symbol]:
        """For a program assembled from renamed copies of other programs: each symbol ->
        the symbol it copies, whose name orders the terms and factors it appears in when
        lowered (:mod:`derive.lowering`); empty: the symbols' own names."""
        return dict(self._order_names)

    def sort_keys(self) -> SortKeys:
        """sympy's order of this final program's expressions, its symbols named as in
        :attr:`order_names`, remembered: every lowering of the program (Python, C, its
        counts) shares one memo of keys."""
        if not self._optimized:
            raise ProgramError(f"sort_keys: program {self.name!r} is not final")
        if self._sort_keys is None:
            self._sort_keys = SortKeys(self._order_names)
        return self._sort_keys

    @property
    def rows(self) -> tuple[RowChunk, ...]:
        """The vector chunks of the body (:mod:`derive.rows`): each one's lanes are
        consecutive assignments of the body, lowered by the chunk's form; empty for a
        program of scalar statements only."""
        return self._rows

    @property
    def results(self) -> dict[str, tuple[sympy.Expr, ...]]:
        """Per output port (in port order), the flat atoms written to it."""
        return {p.name: self._results[p.name] for p in self.outputs if p.name in self._results}

    @property
    def has_checks(self) -> bool:
        """True when the body holds runtime checks (C returns a status)."""
        return any(isinstance(s, Check) for s in self._body)

    def port(self, name: str) -> Port:
        """The input or output port called ``name``."""
        for port in self.inputs + self.outputs:
            if port.name == name:
                return port
        raise ProgramError(f"program {self.name!r} has no port {name!r}; ports: "
                           f"{[p.name for p in self.inputs + self.outputs]}")

    def _input(self, name: str) -> Port:
        port = self.port(name)
        if port not in self.inputs:
            raise ProgramError(f"port {name!r} of program {self.name!r} is an output, not an input")
        return port

    def listing(self) -> str:
        """A readable dump of the program (for debugging and tests)."""
        lines = [f"program {self.name}({', '.join(p.name for p in self.inputs)}) -> "
                 f"({', '.join(p.name for p in self.outputs)})"]
        for st in self._body:
            if isinstance(st, Assign):
                lines.append(f"  {st.target} = {sympy.sstr(st.expr, order='lex')}")
            else:
                lines.append(f"  require {st.text}  # {st.message}")
        for name, values in self.results.items():
            lines.append(f"  {name} = [{', '.join(str(v) for v in values)}]")
        return "\n".join(lines)

    # -- building ----------------------------------------------------------------------

    def element(self, port: str, i: int, j: int | None = None) -> InputElement:
        """Symbol standing for input element ``port[i]`` or ``port[i, j]``.

        For a symmetric port, ``(i, j)`` and ``(j, i)`` give the same symbol (the
        upper triangle's).
        """
        return self._elements[self._input(port).name][self._input(port).flat_index(i, j)]

    def stored_element(self, port: str, i: int, j: int) -> InputElement:
        """The element stored at ``(i, j)`` of a 2-D input port, for a symmetric port in
        either triangle (``P[i*n + j]`` also below the diagonal, where :meth:`element`
        gives the upper triangle's): how a vector row reads a row of P whole."""
        p = self._input(port)
        k = p.flat_index(i, j)
        if not p.symmetric or i <= j:
            return self._elements[p.name][k]
        sym = self._lower.get((p.name, k))
        if sym is None:
            sym = self._lower[(p.name, k)] = InputElement(f"{p.name}[{k}]")
            self._owner[sym] = p.name
        return sym

    def matrix(self, port: str) -> sympy.Matrix:
        """The input port as a sympy Matrix of element symbols ((n,) ports: n x 1)."""
        p = self._input(port)
        rows, cols = (p.shape[0], 1) if len(p.shape) == 1 else p.shape
        return sympy.Matrix(rows, cols, self._elements[p.name])

    def bind(self, port: str, symbols: Sequence[sympy.Symbol]) -> dict[sympy.Symbol, InputElement]:
        """Map model symbols, in order, to the elements of a 1-D input port (for xreplace).

        Bound to the parameter port ``p``, each symbol that declares a domain
        (nonnegative or positive: :mod:`derive.domains`) gets its runtime check
        (:meth:`require_domain`), kept where the program reads the symbol."""
        p = self._input(port)
        symbols = list(symbols)
        if len(p.shape) != 1 or p.size != len(symbols):
            raise ShapeError(f"bind: port {port!r} has shape {p.shape}, but {len(symbols)} "
                             f"symbols were given: {[str(s) for s in symbols]}")
        binding = dict(zip(symbols, self._elements[p.name]))
        if p.name == PARAMETER_PORT:  # the parameters' declared domains, checked first
            for sym, element in binding.items():
                domain = declared_domain(sym)
                if domain is not None:
                    self.require_domain(element, sym.name, domain)
        return binding

    def _check_open(self) -> None:
        if self._optimized:
            raise ProgramError(f"program {self.name!r} is optimised and final: build on the "
                               "original, then optimise again")

    def _validate(self, expr: sympy.Basic, what: str) -> sympy.Expr:
        try:
            expr = sympy.sympify(expr)
        except (sympy.SympifyError, TypeError) as exc:
            raise ProgramError(f"{what}: {expr!r} is not a sympy expression") from exc
        if not isinstance(expr, sympy.Expr):
            raise ProgramError(f"{what}: {expr!r} is not a scalar expression")
        if expr.has(*NON_FINITE):
            raise MatrixPropertyError(f"{what}: the expression is not finite ({expr}); "
                                      "a structurally zero divisor?")
        unbound = [s for s in expr.free_symbols
                   if self._owner.get(s) is None and s not in self._defined]
        if unbound:
            name = sorted(unbound, key=default_sort_key)[0]
            raise ProgramError(
                f"{what} in program {self.name!r} uses symbol {str(name)!r}, which is neither an "
                "element of one of its input ports nor one of its temporaries (bind model symbols "
                "to the parameter port with Program.bind)")
        return expr

    def _new_temp(self, hint: str) -> Temporary:
        if not isinstance(hint, str) or not re.match(r"^[A-Za-z_]\w*$", hint):
            raise ProgramError(f"temporary hint {hint!r} is not an identifier")
        name = f"t{self._counter}" if hint == "t" else f"t{self._counter}_{hint}"
        self._counter += 1
        return Temporary(name)

    def let(self, expr: sympy.Expr, hint: str = "t") -> sympy.Expr:
        """Append ``tK = expr`` and return ``tK``; an atom (number, symbol) is returned as is."""
        self._check_open()
        expr = self._validate(expr, "let")
        if is_atom(expr):
            return expr
        target = self._new_temp(hint)
        self._defined[target] = len(self._body)
        self._body.append(Assign(target, expr))
        return target

    def set_output(self, port_name: str, flat_values: Iterable[sympy.Expr] | sympy.Matrix) -> None:
        """Set every element of an output port (flat, row-major; a Matrix is flattened).

        Non-atomic values get a temporary each.  For a symmetric port the values
        must be symmetric (entry (i, j) structurally equal to (j, i)).
        """
        self._check_open()
        port = self.port(port_name)
        if port not in self.outputs:
            raise ProgramError(f"set_output: {port_name!r} is an input of program {self.name!r}")
        if port_name in self._results:
            raise ProgramError(f"set_output: output {port_name!r} of {self.name!r} set twice")
        values = [self._validate(v, f"output {port_name}") for v in list(flat_values)]
        if len(values) != port.size:
            raise ShapeError(f"set_output: port {port_name!r} has shape {port.shape} "
                             f"({port.size} values), got {len(values)} values")
        if port.symmetric:
            n = port.shape[0]
            for i in range(n):
                for j in range(i + 1, n):
                    if values[i * n + j] != values[j * n + i]:
                        raise MatrixPropertyError(
                            f"set_output: symmetric port {port_name!r} gets different values at "
                            f"({i}, {j}) and ({j}, {i}): {values[i * n + j]} and "
                            f"{values[j * n + i]} (stage it with symmetric_result=True)")
            atoms = list(values)
            for i in range(n):
                for j in range(i, n):
                    atoms[i * n + j] = atoms[j * n + i] = self.let(values[i * n + j], port_name)
        else:
            atoms = [self.let(v, port_name) for v in values]
        self._results[port_name] = tuple(atoms)

    def require_positive(self, expr: sympy.Expr, message: str) -> None:
        """Runtime check that ``expr > 0`` (a NaN fails too).

        A value that is structurally a positive number needs no check; one that
        is structurally not positive raises MatrixPropertyError now.
        """
        self._check_open()
        value = self.let(expr, "check")
        if value.is_number:
            if value.is_positive is not True:
                raise MatrixPropertyError(f"{message} (the value is structurally {value})")
            return
        self._body.append(Check(value, message if isinstance(message, str) else str(message)))

    def require_domain(self, element: InputElement, name: str, domain: str) -> None:
        """Runtime check that the parameter element ``element`` (model symbol ``name``) lies
        in ``domain`` (``"nonnegative"``: >= 0, ``"positive"``: > 0; a NaN fails).

        Generated C returns a status (``parameter dt must be nonnegative``), generated
        Python raises :class:`derive.errors.NumericalError` naming the value; one
        comparison, counted as ``cmp``. Dropped when optimised if nothing else in the
        program reads ``element``."""
        self._check_open()
        if self._owner.get(element) != PARAMETER_PORT:
            raise ProgramError(f"require_domain: {element!r} is not an element of the "
                               f"parameter port of program {self.name!r}")
        if domain not in DOMAINS:
            raise ProgramError(f"require_domain: unknown domain {domain!r}; domains: "
                               f"{', '.join(DOMAINS)}")
        relation = POSITIVE if domain == DOMAIN_POSITIVE else NONNEGATIVE
        self._body.append(Check(element, domain_message(name, domain), relation,
                                parameter=name))

    def require_zero(self, element: InputElement, message: str) -> None:
        """Runtime check that the input element ``element`` is exactly 0 (a NaN fails).

        For inputs that the code treats as structurally zero (P outside its pattern):
        generated C returns a status, generated Python raises
        :class:`derive.errors.PatternError` naming the element and its value.
        """
        self._check_open()
        if self._owner.get(element) is None:
            raise ProgramError(f"require_zero: {element!r} is not an input element of "
                               f"program {self.name!r}")
        self._body.append(Check(element, str(message), ZERO))

    def renamed(self, name: str, doc: str, pattern_message: str | None = None) -> Program:
        """This final program as the program ``name`` (documented ``doc``); its zero checks
        fail with ``pattern_message`` when given."""
        if not self._optimized:
            raise ProgramError(f"renamed: program {self.name!r} is not final")
        out = Program(name, self.inputs, self.outputs, doc)
        body = [replace(st, message=pattern_message)
                if pattern_message is not None and isinstance(st, Check) and st.relation == ZERO
                else st for st in self._body]
        out._body, out._results = body, dict(self._results)
        out._defined = {st.target: k for k, st in enumerate(body) if isinstance(st, Assign)}
        out._counter = len(out._defined)
        out._optimized = True
        out._order_names = dict(self._order_names)
        out._rows = self._rows
        return out

    def with_presence_checks(self, port: str, names: Sequence[str], message: str) -> Program:
        """This final program with a check that each element of the input ``port`` is not
        NaN after its body (element k holds the measurement ``names[k]``), failing with
        ``message``: one comparison (``cmp``) each, one status for them all (generated C
        returns it before any output is written; derive.build and generated Python name
        the element that was NaN). Appended, so the statuses of the checks already there
        keep their numbers; a program whose measurements may be NaN by design (absent)
        takes none."""
        if not self._optimized:
            raise ProgramError(f"with_presence_checks: program {self.name!r} is not final")
        elements = self._elements[self._input(port).name]
        if len(names) != len(elements):
            raise ProgramError(f"with_presence_checks: {len(names)} names for the "
                               f"{len(elements)} elements of port {port!r}")
        checks = [Check(e, str(message), PRESENT, measurement=str(name))
                  for e, name in zip(elements, names)]
        out = self._final(self._body + checks, self._results)
        out._order_names = dict(self._order_names)
        out._rows = self._rows
        return out

    # -- optimising --------------------------------------------------------------------

    def optimize(self) -> Program:
        """A new, final program: folded, copies propagated, shared, dead code dropped, renumbered.

        Passes, in order: constant folding and copy propagation with merging of
        identical right-hand sides; staging of integer powers (a non-atomic base
        gets a temporary, ``x**k`` with ``|k| >= 4`` is built by squaring);
        sharing of common subexpressions across the whole body, each one kept
        only when it lowers the operation count; dead-code elimination;
        renumbering ``t0, t1, ...`` in order (the passes are in :mod:`derive.optimise`).
        Deterministic.  An optimised program is returned unchanged.
        """
        if self._optimized:
            return self
        missing = [p.name for p in self.outputs if p.name not in self._results]
        if missing:
            raise ProgramError(f"program {self.name!r}: outputs {missing} were never set")
        counter = iter(range(self._counter, 2**62))

        def fresh(hint: str) -> Temporary:
            return Temporary(f"t{next(counter)}_{hint}")

        body, results = optimize_body(self._body, self._results, fresh)
        return self._final(body, results)

    def assembled(self, body: Sequence[Statement], results: dict[str, Sequence[sympy.Expr]],
                  *, optimize: bool,
                  order_names: Mapping[sympy.Symbol, sympy.Symbol] | None = None,
                  rows: Sequence[RowChunk] = ()) -> Program:
        """A final program with this one's ports and a ``body`` built elsewhere (renamed
        parts of other programs: :mod:`derive.filters.blockwise`), its temporaries named
        ``t0, t1, ...`` in order, each output port's atoms in ``results``; optimised as a
        whole when ``optimize``, else taken as it is, its :attr:`order_names`
        ``order_names`` (each renamed symbol -> the symbol of the part it copies).
        Optimising renames the temporaries, so an optimised program takes no
        ``order_names``; ``rows``: its vector chunks (:attr:`rows`), only without
        optimising."""
        self._check_open()
        missing = [p.name for p in self.outputs if p.name not in results]
        if missing:
            raise ProgramError(f"program {self.name!r}: outputs {missing} were never set")
        results = {name: tuple(values) for name, values in results.items()}
        if not optimize:
            out = self._final(list(body), results)
            out._order_names = dict(order_names or {})
            out._rows = _checked_rows(out._body, rows)
            return out
        if rows:
            raise ProgramError(f"program {self.name!r}: an optimised assembly rewrites its "
                               "statements, so it cannot keep vector rows")
        if order_names:
            raise ProgramError(f"program {self.name!r}: an optimised assembly renumbers its "
                               "temporaries, so it cannot keep the order of its parts' names")
        out = Program(self.name, self.inputs, self.outputs, self.doc)
        out._body = list(body)
        out._results = results
        out._defined = {st.target: k for k, st in enumerate(out._body) if isinstance(st, Assign)}
        out._counter = len(out._defined)
        return out.optimize()

    def _final(self, body: list[Statement], results: dict[str, tuple[sympy.Expr, ...]]) -> Program:
        out = Program(self.name, self.inputs, self.outputs, self.doc)
        out._body = list(body)
        out._results = dict(results)
        out._defined = {st.target: k for k, st in enumerate(body) if isinstance(st, Assign)}
        out._counter = len(out._defined)
        out._optimized = True
        return out


def _checked_rows(body: Sequence[Statement], rows: Sequence[RowChunk]) -> tuple[RowChunk, ...]:
    """``rows``, checked against ``body``: each chunk's lanes are consecutive assignments
    whose expressions are the lanes of its form."""
    rows = tuple(rows)
    check_chunks(rows)
    where = {st.target: k for k, st in enumerate(body) if isinstance(st, Assign)}
    for chunk in rows:
        at = [where.get(t) for t in chunk.targets]
        if None in at or at != list(range(at[0], at[0] + len(at))):
            raise ProgramError(f"the lanes {[str(t) for t in chunk.targets]} of a vector chunk "
                               "are not consecutive assignments of the body")
        for lane, k in enumerate(at):
            if body[k].expr != chunk.form.expr(lane):
                raise ProgramError(f"{chunk.targets[lane]} = {body[k].expr} is not lane {lane} "
                                   "of its chunk's form")
    return rows
