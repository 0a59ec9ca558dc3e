"""Determinism: the same input gives byte-identical generated files under different
PYTHONHASHSEED values and on repeated runs in one process."""

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import sympy

from derive import catalog
from derive.generation import render_filter

ROOT = Path(__file__).resolve().parents[1]

MODEL_FILE = """\
[model]
name = "freeplane"
states = ["s", "v"]
measurements = ["zs", "zv"]
[parameters]
dt = { description = "free step" }
q = 0.01
r = { description = "free variance" }
[discrete]
F = [[1, "dt"], [0, 1]]
H = [[1, 0], [0, 1]]
Q = [["q*dt", 0], [0, "q"]]
R = [["r", "r/4"], ["r/4", "r"]]
"""

SCRIPT = """
import sys
from derive import catalog
from derive.generation import generate
for name in catalog.names():
    generate(name, None, "all", "gen")
generate("mpt3d_a", ["kf", "lf", "jklf"], "all", "gen_options",
         {"missing": True, "joseph": True, "P0_pattern": "dense"})
generate("freeplane.toml", ["kf", "lf", "jklf", "ikf"], "all", "gen_file", {"missing": True})
"""

SEEDS = ("0", "4294967295")


def tree(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_generated_files_do_not_depend_on_the_hash_seed(tmp_path):
    runs = {}
    for seed in SEEDS:
        work = tmp_path / f"seed{seed}"
        work.mkdir()
        (work / "freeplane.toml").write_text(MODEL_FILE)
        env = {**os.environ, "PYTHONHASHSEED": seed,
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT),
                                                           os.environ.get("PYTHONPATH")]))}
        runs[seed] = (work, subprocess.Popen([sys.executable, "-c", SCRIPT], cwd=work,
                                             env=env, stderr=subprocess.PIPE, text=True))
    trees = {}
    for seed, (work, proc) in runs.items():
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
        trees[seed] = tree(work)
    first = trees[SEEDS[0]]
    models = {name.split("/")[1] for name in first if name.startswith("gen/")}
    assert models == set(catalog.names())
    assert sum(name.startswith("gen_file/") for name in first) == 4 * 3
    for seed in SEEDS[1:]:
        assert sorted(trees[seed]) == sorted(first)
        differ = [name for name in first if trees[seed][name] != first[name]]
        assert not differ, f"PYTHONHASHSEED={seed} changes {differ[:5]}"


def test_repeated_runs_in_one_process_are_identical():
    """Twice in one process, with sympy's cache cleared in between: the same bytes."""
    model = catalog.load("gsm2d_a")
    jobs = [("kf", {}), ("kf", {"missing": True, "joseph": True}), ("lf", {"missing": True}),
            ("jklf", {}), ("sskf", {}), ("fir", {"eps": 1e-3}), ("pred", {"horizon": 3})]
    first = {(f, str(o)): render_filter(model, f, "all", o, "gsm2d_a", "gen") for f, o in jobs}
    sympy.core.cache.clear_cache()
    again = {(f, str(o)): render_filter(catalog.load("gsm2d_a"), f, "all", o, "gsm2d_a", "gen")
             for f, o in jobs}
    assert again == first
