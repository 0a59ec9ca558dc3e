"""Print lowered trees and programs as Python.

Only elementwise arithmetic is emitted (``+ - * /``, ``_sqrt(v) = v ** 0.5`` and the
missing-measurement select ``_if_present(z, a, b)``, the guards' ``_if_greater(l, r, a, b)``
and ``_if_at_least(l, r, a, b)``), so a generated function runs on
floats, on NumPy arrays with a trailing track axis (many tracks at once) and on
:class:`derive.flops.CountingFloat`.  Constants are printed with ``repr`` (shortest
round trip); negative ones in parentheses.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from derive.errors import NumericalError, PatternError
from derive.lowering import LoweredAssign, LoweredCheck, LoweredProgram, lower_program
from derive.program import PARAMETER_PORT
from derive.trees import Const, Op, Tree, Var, tree_vars

#: Precedence: higher binds tighter.
_PREC = {"add": 1, "sub": 1, "mul": 2, "div": 2, "neg": 3}
_SYMBOL = {"add": "+", "sub": "-", "mul": "*", "div": "/"}
_ATOM = 4

#: lowering call name -> Python spelling (NumPy ufuncs call methods of objects).
PY_CALLS = {"sin": "np.sin", "cos": "np.cos", "tan": "np.tan", "exp": "np.exp", "log": "np.log",
            "atan": "np.arctan", "atan2": "np.arctan2", "fabs": "abs",
            "ceil": "np.ceil"}

def _guard_helper(name: str, relation: str) -> list[str]:
    """The lines of a guard's select helper ``name(left, right, a, b)``: a where ``left
    relation right``, else b."""
    return [f'def {name}(left, right, a, b):',
            f'    """a where left {relation} right, else b (also for a NaN); per track for',
            '    arrays. With a CountingFloat the select is counted, and a constant result',
            '    onwards."""',
            f'    holds = left {relation} right',
            '    if isinstance(holds, np.ndarray):',
            '        return np.where(holds, a, b)',
            '    value = a if holds else b',
            '    counted = (getattr(left, "derive_selected", None)',
            '               or getattr(right, "derive_selected", None))',
            '    return value if counted is None else counted(value)']


HELPERS = {
    "sqrt": ['def _sqrt(v):',
             '    """Square root of a float, a NumPy array or a CountingFloat."""',
             '    return v ** 0.5'],
    "select": ['def _if_present(z, a, b):',
               '    """a where the measurement z is present (not NaN), else b; per track for',
               '    arrays.  With a CountingFloat z a constant result is counted onwards."""',
               '    present = z == z  # noqa: PLR0124 (false for NaN only)',
               '    if isinstance(present, np.ndarray):',
               '        return np.where(present, a, b)',
               '    value = a if present else b',
               '    counted = getattr(z, "derive_selected", None)',
               '    return value if counted is None else counted(value)'],
    "gate": ['def _if_at_most(v, bound, a, b):',
             '    """a where v <= bound, else b (also for a NaN v); per track for arrays.',
             '    With a CountingFloat v a constant result is counted onwards."""',
             '    within = v <= bound',
             '    if isinstance(within, np.ndarray):',
             '        return np.where(within, a, b)',
             '    value = a if within else b',
             '    counted = getattr(v, "derive_selected", None)',
             '    return value if counted is None else counted(value)'],
    "if_gt": _guard_helper("_if_greater", ">"),
    "if_ge": _guard_helper("_if_at_least", ">="),
    "pattern": ['def _require_zero(values, indices, n, name, message):',
                '    """Raise PatternError unless values[k] == 0 for every k in indices (every',
                '    track of an array): entries outside the pattern of the n x n matrix."""',
                '    if isinstance(values, np.ndarray) and indices:  # all in one comparison',
                '        rows = values[list(indices)].reshape(len(indices), -1)',
                '        wrong = np.flatnonzero((rows != 0).any(axis=1))',
                '        if not wrong.size:',
                '            return',
                '        indices = [indices[wrong[0]]]',
                '    for k in indices:',
                '        zero = values[k] == 0',
                '        if hasattr(zero, "all"):',
                '            zero = zero.all()',
                '        if not zero:',
                '            value = np.ravel(values[k]).astype(float)',
                '            value = float(value[value != 0][0])',
                '            entry = f"{name}[{k // n}][{k % n}]"',
                '            raise PatternError(f"{entry} = {value!r}: {message}")'],
    "matrix": ['def _matrix(flat, shape):',
               '    """A flat row-major result as an array of shape (then any track axes)."""',
               '    if any(np.ndim(v) for v in flat):  # tracks: constants broadcast',
               '        flat = np.broadcast_arrays(*flat)',
               '    array = np.array(flat)',
               '    return array.reshape(shape + array.shape[1:])'],
    "shape": ['def _require_shape(name, array, shape, text):',
              '    """Raise ShapeError unless the leading axes are shape (then tracks)."""',
              '    if array.shape[:len(shape)] != shape:',
              '        raise ShapeError(f"run: {name} must have shape {text}, then any "',
              '                         f"track axes; got {array.shape}")'],
    "real": ['def _real(name, value):',
             '    """value as a float64 array; DtypeError unless it holds real numbers that',
             '    float64 holds exactly (not complex, bool, str or object; no wider float)."""',
             '    array = np.asarray(value)',
             '    if array.dtype.kind not in "fiu" or (array.dtype.kind == "f" and',
             '                                         array.dtype.itemsize > 8):',
             '        raise DtypeError(f"run: {name} is an array of {array.dtype}; run takes "',
             '                         "real numbers as float64")',
             '    if array.dtype == np.float64:',
             '        return array',
             '    converted = array.astype(np.float64)',
             '    whole = array.dtype.kind in "iu"',
             '    if whole and not (converted.astype(array.dtype) == array).all():',
             '        raise DtypeError(f"run: {name} holds an integer float64 cannot represent "',
             '                         "exactly")',
             '    return converted'],
    "check": ['def _require_positive(value, message):',
              '    """Raise NumericalError unless value > 0 (every track of an array)."""',
              '    positive = value > 0',
              '    if hasattr(positive, "all"):',
              '        positive = positive.all()',
              '    if not positive:',
              '        raise NumericalError(message)'],
    "present": ['def _nan_named(values, labels, message):',
                '    """message, after the label of the first of values that is NaN (in any',
                '    track)."""',
                '    for value, label in zip(values, labels):',
                '        same = value == value  # noqa: PLR0124 (false for NaN only)',
                '        if not (same.all() if hasattr(same, "all") else same):',
                '            return f"{label}: {message}"',
                '    return message',
                '',
                '',
                'def _require_present(values, labels, message):',
                '    """Raise NumericalError naming the measurement unless no value is NaN',
                '    (every track of an array); a comparison each."""',
                '    present = True',
                '    for value in values:',
                '        same = value == value  # noqa: PLR0124 (false for NaN only)',
                '        present = (same.all() if hasattr(same, "all") else same) and present',
                '    if not present:',
                '        raise NumericalError(_nan_named(values, labels, message))'],
    "domain": ['def _require_domain(value, operator, message):',
               '    """Raise NumericalError naming the value unless value > 0 (operator ">") or',
               '    value >= 0 (">="): a parameter\'s declared domain (every track of an array;',
               '    a NaN fails)."""',
               '    within = value > 0 if operator == ">" else value >= 0',
               '    if hasattr(within, "all") and not within.all():',
               '        value, within = np.ravel(value)[~np.ravel(within)][0], False',
               '    if not within:',
               '        raise NumericalError(f"{message}, got {float(value)!r}")'],
}

ERROR_IMPORT = ['try:',
                '    from derive.errors import NumericalError',
                'except ImportError:  # derive not installed: a stand-in with the same base',
                '',
                '    class NumericalError(ArithmeticError):',
                '        """A numerical failure such as a non-positive pivot."""']

PATTERN_ERROR_IMPORT = [
    'try:',
    '    from derive.errors import PatternError',
    'except ImportError:  # derive not installed: a stand-in with the same base',
    '',
    '    class PatternError(ValueError):',
    '        """P (or P0) is not zero outside the pattern the code was generated for."""']


SHAPE_ERROR_IMPORT = [
    'try:',
    '    from derive.errors import ShapeError',
    'except ImportError:  # derive not installed: a stand-in with the same base',
    '',
    '    class ShapeError(ValueError):',
    '        """An argument of the wrong shape."""']


DTYPE_ERROR_IMPORT = [
    'try:',
    '    from derive.errors import DtypeError',
    'except ImportError:  # derive not installed: a stand-in with the same base',
    '',
    '    class DtypeError(ValueError):',
    '        """An argument that is not an array of real numbers run takes exactly."""']


def error_imports(lowered: list[LoweredProgram], run: bool = False) -> list[list[str]]:
    """The import blocks of the exception classes the programs (and ``run``) raise."""
    blocks = [SHAPE_ERROR_IMPORT, DTYPE_ERROR_IMPORT] if run else []
    if any(c for lp in lowered for c in lp.checks if not c.is_pattern):
        blocks.append(ERROR_IMPORT)
    if any(lp.pattern_checks for lp in lowered):
        blocks.append(PATTERN_ERROR_IMPORT)
    return blocks


class InfixPrinter:
    """Infix printing with minimal parentheses that keep the tree's evaluation order.

    ``names``: the name map, ``names(var) -> text`` for every variable printed (as
    SymPy's printers map symbols at print time); None prints each variable's name."""

    def __init__(self, names: Callable[[Var], str] | None = None) -> None:
        self.names = names

    def const(self, value: float) -> str:
        text = repr(float(value))
        return f"({text})" if text.startswith("-") else text

    def call(self, kind: str, args: list[str]) -> str:
        raise NotImplementedError

    def _prec(self, tree: Tree) -> int:
        return _PREC.get(tree.kind, _ATOM) if isinstance(tree, Op) else _ATOM

    def expression(self, tree: Tree) -> str:
        """Text of one tree."""
        if isinstance(tree, Const):
            return self.const(tree.value)
        if isinstance(tree, Var):
            return tree.name if self.names is None else self.names(tree)
        if tree.kind in _SYMBOL:
            left, right = tree.args
            prec = _PREC[tree.kind]
            a = self.expression(left)
            b = self.expression(right)
            if self._prec(left) < prec:
                a = f"({a})"
            if self._prec(right) <= prec:
                b = f"({b})"
            sep = f" {_SYMBOL[tree.kind]} " if prec == 1 else _SYMBOL[tree.kind]
            return f"{a}{sep}{b}"
        if tree.kind == "neg":
            inner = self.expression(tree.args[0])
            return f"-({inner})" if self._prec(tree.args[0]) <= _PREC["neg"] else f"-{inner}"
        return self.call(tree.kind, [self.expression(a) for a in tree.args])


class PythonPrinter(InfixPrinter):
    """Python spelling: ``_sqrt``, NumPy calls; no fma."""

    def call(self, kind: str, args: list[str]) -> str:
        if kind == "sqrt":
            return f"_sqrt({args[0]})"
        if kind == "select":
            return f"_if_present({', '.join(args)})"
        if kind == "gate":
            return f"_if_at_most({', '.join(args)})"
        if kind == "if_gt":
            return f"_if_greater({', '.join(args)})"
        if kind == "if_ge":
            return f"_if_at_least({', '.join(args)})"
        if kind.startswith("call:") and kind[5:] in PY_CALLS:
            return f"{PY_CALLS[kind[5:]]}({', '.join(args)})"
        raise ValueError(f"no Python spelling for operation {kind!r} (fma is C only)")


def expression(tree: Tree) -> str:
    """Python text of one lowered tree."""
    return PythonPrinter().expression(tree)


def helpers_needed(lowered: list[LoweredProgram]) -> list[str]:
    """Helper names (keys of :data:`HELPERS`) the programs use, in a fixed order."""
    kinds = set().union(*(lp.kinds() for lp in lowered)) if lowered else set()
    needed = []
    if "sqrt" in kinds:
        needed.append("sqrt")
    if "select" in kinds:
        needed.append("select")
    for kind in ("gate", "if_gt", "if_ge"):
        if kind in kinds:
            needed.append(kind)
    if any(lp.pattern_checks for lp in lowered):
        needed.append("pattern")
    if any(c for lp in lowered for c in lp.checks
           if not (c.is_pattern or c.parameter or c.is_presence)):
        needed.append("check")
    if any(c.is_presence for lp in lowered for c in lp.checks):
        needed.append("present")
    if any(c.parameter for lp in lowered for c in lp.checks):
        needed.append("domain")
    return needed


def uses_numpy_calls(lowered: list[LoweredProgram]) -> bool:
    """True when a printed call or helper needs ``np``."""
    kinds = set().union(*(lp.kinds() for lp in lowered)) if lowered else set()
    return bool({"select", "gate", "if_gt", "if_ge"} & kinds) or any(
        lp.pattern_checks or square_input_lines(lp) or any(c.parameter for c in lp.checks)
        for lp in lowered) or any(
        k.startswith("call:") and PY_CALLS.get(k[5:], "").startswith("np.") for k in kinds)


def _list_lines(name: str, items: list[str], width: int = 92) -> list[str]:
    one = f"{name} = [{', '.join(items)}]"
    if len(one) <= width:
        return [one]
    lines = [f"{name} = ["]
    row = ""
    for item in items:
        piece = f"{item}, "
        if row and len(row) + len(piece) > width - 4:
            lines.append("    " + row.rstrip())
            row = ""
        row += piece
    lines.append("    " + row.rstrip())
    lines.append("]")
    return lines


def function_parts(lowered: LoweredProgram, doc_lines: list[str] | None = None) -> dict:
    """Precomputed strings of one function: ``signature``, ``doc`` lines, ``body`` lines."""
    printer = PythonPrinter()
    params = signature_parameters(lowered)
    body: list[str] = square_input_lines(lowered) + pattern_check_lines(lowered)
    presence = [st for st in lowered.body if isinstance(st, LoweredCheck) and st.is_presence]
    unread = unread_temporaries(lowered)
    for st in lowered.body:
        if isinstance(st, LoweredAssign):
            target = f"_{st.target}" if st.target in unread else st.target
            body.append(f"{target} = {printer.expression(st.tree)}")
        elif st.is_presence:  # a program's share one status: one call, at the first
            if st is presence[0]:
                body.append(presence_call(presence, printer.expression))
        elif st.parameter:
            value = printer.expression(st.tree.args[0])
            body.append(f"_require_domain({value}, {st.operator!r}, {st.message!r})")
        elif not st.is_pattern:
            value = printer.expression(st.tree.args[0])
            body.append(f"_require_positive({value}, {st.message!r})")
    for name, leaves in lowered.results:
        body.extend(_list_lines(name, [printer.expression(leaf) for leaf in leaves]))
    names = [p.name for p in lowered.outputs]
    body.append(f"return {', '.join(names)}")
    if doc_lines is None:
        doc_lines = port_doc_lines(lowered)
    return {"signature": f"def {lowered.name}({params}):", "doc": doc_lines, "body": body}


def unread_temporaries(lowered: LoweredProgram) -> set[str]:
    """The temporaries no statement or result reads: the lanes a vector row computes
    beyond its row's end (the C computes them too, so the counts agree). Python prints
    them with a leading underscore, the name linters take as meant to be unused."""
    read = {var.name for st in lowered.body for var in tree_vars(st.tree)}
    read |= {var.name for _, leaves in lowered.results for leaf in leaves
             for var in tree_vars(leaf)}
    return {st.target for st in lowered.body
            if isinstance(st, LoweredAssign) and st.target not in read}


def presence_labels(checks: list[LoweredCheck]) -> tuple[str, ...]:
    """How an error names each checked measurement: ``zx (z[0])``."""
    return tuple(f"{c.measurement} ({c.tree.args[0].name})" for c in checks)


def presence_call(checks: list[LoweredCheck], expression: Callable[[Tree], str]) -> str:
    """The call of ``_require_present`` for a program's presence checks."""
    values = ", ".join(expression(c.tree.args[0]) for c in checks)
    return (f"_require_present(({values},), {presence_labels(checks)!r}, "
            f"{checks[0].message!r})")


def unread_parameters(lowered: LoweredProgram) -> bool:
    """True when the program takes ``p`` (last) but reads none of it (a nonlinear predict of a
    model whose parameters are in h alone): Python may then be called without it."""
    return (bool(lowered.inputs) and lowered.inputs[-1].name == PARAMETER_PORT
            and PARAMETER_PORT not in lowered.used_inputs())


def signature_parameters(lowered: LoweredProgram) -> str:
    """The parameters of the printed ``def``: the input ports, ``p=None`` when unread."""
    names = [p.name for p in lowered.inputs]
    if unread_parameters(lowered):
        names[-1] += "=None"
    return ", ".join(names)


def square_input_lines(lowered: LoweredProgram) -> list[str]:
    """Lines that accept a 2-D (n, n) matrix (then any track axes) for each flat n*n input
    port (P, R): it is flattened row-major; a flat one is used as it is (n = 1: a 2-D one
    is one whose second axis has length 1, [[r]], as [r] of one track is)."""
    lines = []
    for port in lowered.inputs:
        if len(port.shape) == 2 and port.shape[0] == port.shape[1] > 1:
            n, name = port.shape[0], port.name
            lines += [f"if len({name}) == {n}:  # a 2-D ({n}, {n}) {name}: flattened, row-major",
                      f"    {name} = np.reshape({name}, ({n * n},) + np.shape({name})[2:])"]
        elif port.shape == (1, 1):
            name = port.name
            lines += [f"if np.shape({name})[1:2] == (1,):  # a 2-D (1, 1) {name}: flattened",
                      f"    {name} = np.reshape({name}, (1,) + np.shape({name})[2:])"]
    return lines


def pattern_indices(lowered: LoweredProgram) -> dict[str, tuple[int, ...]]:
    """Per input port, the flat indices its zero checks require to be 0, in order."""
    out: dict[str, list[int]] = {}
    for check in lowered.pattern_checks:
        port, index = check.tree.args[0].name.rstrip("]").split("[")
        out.setdefault(port, []).append(int(index))
    return {port: tuple(indices) for port, indices in out.items()}


def pattern_check_lines(lowered: LoweredProgram, names: dict[str, str] | None = None) -> list[str]:
    """One ``_require_zero(...)`` line per port with zero checks (``names``: port -> the
    expression holding it flat, default the port itself); one comparison per entry."""
    if not lowered.pattern_checks:
        return []
    message = lowered.pattern_checks[0].message
    ports = {p.name: p for p in lowered.inputs}
    lines = []
    for port, indices in pattern_indices(lowered).items():
        source = (names or {}).get(port, port)
        label = source.split(".")[0]
        lines.append(f"_require_zero({source}, {indices!r}, {ports[port].shape[-1]}, "
                     f"{label!r}, {message!r})")
    return lines


def _shape_text(port) -> str:
    text = "x".join(str(d) for d in port.shape)
    return f"{text}, symmetric" if port.symmetric else text


def matrix_outputs(lowered: LoweredProgram) -> list:
    """The outputs with two axes (P, U): the public Python function returns them as
    arrays of that shape."""
    return [p for p in lowered.outputs if len(p.shape) == 2]


def flat_name(lowered: LoweredProgram) -> str:
    """The name of the function run's loop calls: ``_NAME``, returning the matrices flat,
    for a program with :func:`matrix_outputs` (``NAME`` itself returns them shaped);
    ``NAME`` otherwise."""
    return f"_{lowered.name}" if matrix_outputs(lowered) else lowered.name


def shaped_return_lines(lowered: LoweredProgram, call: str) -> list[str]:
    """``outputs = call`` and the return of the outputs, each matrix as an array of its
    shape (then any track axes) by ``_matrix``."""
    names = [p.name for p in lowered.outputs]
    shaped = [f"_matrix({p.name}, {p.shape!r})" if len(p.shape) == 2 else p.name
              for p in lowered.outputs]
    return [f"{', '.join(names)} = {call}",
            f"return {', '.join(shaped)}"]


def port_doc_lines(lowered: LoweredProgram, shaped: bool = False) -> list[str]:
    """Docstring lines: purpose, then one line per port (flat, row-major; ``shaped``: the
    outputs with two axes returned as arrays of that shape)."""
    square = " or 2-D (n, n) matrices" if square_input_lines(lowered) else ""
    lines = [doc_text(lowered.doc or f"The generated function {lowered.name}."), "",
             f"Arguments (flat, row-major sequences{square}; elements may be NumPy arrays):"]
    unread = unread_parameters(lowered)
    lines += [doc_text(f"    {p.name} [{_shape_text(p)}]: {p.doc}".rstrip(": ")
                       + (" (not read here: may be left out)"
                          if unread and p.name == PARAMETER_PORT else ""))
              for p in lowered.inputs]
    lines.append("Returns:")
    for p in lowered.outputs:
        if shaped and len(p.shape) == 2:
            text = (f"{p.shape} array" + (", symmetric" if p.symmetric else "")
                    + ", then any track axes")
            doc = p.doc.replace(", row-major", "")
        else:
            text, doc = _shape_text(p), p.doc
        lines.append(doc_text(f"    {p.name} [{text}]: {doc}".rstrip(": ")))
    if any(not c.is_pattern for c in lowered.checks):
        lines.append("Raises NumericalError when a runtime check fails.")
    for port, indices in pattern_indices(lowered).items():
        lines.append(f"Raises PatternError unless {port} is 0 outside its pattern "
                     f"(upper triangle, {len(indices)} entries).")
    return lines


def doc_text(text: str) -> str:
    return text.replace("\\", "\\\\").replace('"""', '\\"\\"\\"')


def function_source(lowered: LoweredProgram) -> str:
    """The full ``def`` of one lowered program (for exec; the templates lay out their own)."""
    parts = function_parts(lowered)
    lines = [parts["signature"], '    """' + parts["doc"][0]]
    lines += [f"    {line}".rstrip() for line in parts["doc"][1:]]
    lines.append('    """')
    lines += [f"    {line}" for line in parts["body"]]
    return "\n".join(lines) + "\n"


def python_function(program, *, namespace: dict | None = None) -> Callable:
    """Compile the printed Python of ``program.optimize()`` into a callable.

    The function is exactly what the templates emit (same printer), with its
    helpers; useful for verification and for the dynamic operation count.
    """
    lowered = lower_program(program, use_fma=False)
    scope: dict = {"np": np, "NumericalError": NumericalError, "PatternError": PatternError}
    for name in helpers_needed([lowered]):
        exec("\n".join(HELPERS[name]), scope)  # our own printed code
    if namespace:
        scope.update(namespace)
    exec(function_source(lowered), scope)
    return scope[lowered.name]
