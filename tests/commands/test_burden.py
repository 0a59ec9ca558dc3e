"""`derive burden`: exact counts by kind, per filter, program and language."""

import json

import pytest

from derive import catalog
from derive.apps import formulas, paper
from derive.cli import main
from derive.commands.burden import KINDS
from derive.filters import derive_unit
from derive.flops import count


def _json(capsys, *argv):
    assert main(["burden", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_burden_rows_are_the_counts_of_the_programs(capsys):
    data = _json(capsys, "mpt3d_a", "--filter", "kf", "--filter", "pred")
    assert (data["model"], data["n"], data["m"]) == ("mpt3d_a", 6, 3)
    model = catalog.load("mpt3d_a")
    seen = set()
    for row in data["rows"]:
        program = derive_unit(model, row["filter"], {}).programs[row["program"]]
        n = count(program, row["lang"])
        assert {k: row[k] for k in KINDS} == n.as_dict()
        assert (row["flops"], row["instructions"]) == (n.flops, n.instructions)
        seen.add((row["filter"], row["program"], row["lang"]))
    assert seen == {(f, p, lang) for f, p in (("kf", "step"), ("pred", "step"), ("pred", "init"))
                    for lang in ("python", "c")}
    kf = [r for r in data["rows"] if r["filter"] == "kf"]
    assert {r["papers"] for r in kf} == {formulas.kf(6, 3)}
    assert [r["papers"] for r in data["rows"] if r["program"] == "init"] == [None, None]


@pytest.mark.parametrize("model", ["cv", "gsm2d_a", "gps_static"])
def test_python_and_c_count_the_same_flops(capsys, model):
    rows = _json(capsys, model)["rows"]
    by_key: dict = {}
    for r in rows:
        by_key.setdefault((r["filter"], r["program"]), {})[r["lang"]] = r
    for key, langs in by_key.items():
        py, c = langs["python"], langs["c"]
        assert py["fma"] == 0 and py["flops"] == c["flops"], key
        # fusing touches only + - *: divisions, roots and checks are the same in both
        assert [py[k] for k in ("div", "sqrt", "cmp")] == [c[k] for k in ("div", "sqrt", "cmp")]


def test_paper_rows_count_the_formulas(capsys):
    data = _json(capsys, "gsm2d_a", "--paper", "--filter", "kf", "--filter", "lf",
                 "--filter", "fir", "--order", "3")
    papers = {(r["filter"], r["lang"]): r for r in data["rows"] if r["mode"] == "paper"}
    assert papers[("kf", "python")]["flops"] == formulas.kf(4, 2) == 509
    assert papers[("lf", "c")]["flops"] == formulas.lf(4, 2) == 670
    assert papers[("fir", "python")]["flops"] == formulas.fir(3, 4, 2)
    assert all(r["papers"] == formulas.fir(3, 4, 2) for r in data["rows"] if r["filter"] == "fir")
    assert count(paper.step_program("fir", 4, 2, 3)).flops == formulas.fir(3, 4, 2)


def test_burden_text_states_the_conventions(capsys):
    assert main(["burden", "cv", "--filter", "sskf"]) == 0
    out = capsys.readouterr().out
    assert "an fma: 2 flops, 1 instruction" in out
    assert "neg, cmp, select and calls are not flops" in out
    head = next(ln for ln in out.splitlines() if ln.startswith("filter")).split()
    line = next(ln for ln in out.splitlines() if ln.startswith("sskf") and "python" in ln)
    row = dict(zip(head, line.split()))
    # the step's comparison (z present) is an instruction, not a flop
    assert row["flops"] == row["papers"] == str(formulas.sskf(2, 1))
    step = count(derive_unit(catalog.load("cv"), "sskf", {}).programs["step"], "python")
    assert step.cmp > 0 and row["cmp"] == str(step.cmp)
    assert int(row["instr"]) == int(row["flops"]) + step.cmp


def test_nonlinear_filters_have_no_formula(capsys):
    rows = _json(capsys, "gnss_pseudorange", "--filter", "ekf")["rows"]
    assert {r["program"] for r in rows} >= {"step"} and all(r["papers"] is None for r in rows)
    assert all(r["sqrt"] > 0 for r in rows if r["program"] == "step")


def test_burden_rejects_an_unknown_filter(capsys):
    assert main(["burden", "cv", "--filter", "kff"]) == 2
    assert "unknown filter 'kff'" in capsys.readouterr().err


def test_chains_are_the_run_loops_carried_bound(capsys):
    """The chain section: each filter's C run loop (the two-step pass for a steady-state
    filter) through derive.apps.latency, in the reference cycles."""
    from derive.apps.latency import REFERENCE_CYCLES, carried_bound
    from derive.lowering import lower_program
    from derive.runs.kinds import carried_pass

    data = _json(capsys, "mpt3d_b", "--filter", "kf", "--filter", "sskf", "--filter", "fir")
    assert data["chain_unit"] == "cycles"
    chains = {c["filter"]: c for c in data["chains"]}
    model = catalog.load("mpt3d_b")
    for name in ("kf", "sskf"):
        program, steps = carried_pass(derive_unit(model, name, {}))
        bound = carried_bound(lower_program(program, use_fma=True), REFERENCE_CYCLES)
        assert chains[name]["per_step"] == bound.per_step / steps
        assert chains[name]["operations_per_pass"] == dict(bound.operations)
    assert chains["sskf"]["steps_per_pass"] == 2 and chains["kf"]["steps_per_pass"] == 1
    assert chains["fir"]["per_step"] is None
    assert main(["burden", "mpt3d_b", "--filter", "kf"]) == 0
    out = capsys.readouterr().out
    assert "carried chain of the C run loop" in out and "1 div" in out
