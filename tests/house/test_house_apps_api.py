"""derive/apps/ imports of the generator only what derive.public declares for it, and the
declaration names no private name (read with ``ast``, nothing imported)."""

from __future__ import annotations

import ast
from pathlib import Path

from test_import_graph import _top_level

from derive.public import APPLICATIONS

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "derive"


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module(p): p for p in PACKAGE.rglob("*.py") if "templates" not in p.parts}


def _imports(path: Path, module: str = ""):
    """(module, name or None for the module itself, line) of each import in ``path`` (the
    module ``module``, by default the file's)."""
    module = module or _module(path)
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from ((a.name, None, node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            parent = ".".join(base + ([node.module] if node.module else []))
            for a in node.names:
                full = f"{parent}.{a.name}"
                yield (full, None, node.lineno) if full in MODULES else \
                    (parent, a.name, node.lineno)


def _generator(module: str) -> bool:
    return module.split(".")[0] == "derive" and not module.startswith("derive.apps")


def _undeclared(path: Path, module: str = "") -> list[str]:
    return [f"{path.name}:{line} {imported}{'.' + name if name else ''}"
            for imported, name, line in _imports(path, module) if _generator(imported)
            and (imported not in APPLICATIONS
                 or (name is not None and name not in APPLICATIONS[imported]))]


def test_apps_import_only_the_declared_names():
    assert [line for path in sorted((PACKAGE / "apps").rglob("*.py"))
            for line in _undeclared(path)] == []


def test_a_private_or_undeclared_import_is_caught(tmp_path):
    app = tmp_path / "app.py"
    app.write_text("from derive.build import _compiler\n"
                   "from ...emit.render import render_c\n"
                   "from derive import cli\n"
                   "from derive.catalog import load\n"
                   "from ..verify import relative_error\n")
    assert [line.split()[1] for line in _undeclared(app, "derive.apps.bench.app")] == [
        "derive.build._compiler", "derive.emit.render.render_c", "derive.cli",
        "derive.catalog.load"]  # a module declared whole is imported whole


def _defined(path: Path) -> set[str]:
    names = set()
    for node in _top_level(ast.parse(path.read_text(encoding="utf-8")).body):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, ast.ImportFrom) and path.name == "__init__.py":
            names |= {a.asname or a.name for a in node.names}  # a package gathers its API
    return names


def test_the_declaration_names_public_names_the_modules_define():
    assert "derive.cli" not in APPLICATIONS
    assert "render_c" not in APPLICATIONS["derive.emit.render"]
    for module, names in APPLICATIONS.items():
        assert module in MODULES, module
        assert not [n for n in names if n.startswith("_") and n != "__version__"], module
        assert set(names) <= _defined(MODULES[module]), module
