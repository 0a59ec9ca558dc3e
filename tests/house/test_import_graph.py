"""The import graph of derive/, read from the source with ``ast`` (every import, the
function-local ones included): no circle, the program core layered bottom-up, imports at
the top except where a short list says why, and no module re-exporting another's names.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "derive"

#: Third-party packages that are optional (extras in pyproject.toml, or C toolchains
#: that may be missing), or heavy and needed only on a rare path (scipy): imported where
#: they are needed, so that derive works without them and starts fast.
OPTIONAL_DEPENDENCIES = {
    "casadi": "casadi extra: the Jacobian witness of derive verify, CasADi's C in the bench",
    "scipy": "a runtime dependency, not an extra: imported only on the rare path that needs "
             "it (the numeric Van Loan discretisation), since every CLI start-up loads "
             "derive.discretize",
    "matplotlib": "report extra: figures",
    "filterpy": "bench extra: a peer implementation",
    "pykalman": "bench extra: a peer implementation",
    "symforce": "bench: SymForce's generated C++ for the INS/GNSS EKF, a peer (ops, time)",
    "simdkalman": "bench extra: a peer implementation",
    "rich": "report extra: progress display",
    "georinex": "test extra only: an independent parse of the RINEX files",
    "cffi": "C builds need a compiler and cffi, loaded only when something is compiled",
    "dask": "dask extra: derive.batch on Dask arrays, the bench's Dask rows",
    "dask.array": "dask extra: derive.batch on Dask arrays, the bench's Dask rows",
    "distributed": "dask extra: the bench's Dask LocalCluster",
}

#: Modules that run when the CLI starts (``derive --help``): they import what a command
#: needs when that command runs, so that start-up stays fast.
CLI_START_UP = {
    "derive.cli": "the entry point: each command's arguments added when it is used",
    "derive.commands": "one module per command: each imports its work when it runs",
    "derive.apps.gnss.command": "the `derive gnss --real` command, imported by the CLI parser",
}

#: The program core, bottom-up: a module imports only modules before it.
PROGRAM_CORE = ["derive.statements", "derive.trees", "derive.expression_lowering", "derive.rows",
                "derive.optimise", "derive.program", "derive.lowering", "derive.flops"]


@dataclass(frozen=True)
class Import:
    module: str      # the importing module
    line: int
    target: str      # the imported module (a derive module, or a top-level package name)
    local: bool      # inside a function or class body
    annotation: bool  # under ``if TYPE_CHECKING:`` (never executed)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _sources() -> dict[str, Path]:
    # derive/templates holds Jinja sources of generated code, not modules of derive
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))
            if "templates" not in p.relative_to(PACKAGE).parts}


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _imports(module: str, path: Path, modules: set[str]) -> list[Import]:
    found: list[Import] = []
    is_package = path.name == "__init__.py"

    def targets(node: ast.Import | ast.ImportFrom) -> list[str]:
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                parent = ".".join(base + ([node.module] if node.module else []))
            else:
                parent = node.module or ""
            names = [f"{parent}.{a.name}" if f"{parent}.{a.name}" in modules else parent
                     for a in node.names]
        out = []
        for name in names:
            if name.split(".")[0] != "derive":
                out.append(name.split(".")[0])
                continue
            while name not in modules and "." in name:
                name = name.rsplit(".", 1)[0]
            out.append(name)
        return out

    def visit(node: ast.AST, local: bool, annotation: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.extend(Import(module, child.lineno, t, local, annotation)
                             for t in dict.fromkeys(targets(child)))
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda,
                                    ast.ClassDef)):
                visit(child, True, annotation)
            elif isinstance(child, ast.If) and _is_type_checking(child):
                visit(child, local, True)
            else:
                visit(child, local, annotation)

    visit(ast.parse(path.read_text(encoding="utf-8")), False, False)
    return found


@pytest.fixture(scope="module")
def imports() -> list[Import]:
    sources = _sources()
    return [imp for module, path in sources.items()
            for imp in _imports(module, path, set(sources))]


def _within(module: str, prefixes) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            connect(v)
    return circles


def test_the_graph_is_read_from_every_module(imports):
    modules = {imp.module for imp in imports}
    assert {"derive.program", "derive.optimise", "derive.emit.render",
            "derive.filters.kf"} <= modules
    assert any(imp.local for imp in imports)   # function-local imports are seen


def test_no_import_circle(imports):
    """Among all modules of derive (the generator and the applications), type-only imports
    included: a module whose annotations name a later one is as tied to it."""
    edges: dict[str, set[str]] = {}
    for imp in imports:
        if imp.target.startswith("derive") and imp.target != imp.module:
            edges.setdefault(imp.module, set()).add(imp.target)
    assert _circles(edges) == []


def test_circle_finder_finds_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_program_core_reads_bottom_up(imports):
    """statements -> trees -> expression_lowering -> rows -> optimise -> program -> lowering ->
    flops: no module imports a later one, type annotations included."""
    for imp in imports:
        if imp.module in PROGRAM_CORE and imp.target in PROGRAM_CORE:
            assert PROGRAM_CORE.index(imp.target) < PROGRAM_CORE.index(imp.module), imp


def test_derivation_imports_nothing_of_emit(imports):
    """The derivation (derive/filters/) and the language-free description of a run
    (derive/runs/) name no module of a language's rendering (derive/emit/)."""
    assert [f"{imp.module}:{imp.line} imports {imp.target}" for imp in imports
            if _within(imp.module, ("derive.filters", "derive.runs"))
            and _within(imp.target, ("derive.emit",))] == []


def test_model_imports_no_filter_option(imports):
    """The model declares what it is; the filters' options (derive.options) are a layer above
    it (the forms both name live in derive.forms)."""
    assert [imp for imp in imports if imp.module == "derive.model"
            and _within(imp.target, ("derive.options", "derive.filters", "derive.emit"))] == []


def test_generator_does_not_import_the_package_api(imports):
    """derive/__init__.py imports generation and build: a generator module importing
    ``derive`` itself would close a circle through them."""
    assert [imp for imp in imports if imp.target == "derive" and imp.module != "derive"] == []


def test_function_local_imports_only_where_allowed(imports):
    unexplained = [
        f"{imp.module}:{imp.line} imports {imp.target}" for imp in imports
        if imp.local and not imp.annotation
        and imp.target not in OPTIONAL_DEPENDENCIES
        and not _within(imp.module, CLI_START_UP)
    ]
    assert unexplained == []


def _top_level(body: list[ast.stmt]):
    """The statements of a module body, those under a top-level if or try included."""
    for node in body:
        yield node
        if isinstance(node, ast.If):
            yield from _top_level(node.body + node.orelse)
        elif isinstance(node, ast.Try):
            yield from _top_level(node.body + node.orelse + node.finalbody
                                  + [s for h in node.handlers for s in h.body])


def test_no_module_re_exports_another_modules_names():
    """A module's ``__all__`` names what it defines (a package's __init__ gathers its API)."""
    re_exported = {}
    for module, path in _sources().items():
        if path.name == "__init__.py":
            continue
        defined, listed = set(), []
        for node in _top_level(ast.parse(path.read_text(encoding="utf-8")).body):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                defined.add(node.name)
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
                defined |= names
                if "__all__" in names:
                    listed = [ast.literal_eval(e) for e in node.value.elts]
        missing = [name for name in listed if name not in defined]
        if missing:
            re_exported[module] = missing
    assert re_exported == {}


def test_riccati_names_only_its_solvers():
    from derive import horizon, riccati, system_checks

    for name in ("fir_order", "fir_taps", "pred_constants", "psd_sqrt", "check_detectable"):
        assert name not in riccati.__all__
        assert hasattr(horizon, name) or hasattr(system_checks, name)
    assert not hasattr(riccati, "fir_order")


def test_cli_help_imports_no_application():
    """``derive --help`` builds every parser; the work of the commands (verify, reports,
    bench, the C builds of the gnss run) is imported only when a command runs."""
    code = ("import sys, contextlib, io\n"
            "from derive import cli\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    assert cli.main(['--help']) == 0\n"
            "print('\\n'.join(sorted(sys.modules)))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT, check=True)
    loaded = set(done.stdout.split())
    assert "derive.cli" in loaded
    heavy = {"derive.apps.verify", "derive.apps.report", "derive.apps.bench", "derive.apps.audit",
             "derive.apps.paper", "derive.apps.gnss.generated", "derive.apps.casadi_bridge",
             "scipy", "matplotlib", "cffi"}
    assert sorted(loaded & heavy) == []
