"""The option ``latency_schedule`` where issuing the step's arithmetic limits the run loop
(derive.schedule.issue_limited): the default step is kept, bitwise, the header says why,
and the search is not run (a 32-state Joseph-form KF spent most of 52 s there, for a
chain its arithmetic hides many times over). Where the chain or the divider can limit the
loop (every catalog KF, k independent axes) the schedule applies as before."""

from __future__ import annotations

from _band_models import band_file, band_model, hang_guard

from derive import LinearModel, catalog
from derive import schedule as schedule_module
from derive.apps.latency import run_loop_bound
from derive.cli import main
from derive.filters import available, derive_unit
from derive.flops import count
from derive.schedule import REFERENCE_DIVIDER, WIDEST_ISSUE, issue_limited, one_step_chain

JOSEPH = {"joseph": True, "missing": True}
HANG_GUARD = 120    # seconds; about 4 on this repository's machines


def test_an_issue_limited_step_keeps_its_default_and_the_search_is_not_run(monkeypatch):
    model = band_model(12)
    plain = derive_unit(model, "kf", JOSEPH)

    def searched(*args, **kwargs):
        raise AssertionError("the latency schedule's search ran")
    monkeypatch.setattr(schedule_module, "latency_schedule", searched)
    kept = derive_unit(model, "kf", {**JOSEPH, "latency_schedule": True})
    step, default = kept.programs["step"], plain.programs["step"].optimize()
    assert list(map(str, step.body)) == list(map(str, default.body))
    assert step.results == default.results
    (fact,) = [f for f in kept.facts if f.startswith("latency schedule: not applied: ")]
    assert set(plain.facts) == set(kept.facts) - {fact}
    # the figures it gives, from the header's own count and the search's own chain
    flops = count(default, "c").flops
    divisions = count(default, "c")
    divider = REFERENCE_DIVIDER["div"] * divisions.div + REFERENCE_DIVIDER["sqrt"] * divisions.sqrt
    chain = one_step_chain(default)
    assert flops / 2 / WIDEST_ISSUE >= max(chain, divider)
    assert f"the step's {flops} flops are at least {flops / 2:g} arithmetic instructions" in fact
    assert f"carried chain ({chain:g} reference cycles)" in fact
    assert f"its divider's {divider:g} cycles" in fact


def test_the_option_still_schedules_where_the_chain_or_the_divider_limits():
    """mpt3d_a (the chain) and 24 independent axes (the divider: two divisions an axis,
    which the schedule makes one) are scheduled as before: a shorter chain, flops added."""
    axis = catalog.load("mpt3d_b")
    for model in (catalog.load("mpt3d_a"),
                  LinearModel.compose("cv24", [axis] * 24, [f"_{i}" for i in range(24)])):
        plain = derive_unit(model, "kf", {})
        assert issue_limited(plain.programs["step"], plain.carried) is None
        scheduled = derive_unit(model, "kf", {"latency_schedule": True})
        assert not [f for f in scheduled.facts if f.startswith("latency schedule")]
        assert count(scheduled.programs["step"], "c").flops > \
            count(plain.programs["step"], "c").flops
        assert run_loop_bound(scheduled).per_step < run_loop_bound(plain).per_step


def test_no_catalog_kf_is_issue_limited():
    linear = [catalog.load(name) for name in catalog.names()]
    linear = [model for model in linear if "kf" in available(model)]
    assert len(linear) >= 7
    for model in linear:
        for options in ({}, JOSEPH):
            unit = derive_unit(model, "kf", options)
            assert issue_limited(unit.programs["step"], unit.carried) is None, model.name


def test_the_written_header_says_why(tmp_path):
    from derive.generation import generate
    paths = generate(band_model(12), ["kf"], "c", tmp_path, {**JOSEPH, "latency_schedule": True})
    header = next(p for p in paths if p.suffix == ".h").read_text()
    assert "latency schedule: not applied: the step's " in " ".join(header.split())


def test_a_32_state_joseph_file_with_the_schedule_generates_within_a_hang_guard(tmp_path,
                                                                                 capsys):
    """The red team's case: a 32-state model file (F banded, P filling) with
    --latency-schedule --joseph --missing took 52 s and 300 MB; the search it spent them
    on cannot shorten that loop. The guard only catches a hang."""
    (tmp_path / "band32.toml").write_text(band_file(32))
    assert len(band_file(32)) < 64 * 1024
    with hang_guard(HANG_GUARD):
        status = main(["generate", str(tmp_path / "band32.toml"), "--filter", "kf",
                       "--latency-schedule", "--joseph", "--missing", "--lang", "c",
                       "--out", str(tmp_path / "out")])
    assert status == 0, capsys.readouterr().err
    header = " ".join((tmp_path / "out" / "band32" / "kf.h").read_text().split())
    assert "latency schedule: not applied: the step's " in header
