"""Run loops are built on the lowered program, not on printed text: printers take a name
map, lanes and steps are renamed on the lowered program, the steady filters' two-step map
comes from their derivation; emit/ applies no regular expression to generated code and
does not import sympy."""

from __future__ import annotations

import ast
from pathlib import Path

import sympy

from derive import catalog
from derive.emit.c_printer import CPrinter
from derive.emit.python_printer import PythonPrinter
from derive.filters.steady import steady_gains, two_step_program
from derive.generation import derive_unit
from derive.lowering import lower_program
from derive.program import Port, Program
from derive.trees import Var, tree_vars

EMIT = Path(__file__).resolve().parents[2] / "derive" / "emit"
#: emit modules that may use ``re``: identifiers of units (unit.py) and names of leftover
#: files (write.py); neither sees generated code.
RE_ALLOWED = {"unit.py", "write.py"}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module.split(".")[0])
    return found


def test_emit_does_not_import_sympy():
    assert [p.name for p in sorted(EMIT.glob("*.py")) if "sympy" in _imports(p)] == []


def test_emit_applies_no_regular_expression_to_generated_code():
    users = {p.name for p in EMIT.glob("*.py") if "re" in _imports(p)}
    assert users <= RE_ALLOWED


def _program():
    prog = Program("step", [Port("x", (2,)), Port("z", (1,))], [Port("x_new", (2,))])
    x0, x1, z = prog.element("x", 0), prog.element("x", 1), prog.element("z", 0)
    shared = sympy.sqrt(x0 * x0 + z)
    prog.set_output("x_new", [shared + x1, shared * x1])
    return lower_program(prog.optimize())


def test_printers_take_a_name_map():
    lp = _program()
    trees = [st.tree for st in lp.body] + [leaf for _, leaves in lp.results for leaf in leaves]
    tree = next(t for t in trees if Var("x[1]") in tree_vars(t))

    def name(var: Var) -> str:
        return f"{var.base}_{var.index}" if var.index is not None else var.name.upper()

    for printer in (PythonPrinter, CPrinter):
        plain, mapped = printer().expression(tree), printer(name).expression(tree)
        assert "x[1]" in plain and "[" not in mapped and "x_1" in mapped


def test_renaming_is_done_on_the_lowered_program():
    lp = _program()
    lane = lp.renamed({"x": "x_l0", "x_new": "xn_l0", "z": "z_l0"}, lambda t: f"{t}_l0")
    read = {v.name for _, leaves in lane.results for leaf in leaves for v in tree_vars(leaf)}
    read |= {v.name for s in lane.body for v in tree_vars(s.tree)}
    targets = {s.target for s in lane.body}
    assert targets and all(t.endswith("_l0") and t.startswith("t") for t in targets)
    assert read and all(n.startswith(("x_l0[", "z_l0[")) or n in targets for n in read)
    assert [name for name, _ in lane.results] == ["xn_l0"]
    assert lane.temporaries() == 0 and lp.temporaries() == len(targets)


def test_two_step_map_comes_from_the_derivation():
    model = catalog.load("mpt3d_b")
    unit = derive_unit(model, "sskf", {})
    A, B = steady_gains(model, "sskf")
    assert unit.lookahead is not None
    expected = two_step_program(model.n, model.m, A, B)
    assert unit.lookahead.results == expected.results
    assert derive_unit(model, "kf", {}).lookahead is None
