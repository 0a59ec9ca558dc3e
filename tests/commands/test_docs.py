"""docs/robustness.md stays true: every table row names the test that checks it, every test
named there exists (for a parametrized id, pytest collects that id), and every
``tests/AREA/test_*.py`` path named in README.md or docs/*.md exists. Also the per-step costs of
the option ``missing`` in the page's table are those derive counts."""

import os
import re
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

from derive import catalog
from derive.filters import derive_unit
from derive.flops import count

ROOT = Path(__file__).resolve().parents[2]
ROBUSTNESS = ROOT / "docs" / "robustness.md"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# `test_name`, `test_name[param id]` or `tests/test_file.py::test_name[param id]`
TEST_REFERENCE = re.compile(r"`(?:(tests/(?:\w+/)?test_\w+\.py)::)?(test_\w+)(?:\[([^`]*)\])?`")
TEST_FILE = re.compile(r"tests/(?:\w+/)?test_\w+\.py")
SEPARATOR = re.compile(r"\|(\s*:?-+:?\s*\|)+\s*")
TEST_DEFINITION = re.compile(r"^(?:async )?def (test_\w+)\(", re.MULTILINE)


def table_rows(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every table row: not a table's first (header) line, not a
    separator line."""
    rows, in_table = [], False
    for number, line in enumerate(text.splitlines(), 1):
        is_row = line.startswith("|")
        if is_row and in_table and not SEPARATOR.fullmatch(line):
            rows.append((number, line))
        in_table = is_row
    return rows


@cache
def defined_tests() -> dict[str, set[str]]:
    """Test function name -> the files of tests/ (``tests/AREA/test_x.py``) that define it."""
    where: dict[str, set[str]] = {}
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        for name in TEST_DEFINITION.findall(path.read_text()):
            where.setdefault(name, set()).add(path.relative_to(ROOT).as_posix())
    return where


def collected_ids(files: list[str]) -> set[str]:
    """``tests/test_x.py::test_y[id]`` of every test pytest collects from ``files``."""
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         *files], cwd=ROOT, capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return {line for line in proc.stdout.splitlines() if "::" in line}


def test_every_table_row_names_a_test():
    unnamed = [f"docs/robustness.md:{number}: {line[:100]}"
               for number, line in table_rows(ROBUSTNESS.read_text())
               if not TEST_REFERENCE.search(line)]
    assert not unnamed, "rows that name no test:\n" + "\n".join(unnamed)


def test_every_named_test_exists():
    text = ROBUSTNESS.read_text()
    references = TEST_REFERENCE.findall(text)
    assert len(references) > 100, references  # the pattern still finds the page's names
    defined = defined_tests()
    problems, wanted = [], []
    for path, name, param in references:
        files = defined.get(name, set())
        if path and path not in files:
            problems.append(f"{path}::{name}: no such test function in {path}")
        elif not files:
            problems.append(f"{name}: no test function of that name in tests/")
        elif param:
            wanted.append((sorted([path] if path else files), name, param))
    assert not problems, "\n".join(problems)
    collected = collected_ids(sorted({f for files, _, _ in wanted for f in files}))
    for files, name, param in wanted:
        if not any(f"{f}::{name}[{param}]" in collected for f in files):
            problems.append(f"{name}[{param}]: pytest collects no such id from {files}")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_named_test_files_exist(page):
    absent = sorted(n for n in set(TEST_FILE.findall(page.read_text()))
                    if not (ROOT / n).is_file())
    assert not absent, f"{page.name} names test files that do not exist: {absent}"


def test_table_rows_are_found_as_the_page_writes_them():
    text = "intro\n| a | b |\n|---|:-:|\n| x | `test_x` |\n| y | no test |\n\n| c |\n|---|\n"
    rows = table_rows(text)
    assert [line for _, line in rows] == ["| x | `test_x` |", "| y | no test |"]
    assert [bool(TEST_REFERENCE.search(line)) for _, line in rows] == [True, False]
    assert TEST_REFERENCE.findall("`tests/test_a.py::test_b[c d]`, `tests/test_e.py`") == [
        ("tests/test_a.py", "test_b", "c d")]


# -- the cost of the option `missing` (## Missing measurements) --------------------------

def missing_measurement_costs() -> dict[str, tuple[int, ...]]:
    """model -> (KF flops, KF flops missing, KF cmp, KF cmp missing, LF flops, LF flops
    missing), as the page's table states them."""
    section = ROBUSTNESS.read_text().split("\n## Missing measurements\n", 1)[1]
    section = section.split("\n## ", 1)[0]
    row = re.compile(r"\| (\w+) \| (\d+) → (\d+) \| (\d+) → (\d+) \| (\d+) → (\d+) \|")
    return {m[1]: tuple(int(v) for v in m.groups()[1:])
            for m in map(row.match, section.splitlines()) if m}


MISSING_COSTS = missing_measurement_costs()


@pytest.mark.parametrize("name", sorted(MISSING_COSTS))
def test_missing_measurement_costs_match_the_table(name):
    model = catalog.load(name)
    kf, kf_missing, lf, lf_missing = (
        count(derive_unit(model, filter_name, options).programs["step"], "c")
        for filter_name in ("kf", "lf") for options in ({}, {"missing": True}))
    assert (kf.flops, kf_missing.flops, kf.cmp, kf_missing.cmp, lf.flops,
            lf_missing.flops) == MISSING_COSTS[name]
