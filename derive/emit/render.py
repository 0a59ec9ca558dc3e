"""Render a :class:`~derive.runs.unit.Unit` to Python or C99 source with Jinja2.

The templates (``templates/python/*.jinja``, ``templates/c/*.jinja``, package
``derive.templates``) only lay out strings computed here: header lines,
signatures, ``lhs = rhs`` lines.  Every program is optimised, lowered once
per language, counted from that lowering and printed from it, so each file's
header states the exact operation count of the code below it.  Output is
deterministic (no timestamps, no hash-ordered iteration).
"""

from __future__ import annotations

import importlib.resources
from functools import cache
from pathlib import Path

import jinja2
import numpy as np

from derive import interface
from derive.collection import few_collections
from derive.emit import c_lanes, c_loops, c_printer, c_run, python_printer, python_run
from derive.emit.c_loops import P_STRIDE, body_functions, body_name, step_function_body
from derive.emit.python_loop import single_track_loop
from derive.emit.python_run import PARAMETER_ROWS, PARAMETER_START
from derive.flops import LANGUAGES, count_lowered
from derive.lowering import LoweredProgram, lower_programs
from derive.precision import DOUBLE, Precision, precision
from derive.program import PARAMETER_PORT
from derive.runs import blocks, kinds, shared
from derive.runs.loops import Store, walk
from derive.runs.unit import Argument, Unit, run_arguments
from derive.runs.unit import sizes as run_sizes
from derive.runs.unit import space as array_space
from derive.trees import FUSED_KINDS
from derive.version import __version__


def derive_version() -> str:
    """derive.__version__ (the installed distribution's version, else "0.1.0")."""
    return __version__


def _template_source(name: str) -> str:
    try:
        root = importlib.resources.files("derive.templates")
        return root.joinpath(name).read_text(encoding="utf-8")
    except (ModuleNotFoundError, FileNotFoundError):
        # A source tree that is not installed: templates/ sits beside derive/.
        path = Path(__file__).resolve().parents[2] / "templates" / name
        return path.read_text(encoding="utf-8")


@cache
def environment() -> jinja2.Environment:
    """The Jinja2 environment: StrictUndefined, trailing newline kept, no autoescape."""
    return jinja2.Environment(
        loader=jinja2.FunctionLoader(_template_source),
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
        autoescape=False,
    )


def _order(unit: Unit) -> list[str]:
    if unit.run.sensors:  # predict, then the updates in the sensors' order
        return ["predict"] + [f"update_{s.name}" for s in unit.sensors]
    names = [n for n in ("init", "step") if n in unit.programs]
    return names + sorted(n for n in unit.programs if n not in ("init", "step"))


def _lowered(unit: Unit, use_fma: bool) -> dict[str, LoweredProgram]:
    """The unit's programs lowered in the file's order, their statuses numbered apart."""
    state = tuple(port for port, _ in unit.carried)
    return lower_programs([unit.programs[name] for name in _order(unit)], use_fma=use_fma,
                          state_ports=state)


def _dims(arg: Argument, sep: str) -> str:
    return sep.join(str(d) for d in arg.dims)


def describe(prefix: str, lowered: dict[str, LoweredProgram],
             run: list[Argument] | None = None, real: Precision = DOUBLE, *,
             c_run: bool = True, tracks: bool = False,
             unit: Unit | None = None) -> interface.Interface:
    """The interface of one file: a function per program (C: ``PREFIX_NAME``) and, with
    ``run`` (the run function's arguments), the run function (in C only when ``c_run``;
    with ``tracks``, C's ``PREFIX_run_tracks`` too, taking run's arguments per track);
    statuses of every check; ``real``: the C's element type; ``unit``: whose covariance
    may live in a tangent space (each array of x or P then says its space)."""
    functions, python = [], []

    def space(name: str) -> str:
        return "" if unit is None else array_space(unit, name)

    for lp in lowered.values():
        ports = {p.name: p for p in lp.inputs + lp.outputs}
        outputs = {p.name for p in lp.outputs}
        functions.append(interface.Function(
            name=f"{prefix}_{lp.name}", program=lp.name, returns_status=lp.has_checks,
            arguments=tuple(interface.Argument(name, ports[name].shape, name in outputs,
                                               space=space(name))
                            for name in c_printer.argument_order(lp))))
        python.append(interface.Function(
            name=lp.name, program=lp.name, returns_status=lp.has_checks,
            arguments=tuple(interface.Argument(p.name, p.shape, p in lp.outputs,
                                               space=space(p.name))
                            for p in lp.inputs + lp.outputs)))
    if run is not None:
        status = any(lp.has_checks for lp in lowered.values())
        args = tuple(interface.Argument(a.c_name, a.dims, a.output, a.optional,
                                        strided=a.c_name == PARAMETER_PORT, py_name=a.py_name,
                                        scratch=a.scratch, space=space(a.c_name))
                     for a in run)
        if c_run:
            functions.append(interface.Function(f"{prefix}_run", "run", status, args, True))
        if tracks:
            functions.append(interface.Function(f"{prefix}_run_tracks", "run_tracks", status,
                                                args, True))
        python.append(interface.Function("run", "run", status,
                                         tuple(a for a in args if not a.scratch), True))
    statuses = []
    for lp in lowered.values():
        messages = {c.status: c.message for c in lp.checks}
        pattern_checks = lp.pattern_checks
        zero = ({pattern_checks[0].status: tuple(sorted(c.tree.args[0].index
                                                        for c in pattern_checks))}
                if pattern_checks else {})
        # a domain check's relation is named as its domain ("positive", "nonnegative")
        parameters = {c.status: (c.tree.args[0].index, c.parameter, c.relation)
                      for c in lp.checks if c.parameter}
        presence = [c for c in lp.checks if c.is_presence]  # one status, the element named
        present = ({presence[0].status: (presence[0].tree.args[0].base,
                                         tuple(c.measurement for c in presence))}
                   if presence else {})
        statuses += [interface.Status(lp.name, number, messages[number], zero.get(number, ()),
                                      parameters.get(number, ()), present.get(number, ()))
                     for number in sorted(messages)]
    spaces = ({"storage": unit.n, "tangent": unit.nt}
              if unit is not None and unit.nt != unit.n else {})
    return interface.Interface(tuple(functions), tuple(statuses), tuple(python),
                               element=real.c_type, spaces=spaces)


def _language(lang: str, use_fma: bool, real: Precision = DOUBLE) -> str:
    if lang != "c":
        return "Python"
    c99 = "C99" if real is DOUBLE else f"C99 {real.words}"
    return f"{c99}, fma through DERIVE_FMA and DERIVE_FNMA" if use_fma else c99


def precision_line(unit: Unit, lang: str) -> list[str]:
    """The header's statement of a precision other than double (none for double, whose
    files are as they always were): C float32, or the Python staying double."""
    real = precision(unit.precision)
    if real is DOUBLE:
        return []
    if lang != "c":
        return [f"precision: double (float64); the C of this filter is {real.words} "
                f"(--precision {real.name}), this Python computes in double"]
    return [f"precision: {real.words} (C {real.c_type}): arrays, temporaries and arithmetic; "
            f"constants are the double nearest their exact value rounded once to the "
            f"nearest {real.c_type}; math.h's {real.math('sqrt')}, DERIVE_FMA is "
            f"{real.math('fma')} where {real.fast_fma}; unit roundoff "
            f"2^{int(np.log2(real.unit_roundoff))}"]


def _header_lines(unit: Unit, lang: str, lowered: dict[str, LoweredProgram]) -> list[str]:
    real = precision(unit.precision) if lang == "c" else DOUBLE
    language = _language(lang, any(lp.use_fma for lp in lowered.values()), real)
    lines = [f"{unit.title[:1].upper() + unit.title[1:]} for the model {unit.model}.",
             f"Generated by derive {derive_version()}; do not edit. Regenerate with:",
             f"    {unit.command or '(no command given)'}",
             "",
             f"model: {unit.model}",
             f"filter: {unit.filter} ({unit.title})",
             f"family: {unit.family}",
             f"n: {unit.n} (states)",
             *([f"n_tangent: {unit.nt} (P is {unit.nt} x {unit.nt} over the tangent space; "
                "arrays marked storage hold n numbers per state vector, tangent nt x nt)"]
               if unit.nt != unit.n else []),
             f"m: {unit.m} (measurements)",
             "parameters: " + (f"p = [{', '.join(unit.parameters)}]" if unit.parameters
                               else "none")] + precision_line(unit, lang)
    if unit.run.window:
        lines.append(f"window: {unit.window} (last measurements, newest first)")
    lines.append("interface (flat row-major arrays; steps = number of steps):" if lang == "c"
                 else "interface (matrices taken flat, row-major, or (n, n), returned (n, n); "
                      "steps = number of steps):")
    described = describe(unit.prefix, lowered, run_arguments(unit), real,
                         c_run=unit.run_function, tracks=unit.run_tracks, unit=unit)
    lines += described.c_lines() if lang == "c" else described.python_lines()
    if lang == "c" and unit.run_tracks:
        lines.append(f"    many tracks: {unit.prefix}_run_tracks(steps, tracks, the run's arrays "
                     "for each track, one track after another" + (", p and p_stride shared by "
                     "the tracks" if unit.parameters else "") + ")")
    if unit.parameters:
        np_ = len(unit.parameters)
        lines.append(f"run's p: one row of {np_} for every step (C: {P_STRIDE} 0) or one row "
                     f"per step, (steps, {np_}) (C: {P_STRIDE} {np_})"
                     if lang == "c" else
                     f"run's p: one row ({np_},) for every step or one row per step "
                     f"(steps, {np_})")
    for lp in lowered.values():
        sym = [p.name for p in lp.inputs + lp.outputs if p.symmetric]
        whole = [p.name for p in lp.inputs if p.symmetric and lp.reads_below_diagonal(p)]
        if sym:
            lines.append(f"symmetric in {lp.name}: {', '.join(sym)} (inputs: "
                         + (f"{', '.join(whole)} read whole, both triangles, so "
                            f"{' and '.join(whole)} must be symmetric; "
                            if whole else "upper triangle read; ")
                         + "outputs: written whole)")
    lines += described.status_lines(_raises(lowered.values()))
    for lp in lowered.values():
        lines.append(f"operations per call of {lp.name} ({language}): "
                     f"{count_lowered(lp).summary()}")
    lines += list(unit.facts)
    return lines


def _raises(lowered) -> str:
    """What Python raises for a non-zero status (the zero checks of a pattern share one
    status; Python raises PatternError for it, NumericalError else)."""
    pattern = any(lp.pattern_checks for lp in lowered)
    return "NumericalError" + (", or PatternError for P's pattern" if pattern else "")


def _render(template: str, context: dict) -> str:
    return environment().get_template(template).render(**context)


#: The Python step without its pattern check, which run's loop calls: P stays inside the
#: pattern by construction once P0 has been checked.
IN_PATTERN_STEP = "_step_in_pattern"


def _python_functions(lp: LoweredProgram) -> list[dict]:
    """The Python function(s) of one program.  One returning a matrix (P) is printed as
    the function run's loop calls, :func:`python_printer.flat_name`, returning it flat,
    and the public function, which calls it and returns the matrix as an (n, n) array
    (as run returns (steps, n, n)).  A ``step`` with a pattern check is printed as the
    check, then a call of :data:`IN_PATTERN_STEP`, which holds the rest (and which run's
    loop calls)."""
    pattern = lp.name == "step" and bool(lp.pattern_checks)
    if not pattern and not python_printer.matrix_outputs(lp):
        return [python_printer.function_parts(lp)]
    params = ", ".join(p.name for p in lp.inputs)
    outer = python_printer.function_parts(lp, python_printer.port_doc_lines(lp, shaped=True))
    if pattern:
        inner_name = IN_PATTERN_STEP
        body = python_printer.function_parts(lp.without_pattern_checks())
        body["body"] = body["body"][len(python_printer.square_input_lines(lp)):]
        body["doc"] = ["step without the check of P's pattern (run checks P0 once instead)."]
        checks = (python_printer.square_input_lines(lp)
                  + python_printer.pattern_check_lines(lp))
    else:
        inner_name = python_printer.flat_name(lp)
        body = python_printer.function_parts(lp)
        body["doc"] = [f"{lp.name} with its matrices flat, row-major (as run calls it)."]
        checks = []
    body["signature"] = f"def {inner_name}({params}):"
    outer["body"] = checks + python_printer.shaped_return_lines(lp, f"{inner_name}({params})")
    return [outer, body]


def _python_run_checks(step: LoweredProgram, unit: Unit) -> list[str]:
    """run's check of P0 against the pattern, once before the loop (none when an ``enter``
    program starts the carried state: it checks run's arguments itself)."""
    if not step.pattern_checks or "enter" in unit.programs:
        return []
    flat = f"P0.reshape(({unit.nt * unit.nt},) + P0.shape[2:])"
    return python_printer.pattern_check_lines(step, {"P": flat})


def _python_run_prologue(unit: Unit, inputs: list[Argument]) -> list[str]:
    """run's first lines: every input as a float64 array of the documented shape (then any
    track axes), or ShapeError naming the argument and both shapes (DtypeError for an
    array that is not real numbers float64 holds exactly: ``_real``).

    Accepted besides: a per-step input of one value per step as shape (steps,); P0 flat
    (n*n,); p as one row (np,) for every step or one row per step (steps, np)."""
    lines = [f"{a.py_name} = _real({a.py_name!r}, {a.py_name})" for a in inputs]
    tracks = []
    for a in inputs:
        name, dims = a.py_name, tuple(d for d in a.dims if d != "steps")
        text = "(" + ", ".join(str(d) for d in a.dims) + ("," if len(a.dims) == 1 else "") + ")"
        if a.c_name == PARAMETER_PORT:
            either = f"{text} or (steps, {dims[0]})"
            if dims == (1,):  # one parameter: a number is its row (as C's wrapper takes it)
                lines += [f"if {name}.ndim == 0:", f"    {name} = {name}.reshape(1)"]
            lines += [f"if {name}.ndim < 2:  # one row for every step",
                      f"    _require_shape({name!r}, {name}, {dims}, {either!r})",
                      f"    {PARAMETER_ROWS} = np.broadcast_to({name}, (steps,) + {name}.shape)",
                      "else:  # one row per step",
                      f"    _require_shape({name!r}, {name}, (steps,) + {dims}, "
                      f"f{either + ', steps = {steps} as ' + inputs[0].py_name + ' has'!r})",
                      f"    {PARAMETER_ROWS} = {name}"]
            if "init" in unit.programs:
                lines.append(f"{PARAMETER_START} = {PARAMETER_ROWS}[0] if steps else "
                             f"np.zeros({dims[0]})")
            tracks.append(f"{PARAMETER_ROWS}.shape[2:]")
            continue
        if a.dims[0] == "steps":
            if dims == (1,):
                lines += [f"if {name}.ndim == 1:  # one value per step",
                          f"    {name} = {name}[:, np.newaxis]"]
            if a is inputs[0]:
                lines += [f"_require_shape({name!r}, {name}, {name}.shape[:1] + {dims}, "
                          f"{text!r})", f"steps = {name}.shape[0]"]
            else:  # steps are the rows of the first input: the message says so
                counted = f"{text}, steps = {{steps}} as {inputs[0].py_name} has"
                lines.append(f"_require_shape({name!r}, {name}, (steps,) + {dims}, "
                             f"f{counted!r})")
        else:
            if len(dims) == 2 and dims[0] * dims[1] != dims[0]:
                flat = dims[0] * dims[1]
                lines += [f"if {name}.shape[:1] == ({flat},):  # flat, row-major",
                          f"    {name} = {name}.reshape({dims} + {name}.shape[1:])"]
            lines.append(f"_require_shape({name!r}, {name}, {dims}, {text!r})")
        tracks.append(f"{name}.shape[{len(a.dims)}:]")
    # one track (no trailing axes) without np.broadcast_shapes, which costs microseconds
    lines += [f"tracks = ({', '.join(tracks)}{',' if len(tracks) == 1 else ''})",
              "track = np.broadcast_shapes(*tracks) if any(tracks) else ()"]
    return lines


def _python_context(unit: Unit, lowered: dict[str, LoweredProgram]) -> dict:
    """What every Python file's template is given: the header, the helpers its programs
    need, run's signature, doc and prologue."""
    lps = list(lowered.values())
    header = [python_printer.doc_text(line) for line in _header_lines(unit, "python", lowered)]
    args = run_arguments(unit)
    inputs = [a for a in args if not a.output]
    return {
        "title": header[0],
        "header": header[1:],
        "numpy": True,
        "error_imports": python_printer.error_imports(lps, run=True),
        "helpers": ["\n".join(python_printer.HELPERS[h])
                    for h in python_printer.helpers_needed(lps) + ["real", "shape"]
                    + (["matrix"] if any(map(python_printer.matrix_outputs, lps)) else [])],
        "run_signature": f"def run({', '.join(a.py_name for a in inputs)}):",
        "run_doc": [python_printer.doc_text(f"{a.py_name} [{_dims(a, ', ')}]: {a.doc}")
                    for a in args if not a.scratch],
        "prologue": _python_run_prologue(unit, inputs),
        "single": (),
        "n": unit.n,
        "about": unit.about.get("python", "Run the filter over a sequence of steps."),
    }


def _render_python_sensors(unit: Unit) -> dict[str, str]:
    """The Python file of a unit of the run kind ``sensors`` (derive.runs.kinds.sensors)."""
    lowered = _lowered(unit, use_fma=False)
    context = {**_python_context(unit, lowered),
               "functions": [part for lp in lowered.values() for part in _python_functions(lp)],
               "run_checks": [],
               "loop": python_run.run_lines(kinds.sensors(unit, lowered), lowered,
                                            {a.c_name: a.py_name for a in run_arguments(unit)},
                                            _loop_functions(lowered))}
    return {f"{unit.filter}.py": _render("python/run.jinja", context)}


def _c_parameters(unit: Unit, real: Precision, lead: tuple[str, ...] = ("size_t steps",)
                  ) -> str:
    """C run's parameters (``lead``, run's arrays, p's stride), joined."""
    arrays = [(f"{real.c_type} *" if a.output else f"const {real.c_type} *") + a.c_name
              for a in run_arguments(unit)]
    return ", ".join([*lead, *arrays] + ([f"size_t {P_STRIDE}"] if unit.parameters else []))


def _c_frame(unit: Unit, lps: list[LoweredProgram], real: Precision, header_lines: list[str],
             sizes: list[str], described: interface.Interface) -> dict:
    """The C files' frame both renderings share: header comment, include guard, the
    defines (restrict, sizes, statuses), includes and the fma macros."""
    enum = status_enum(unit.prefix, described)
    return {"header": [c_printer.comment_text(line) for line in header_lines],
            "guard": include_guard(f"{unit.model}_{unit.filter}", unit.symbol_prefix),
            "defines": c_printer.restrict_lines(unit.symbol_prefix) + [""] + sizes
            + ([""] + enum if enum else []),
            "h_file": f"{unit.filter}.h",
            "math_h": c_printer.needs_math_h(lps),
            "fma_macro": c_printer.macro_lines(lps, real),
            "about": unit.about.get("c", "Run the filter over steps steps.")}


def _render_c_sensors(unit: Unit, use_fma: bool, real: Precision) -> dict[str, str]:
    """The C files of a unit of the run kind ``sensors`` (derive.runs.kinds.sensors)."""
    lowered = _lowered(unit, use_fma=use_fma)
    lps = list(lowered.values())
    header_lines = _header_lines(unit, "c", lowered)
    described = describe(unit.prefix, lowered, run_arguments(unit), real, unit=unit)
    header_lines.append(described.block())
    status = any(lp.has_checks for lp in lps)
    prefix = unit.prefix
    run_signature = f"{'int' if status else 'void'} {prefix}_run({_c_parameters(unit, real)})"
    sizes = [f"#define {prefix}_N {unit.n}", f"#define {prefix}_M {unit.m}",
             *([f"#define {prefix}_NT {unit.nt}"] if unit.nt != unit.n else []),
             f"#define {prefix}_NP {len(unit.parameters)}",
             f"#define {prefix}_NU {unit.n_inputs}"]
    sizes += [f"#define {prefix}_M_{s.name.upper()} {s.m}" for s in unit.sensors]
    restrict = c_printer.restrict_macro(unit.symbol_prefix)
    context = {
        **_c_frame(unit, lps, real, header_lines, sizes, described),
        "prototypes": [c_printer.prototype(lp, prefix, restrict, real) + ";" for lp in lps]
        + [run_signature + ";"],
        "math_h": c_printer.needs_math_h(lps) or any(s.gated for s in unit.sensors),
        "functions": [c_printer.function_parts(lp, prefix, real) for lp in lps],
        "run_signature": run_signature,
        "run_body": c_run.run_lines(kinds.sensors(unit, lowered), lowered, prefix,
                                    unit.n_inputs, real),
    }
    return {f"{unit.filter}.h": _render("c/header.jinja", context),
            f"{unit.filter}.c": _render("c/run.jinja", context)}


def _loop_functions(lowered: dict[str, LoweredProgram]) -> dict[str, str]:
    """The function run's loop calls for each program: the one returning matrices flat
    (python_printer.flat_name), the step without its pattern check where it has one."""
    names = {name: python_printer.flat_name(lp) for name, lp in lowered.items()}
    if "step" in lowered and lowered["step"].pattern_checks:
        names["step"] = IN_PATTERN_STEP
    return names


@few_collections()
def render_python(unit: Unit) -> dict[str, str]:
    """``{MODEL_FILTER.py: text}``."""
    if unit.run.sensors:
        return _render_python_sensors(unit)
    lowered = _lowered(unit, use_fma=False)
    args = run_arguments(unit)
    run = kinds.BUILDERS[unit.kind](unit, lowered)
    single: tuple[str, ...] = ()
    stores = [s for s in walk(run.loops) if isinstance(s, Store)]
    ports = {p.name: p for p in lowered["step"].inputs}  # a store of the carried state only
    if (kinds.BUILDERS[unit.kind] is kinds.stepping and "enter" not in lowered
            and "store" not in lowered and all(s.state in ports for s in stores)
            and not unit.update_first):
        # one track: the step's statements inline (derive.emit.python_loop), from the start
        # arrays (a predictor's from init(x0), computed before the loop)
        arrays = {a.c_name: a.py_name for a in args if not a.output}
        arrays = {**{name: arrays[name] for name in unit.step_inputs},
                  **{s.name: "x_start" if run.enter is not None else s.start
                     for s in run.states}, PARAMETER_PORT: PARAMETER_ROWS}
        step = lowered["step"].without_pattern_checks()
        single = single_track_loop(shared.share_blocks(run, step), step, arrays, indent="    ")
    context = {
        **_python_context(unit, lowered),
        "functions": [part for lp in lowered.values() for part in _python_functions(lp)],
        "run_checks": _python_run_checks(lowered["step"], unit),
        "single": single,
        "loop": python_run.run_lines(run, lowered, {a.c_name: a.py_name for a in args},
                                     _loop_functions(lowered), single),
    }
    return {f"{unit.filter}.py": _render("python/run.jinja", context)}




def include_guard(name: str, symbol_prefix: str = "") -> str:
    """The header's include guard: ``name`` (``MODEL_FILTER``) verbatim, so it is unique per
    model and filter whatever the case of the names (``Axis_kf`` and ``axis_kf`` differ),
    with the ``--prefix`` in front like every other name the header defines."""
    return f"{symbol_prefix}DERIVE_{name}_H"


def status_enum(prefix: str, described: interface.Interface) -> list[str]:
    """The header's status enum (empty without statuses): ``PREFIX_STATUS_OK = 0``, then
    each status of the header's list by its name (:meth:`interface.Status.identifier`)
    and number. The functions return these values as ``int``: an enum's size is the
    compiler's choice (``-fshort-enums``), an int is the same in every C and C++ ABI."""
    if not described.statuses:
        return []
    constants = [f"{prefix}_STATUS_OK = 0"] + [
        f"{prefix}_STATUS_{s.identifier()} = {s.number}" for s in described.statuses]
    return (["/* the statuses listed above, by name (the functions return them as int) */",
             f"enum {prefix}_status {{"]
            + [f"    {c}{',' if i < len(constants) - 1 else ''}"
               for i, c in enumerate(constants)]
            + ["};"])


def _run_on_track(unit: Unit, status: bool) -> list[str]:
    """run_tracks' call of run on track t's arrays (optional ones may be NULL)."""
    sizes = run_sizes(unit)

    def track_array(arg: Argument) -> str:
        if arg.c_name == PARAMETER_PORT:
            return arg.c_name
        size = " * ".join(str(sizes.get(d, d)) for d in arg.dims)
        part = f"{arg.c_name} + t * {size}"
        return f"{arg.c_name} ? {part} : NULL" if arg.optional else part

    call = f"{unit.prefix}_run(steps, " + ", ".join(
        track_array(a) for a in run_arguments(unit)) + (
        f", {P_STRIDE})" if unit.parameters else ")")
    return ([f"const int track_status = {call};", "if (track_status) {",
             "    return track_status;", "}"] if status else [f"{call};"])


@few_collections()
def render_c(unit: Unit, *, use_fma: bool = True) -> dict[str, str]:
    """``{MODEL_FILTER.h: text, MODEL_FILTER.c: text}``."""
    real = precision(unit.precision)
    if unit.run.sensors:
        return _render_c_sensors(unit, use_fma, real)
    lowered = _lowered(unit, use_fma=use_fma)
    lps = list(lowered.values())
    header_lines = _header_lines(unit, "c", lowered)
    two = kinds.two_step_map(unit, use_fma)
    if two is not None:
        header_lines += [
            "run: two steps per pass; x(k+1) by the step's own statements, x(k+2) from x(k) "
            "by the two-step map (A^2, A B, B: exact products rounded once), so only x(k+2) "
            "is carried from pass to pass",
            f"operations per pass of run, two steps ({_language('c', use_fma, real)}): "
            f"{(count_lowered(lowered['step']) + count_lowered(two)).summary()}"]
    described = describe(unit.prefix, lowered, run_arguments(unit), real,
                         c_run=unit.run_function, tracks=unit.run_tracks, unit=unit)
    status = any(lp.has_checks for lp in lps)
    prefix = unit.prefix
    # names verbatim (C is case sensitive): models Axis and axis get distinct macros
    size_defines = [f"#define {prefix}_N {unit.n}", f"#define {prefix}_M {unit.m}",
                    f"#define {prefix}_NP {len(unit.parameters)}"]
    if unit.run.window:
        size_defines.append(f"#define {prefix}_WINDOW {unit.window}")
    restrict = c_printer.restrict_macro(unit.symbol_prefix)
    step_lp = lowered["step"]
    run_signature = f"{'int' if status else 'void'} {prefix}_run({_c_parameters(unit, real)})"
    # without --no-run run is exported; else private to run_tracks (its last tracks), or none
    exported_run = [run_signature + ";"] if unit.run_function else []
    if not unit.run_function:
        run_signature = f"static {run_signature}" if unit.run_tracks else ""
    # run checks P0 once (run_checks); the loop's P stays in the pattern by construction.
    # The step's statements are printed once, in its body (derive.emit.c_loops): step, run
    # and run_tracks call it
    loop_step = step_lp.without_pattern_checks()
    step_body = body_name(prefix)
    run = kinds.BUILDERS[unit.kind](unit, lowered)
    if two is not None and kinds.BUILDERS[unit.kind] is kinds.stepping:
        run = kinds.two_steps(run, unit)
    starts = {s.name: (s.start, s.size) for s in run.states}

    def start_element(check, track: str = "") -> str:
        """The run's start array element a zero check of the step tests (P0 for P)."""
        var = check.tree.args[0]
        start, size = starts[var.base]
        return f"{start}[{track}{var.index}]" if not track else \
            f"{start}[{track} * {size} + {var.index}]"

    # an enter program checks run's arguments itself (its own statuses)
    start_checks = step_lp.pattern_checks if "enter" not in lowered else ()
    run_checks = [line for c in start_checks
                  for line in c_printer.pattern_check_lines(c, start_element(c), real)]
    tracks_checks = [line for c in start_checks
                     for line in c_printer.pattern_check_lines(c, start_element(c, "t"), real)]
    tracks_signature = (f"{'int' if status else 'void'} {prefix}_run_tracks("
                        f"{_c_parameters(unit, real, ('size_t steps', 'size_t tracks'))})"
                        if unit.run_tracks else "")
    # update-first: run's step 0 calls the update alone (its body, as the step's)
    loop_update = lowered["update"].without_pattern_checks() if unit.update_first else None
    bodies = [loop_step] + ([two] if two is not None else [])
    functions = body_functions(loop_step, step_body, real)
    if loop_update is not None:
        functions += body_functions(loop_update, body_name(prefix, "update"), real)
    if two is not None:
        functions += body_functions(two, body_name(prefix, "pass"), real)
    for lp in lps:
        parts = c_printer.function_parts(lp, prefix, real)
        if lp.name == "step":
            parts["body"] = step_function_body(lp, loop_step, step_body, real)
        elif lp.name == "update" and loop_update is not None:
            parts["body"] = step_function_body(lp, loop_update, body_name(prefix, "update"),
                                               real)
        functions.append(parts)
    used = step_lp.used_inputs()
    unused = [f"(void){name};" for name in (PARAMETER_PORT, P_STRIDE)
              if unit.parameters and PARAMETER_PORT not in used and not unit.run.window]
    bodied = {"step": loop_step} | ({"pass": two} if two is not None else {}) | (
        {"update": loop_update} if loop_update is not None else {})  # the loops'
    # identical blocks: run carries them in the lanes of one vector (derive.runs.blocks)
    laned = blocks.in_lanes(run, unit.kind, lowered | {"pass": two}) \
        if real is DOUBLE and not unit.run.window and not unit.update_first else None
    vector_run, vector_macros, vector_header = [], [], ""
    if laned is not None:
        # (a pass body is called by the scalar run alone where there is no run_tracks: the
        # vector run names it, else Clang finds an unused static inline function)
        vector_run = c_lanes.lanes_lines(
            laned, lowered | {"pass": two}, prefix,
            [f"(void){body_name(prefix, 'pass')};"] if two is not None else [], real)
        vector_macros = c_lanes.lanes_macro_lines(laned.lanes.width, any(
            lp.kinds() & FUSED_KINDS for lp in (loop_step, two) if lp is not None))
        vector_header = c_lanes.header_line(dict(laned.lanes.blocks)["step"])
    header_lines += [vector_header] if vector_header else []
    header_lines.append(described.block())
    context = {
        **_c_frame(unit, lps, real, header_lines, size_defines, described),
        # with a vector run, run checks P0 before either run (the template then does not)
        "block_run": vector_run,
        "prototypes": [c_printer.prototype(lp, prefix, restrict, real) + ";" for lp in lps]
        + exported_run + ([tracks_signature + ";"] if tracks_signature else []),
        "loop_macros": c_loops.CONTRACT_LINES + (
            c_loops.INLINE_LINES if any(c_loops.inlined(b) for b in bodies) else [])
        + (c_printer.FAIL_LINES if any(b.checks for b in bodies) else [])
        + (c_loops.tracks_macros(run, bodied, real) if unit.run_tracks else []) + vector_macros,
        "functions": functions,
        "run_signature": run_signature,
        "tracks_lines": c_loops.tracks_lines(tracks_signature, run, bodied | {
            name: lowered[name] for name in ("enter",) if name in lowered}, prefix, unused,
                                             tracks_checks, _run_on_track(unit, status),
                                             ["return 0;"] if status else [], real)
        if unit.run_tracks else [],
        "run_checks": run_checks,
    }
    if kinds.BUILDERS[unit.kind] is kinds.stepping:
        context["run_body"] = c_run.stepping_lines(
            run, lowered, prefix, bodied,
            run_checks if not vector_run else [], real)
    else:
        context["run_body"] = c_run.run_lines(run, lowered, prefix, real=real,
                                              per_step=unit.step_inputs)
    return {f"{unit.filter}.h": _render("c/header.jinja", context),
            f"{unit.filter}.c": _render("c/run.jinja", context)}


def render_unit(unit: Unit, lang: str, *, use_fma: bool = True) -> dict[str, str]:
    """Files of one unit in one language ("python" or "c"): ``{filename: text}``."""
    if lang == "python":
        return render_python(unit)
    if lang == "c":
        return render_c(unit, use_fma=use_fma)
    raise ValueError(f"unknown language {lang!r}; expected one of {LANGUAGES}")


def render_files(unit: Unit, langs: tuple[str, ...] = LANGUAGES, *,
                 use_fma: bool = True) -> dict[str, str]:
    """Every file of a unit in the given languages (render all before writing any)."""
    files: dict[str, str] = {}
    for lang in langs:
        files.update(render_unit(unit, lang, use_fma=use_fma))
    return files


def _function_header(name: str, lang: str, lowered: dict[str, LoweredProgram], command: str,
                     facts: tuple[str, ...]) -> list[str]:
    fused = any(lp.use_fma for lp in lowered.values())
    language = ("C99, fma through DERIVE_FMA and DERIVE_FNMA" if fused
                else "C99") if lang == "c" else "Python"
    lines = [f"Generated functions {name}.",
             f"Generated by derive {derive_version()}; do not edit. Regenerate with:",
             f"    {command or '(no command given)'}",
             "",
             "interface (flat row-major arrays):"]
    described = describe(name, lowered)
    lines += described.c_lines() if lang == "c" else described.python_lines()
    lines += described.status_lines(_raises(lowered.values()))
    for lp in lowered.values():
        lines.append(f"operations per call of {lp.name} ({language}): "
                     f"{count_lowered(lp).summary()}")
    lines += list(facts)
    return lines + [described.block()] if lang == "c" else lines


def render_functions(name: str, programs, lang: str, *, command: str = "",
                     facts: tuple[str, ...] = (), use_fma: bool = True) -> dict[str, str]:
    """Files holding only the given programs as functions (no run loop), named ``name``.

    For programs that are not a filter family's (tests, helpers); C functions are
    ``NAME_PROGRAM``.  Same printers, counts and header as :func:`render_unit`.
    """
    if not name.isidentifier():
        raise ValueError(f"file name {name!r} is not an identifier")
    if lang not in LANGUAGES:
        raise ValueError(f"unknown language {lang!r}; expected one of {LANGUAGES}")
    fma = use_fma and lang == "c"
    lowered = lower_programs(programs, use_fma=fma)
    lps = list(lowered.values())
    described = describe(name, lowered)
    enum = status_enum(name, described)
    if lang == "python":
        header = [python_printer.doc_text(x)
                  for x in _function_header(name, lang, lowered, command, facts)]
        context = {
            "title": header[0], "header": header[1:],
            "numpy": python_printer.uses_numpy_calls(lps),
            "error_imports": python_printer.error_imports(lps),
            "helpers": ["\n".join(python_printer.HELPERS[h])
                        for h in python_printer.helpers_needed(lps)],
            "functions": [python_printer.function_parts(lp) for lp in lps],
        }
        return {f"{name}.py": _render("python/functions.jinja", context)}
    header = [c_printer.comment_text(x)
              for x in _function_header(name, lang, lowered, command, facts)]
    context = {
        "header": header, "guard": include_guard(name),
        "defines": c_printer.restrict_lines() + ([""] + enum if enum else []),
        "prototypes": [c_printer.prototype(lp, name, c_printer.restrict_macro()) + ";"
                       for lp in lps],
        "h_file": f"{name}.h", "math_h": c_printer.needs_math_h(lps),
        "fma_macro": c_printer.macro_lines(lps),
        "functions": [c_printer.function_parts(lp, name) for lp in lps],
    }
    return {f"{name}.h": _render("c/header.jinja", context),
            f"{name}.c": _render("c/functions.jinja", context)}
