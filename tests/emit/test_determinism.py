"""Determinism: the same input gives byte-identical generated files under different
PYTHONHASHSEED values and on repeated runs in one process; and the committed generated/
is what `derive generate --all` writes under any of them (one generation of the whole
catalog per seed serves both)."""

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import sympy

from derive import catalog
from derive.generation import render_filter

ROOT = Path(__file__).resolve().parents[2]

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
from derive import cli
from derive.generation import generate
assert cli.main(["generate", "--all", "--out", "generated"]) == 0
generate("mpt3d_a", ["kf", "lf", "jklf"], "all", "gen_options",
         {"missing": True, "joseph": True, "P0_pattern": "dense"})
generate("freeplane.toml", ["kf", "lf", "jklf", "ikf"], "all", "gen_file", {"missing": True})
"""

SEEDS = ("0", "4294967295")


def tree(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def seeded_trees(tmp_path_factory) -> dict[str, dict[str, str]]:
    """The SHA-256 of every file SCRIPT writes, per hash seed (the seeds' runs in parallel)."""
    runs = {}
    for seed in SEEDS:
        work = tmp_path_factory.mktemp(f"seed{seed}")
        (work / "freeplane.toml").write_text(MODEL_FILE)
        env = {**os.environ, "PYTHONHASHSEED": seed,
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT),
                                                           os.environ.get("PYTHONPATH")]))}
        env.pop("DERIVE_PROGRESS", None)
        runs[seed] = (work, subprocess.Popen([sys.executable, "-c", SCRIPT], cwd=work,
                                             env=env, stdout=subprocess.DEVNULL,
                                             stderr=subprocess.PIPE, text=True,
                                             stdin=subprocess.DEVNULL))
    trees = {}
    for seed, (work, proc) in runs.items():
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
        trees[seed] = tree(work)
    return trees


def test_generated_files_do_not_depend_on_the_hash_seed(seeded_trees):
    first = seeded_trees[SEEDS[0]]
    models = {name.split("/")[1] for name in first if name.startswith("generated/")}
    assert models == set(catalog.names())
    assert sum(name.startswith("gen_file/") for name in first) == 4 * 3
    for seed in SEEDS[1:]:
        assert sorted(seeded_trees[seed]) == sorted(first)
        differ = [name for name in first if seeded_trees[seed][name] != first[name]]
        assert not differ, f"PYTHONHASHSEED={seed} changes {differ[:5]}"


def test_committed_generated_tree_is_fresh(seeded_trees):
    """generated/ equals a fresh `derive generate --all` byte for byte."""
    fresh = {name[len("generated/"):]: digest
             for name, digest in seeded_trees[SEEDS[0]].items() if name.startswith("generated/")}
    committed = {name: digest for name, digest in tree(ROOT / "generated").items()
                 if name != "README.md"}
    assert sorted(committed) == sorted(fresh), "generated/ lists other files than --all writes"
    stale = [name for name in fresh if committed[name] != fresh[name]]
    assert not stale, f"generated/ is stale: {stale[:5]} (run `derive generate --all`)"


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
