"""docs/python-api.md: its signatures are Python's, and its example runs as written."""

import importlib
import inspect
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGE = (ROOT / "docs" / "python-api.md").read_text(encoding="utf-8")


def _plain(signature: inspect.Signature) -> str:
    """The signature without annotations, as the page writes it."""
    return str(signature.replace(
        parameters=[p.replace(annotation=inspect.Parameter.empty)
                    for p in signature.parameters.values()],
        return_annotation=inspect.Signature.empty))


def test_every_signature_on_the_page_is_pythons():
    shown = re.findall(r"```text\n(derive\.[\w.]+)(\(.*\))\n```", PAGE)
    assert {name for name, _ in shown} == {
        "derive.LinearModel", "derive.NonlinearModel", "derive.Sensor", "derive.generate",
        "derive.build_c", "derive.load_python", "derive.batch.run_tracks", "derive.fit"}
    for name, text in shown:
        module, _, attribute = name.rpartition(".")
        obj = getattr(importlib.import_module(module), attribute)
        assert text == _plain(inspect.signature(obj)), name


def test_the_example_runs(tmp_path, monkeypatch):
    (block,) = re.findall(r"```python\n(.*?)```", PAGE, re.DOTALL)
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "docs/python-api.md", "exec"), {})


def test_the_batch_snippet_of_performance_md_runs(monkeypatch):
    """docs/performance.md's run_tracks snippet defines its arrays and runs as written
    (from the repository root: it reads generated/mpt3d_b/kf.c)."""
    text = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```python\n(.*?)```", text, re.DOTALL)
                 if "batch.run_tracks" in b)
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(block, "docs/performance.md", "exec"), scope)
    assert scope["xs"].shape == (64, 500, 2)
