"""Every package of the source tree is in pyproject's list, so `pip install .` ships it."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def test_every_package_is_listed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    listed = set(config["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "derive").rglob("__init__.py")}
    assert found - listed == set(), "add these to [tool.setuptools] packages"
    mapped = config["tool"]["setuptools"]["package-dir"]
    assert mapped["derive.templates"] == "templates"
