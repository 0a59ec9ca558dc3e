"""README opens with the two commands, and CI runs exactly the second one."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"```sh\n(.*?)```", text, re.DOTALL)
    assert block and text.index(block.group(0)) < 200, "README must open with the commands"
    return [line for line in block.group(1).splitlines() if line.strip()]


def test_readme_opens_with_two_commands():
    main, tests = _commands()
    assert main.endswith("derive reproduce")
    assert "pytest" in tests


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert _commands()[1] + " || rc=$?" in ci


def test_readme_python_examples_run(tmp_path, monkeypatch):
    """The ```python blocks of README.md run as written, in order, in one namespace (the
    tour's second block uses the model of its first)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.DOTALL)
    assert blocks
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)


def test_the_quick_subset_names_test_files_that_exist():
    """The README's quick check: a pytest command over a few test files, each existing
    (a file renamed away would make it collect nothing)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```sh\n(.*?)```", text, re.DOTALL)
    quick = [line for block in blocks[1:] for line in block.splitlines()
             if line.startswith("pytest ")]
    assert len(quick) == 1
    files = [word for word in quick[0].split() if word.startswith("tests/")]
    assert 2 <= len(files) < len(list((ROOT / "tests").rglob("test_*.py"))) // 4
    for name in files:
        assert (ROOT / name).is_file() and re.search(r"^def test_", (ROOT / name).read_text(),
                                                     re.MULTILINE), name


def test_the_readme_installs_from_a_checkout():
    """derive-filters is not on the package index: the README says to install from a
    checkout (its first two commands do: ``pip install '.[...]'``)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "pip install derive-filters" not in text
    assert "install it from a\ncheckout" in text or "install it from a checkout" in text
    main, tests = _commands()
    assert "pip install -q '.[report]'" in main and "pip install -q '.[test]'" in tests
