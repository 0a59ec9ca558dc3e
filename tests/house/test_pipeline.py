"""One pipeline (derive.pipeline): render, write, load, used by every caller that runs a
generated filter; derive.build.load_module_file the one way to import a file."""

import ast
from pathlib import Path

import numpy as np
import pytest

import derive
from derive import catalog
from derive.apps.simulate import simulate_linear
from derive.errors import FilterError, OptionError
from derive.filters import derive_unit
from derive.pipeline import load_generated, load_units

ROOT = Path(__file__).resolve().parents[2]


def test_load_generated_writes_and_loads_python_and_c(tmp_path):
    kf = load_generated("mpt3d_b", "kf", directory=tmp_path)
    assert derive.load_generated is load_generated
    assert kf.unit.prefix == "mpt3d_b_kf"
    assert sorted(p.name for p in kf.paths.values()) == ["kf.c", "kf.h", "kf.py"]
    assert all(p.parent == tmp_path / "mpt3d_b" for p in kf.paths.values())
    assert "derive generate mpt3d_b" in kf.paths[".py"].read_text()
    num = catalog.load("mpt3d_b").numeric()
    zs = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, 50, 3).zs
    xs_py, Ps_py = kf.python.run(zs, num.x0, np.eye(2))
    xs_c, Ps_c = kf.module("c").run(zs, num.x0, np.eye(2))
    np.testing.assert_allclose(xs_c, xs_py, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(Ps_c, Ps_py, rtol=1e-13, atol=1e-13)


def test_without_a_directory_the_files_are_removed_once_loaded():
    kf = load_generated(catalog.load("mpt3d_b"), "kf", lang="python")
    assert kf.paths == {} and kf.c is None
    assert kf.python.run(np.zeros((3, 1)), np.zeros(2), np.eye(2))[0].shape == (3, 2)
    with pytest.raises(FilterError, match="not loaded in 'c'"):
        kf.module("c")


def test_bad_language_and_options_are_refused_before_anything_is_written(tmp_path):
    with pytest.raises(FilterError, match="language 'fortran'"):
        load_generated("mpt3d_b", "kf", lang="fortran", directory=tmp_path)
    with pytest.raises(OptionError):
        load_generated("mpt3d_b", "kf", {"horizon": 3}, directory=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_load_units_builds_the_c_of_all_units_into_one_extension(tmp_path):
    model = catalog.load("mpt3d_a")
    kf, sskf = load_units([derive_unit(model, "kf"), derive_unit(model, "sskf")], "c", tmp_path)
    assert kf.c.lib is not None and kf.c.lib is sskf.c.lib
    assert (kf.python, sskf.python) == (None, None)
    assert sorted(p.name for p in (tmp_path / "mpt3d_a").iterdir()) == [
        "kf.c", "kf.h", "sskf.c", "sskf.h"]


def _calls(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            f = node.func
            names.add(f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", ""))
    return names


def test_one_pipeline_and_one_file_importer_in_the_source():
    """Outside derive.pipeline nothing in derive (or benchmarks/) writes generated files and
    then builds or imports them by hand; only derive.build executes a file as a module; the
    tests do neither."""
    # library.py: derive.apps.targets.library, the library layout's writer (its files are
    # built by cmake, make or a cross compiler, never loaded into Python)
    writers = {"generation.py", "paper.py", "pipeline.py", "write.py", "library.py"}
    loaders = {"build.py", "pipeline.py"}
    # derive.batch builds a .c file written before, by its path, in each Dask worker
    # (a cffi object cannot travel there); it writes nothing
    path_loaders = {ROOT / "derive" / "batch.py"}
    for path in [*(ROOT / "derive").rglob("*.py"), *(ROOT / "benchmarks").glob("*.py")]:
        calls = _calls(path)
        if path.name not in writers:
            assert "write_files" not in calls, path
        if path.name not in loaders and path not in path_loaders:
            assert not calls & {"build_c", "load_python"}, path
        if path.name != "build.py":
            assert "spec_from_file_location" not in calls, path
    for path in (ROOT / "tests").rglob("*.py"):
        assert "spec_from_file_location" not in _calls(path), path
