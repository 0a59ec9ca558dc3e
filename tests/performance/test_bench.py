"""`derive bench` with tiny counts: the table has every case and implementation, the
peers compute the same filter as derive, skips are reported, JSON is valid. No
wall-clock assertions."""

from __future__ import annotations

import ast
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from derive import cli, commands
from derive.apps.bench import bars as bar_table
from derive.apps.bench import timing
from derive.apps.bench.bars import BARS, REFERENCE
from derive.apps.bench.cases import CASES, Case, Skip, make_data, states
from derive.apps.bench.costs import startup
from derive.apps.bench.machine import probe
from derive.apps.bench.machine.bound import case_bound
from derive.apps.bench.run import (
    IMPLEMENTATIONS,
    LATENCY_SCHEDULE,
    Bar,
    BenchResult,
    Row,
    Settings,
    run_bench,
    time_catalog_generation,
)
from derive.apps.bench.throughput import batch
from derive.options import taken_by

TINY = Settings(c_steps=200, python_steps=20, nonlinear_python_steps=10, repeats=1,
                check_steps=20, batch_tracks=22, batch_steps=8, batch_repeats=1,
                scale_tracks=0, catalog_generation=False, generation_scaling=False,
                compile_states=(2,), startup_repeats=1,
                # the SymForce peer: tests/navigation/test_nav_symforce_peer.py
                navigation_peer_calls=0,
                # the schedule rows of 12 to 120 axes and of the dense KFs (58 of the 93 s
                # of CPU the run took with the defaults): tests/program/test_schedule_*.py
                schedule_axes=(3,), schedule_dense=())
"""The bench with tiny counts: every case, implementation, bar and table, each part at its
smallest size (the parts' large sizes are checked in their own files)."""
STARTUP_CALLS = startup.CALLS[:1]
"""The start-up calls the bench run times: ``derive --help`` (beside the floor and one
command's help). Every call's row and exit status: tests/compiled/test_startup.py."""


class _FirstCommand:
    """derive.commands with its first command only, for the bench run's start-up rows."""

    @staticmethod
    def modules():
        return commands.modules()[:1]
AGREE = 1e-9   # every implementation runs the same filter from the same start


@pytest.fixture(scope="module")
def result():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(startup, "CALLS", STARTUP_CALLS)
        patch.setattr(startup, "commands", _FirstCommand)
        return run_bench(TINY)


def test_one_row_per_case_and_implementation(result):
    expected = []
    for c in CASES:
        for name, _, _ in IMPLEMENTATIONS:
            expected.append((c.label, name))
            if name == "generated C" and "latency_schedule" in taken_by(c.filter):
                expected.append((c.label, LATENCY_SCHEDULE))   # the KF cases
    assert [(r.case, r.implementation) for r in result.rows] == expected
    assert [b.implementation for b in result.batch] == [
        "generated C, run_tracks", "generated C, run_tracks, covariances stored",
        f"generated C, step, {batch.INTERLEAVE} tracks interleaved",
        "generated C, run per track", "generated Python (NumPy arrays)",
        "vectorised NumPy KF", "simdkalman"]


def test_measured_rows_agree_with_the_reference_and_have_ratios(result):
    for r in result.rows:
        if r.timing is None:
            assert r.note.startswith("skipped: ") and r.ratio is None
            continue
        assert r.agreement <= AGREE, (r.case, r.implementation, r.agreement)
        assert r.timing.low <= r.timing.median <= r.timing.high
        assert r.ratio == pytest.approx(
            r.timing.median / result.row(r.case, "generated C").timing.median)
    for b in result.batch:
        assert b.agreement is None or b.agreement <= AGREE, b


def test_generated_and_numpy_rows_always_run(result):
    for case in CASES:
        for name in ("generated C", "generated Python", "NumPy reference"):
            assert result.row(case.label, name).timing is not None, (case.label, name)


def test_peers_without_the_filter_are_skipped_with_a_reason(result):
    assert "FilterPy has no steady-state filter" in result.row("SSKF mpt3d_a", "FilterPy").note
    assert "only the linear" in result.row("EKF gnss_pseudorange", "pykalman").note


def test_missing_peer_is_skipped_not_faked(monkeypatch, tmp_path):
    from derive.apps.bench.peers import libraries as peers

    monkeypatch.setitem(sys.modules, "pykalman", None)   # import raises ImportError
    data = make_data(Case("kf", "mpt3d_b"), 10)
    with pytest.raises(Skip, match="pykalman is not installed"):
        peers.pykalman(Case("kf", "mpt3d_b"), data, tmp_path)


def test_text_and_json(result):
    text = result.text()
    assert "median of 1 repeats" in text and "-O3 -march=native" in text
    for case in CASES:
        assert case.label in text
    navigation = len(result.navigation.bars(Bar))  # the ins_gnss rows (bench/navigation.py)
    compile_bars = 3 * len(result.compile)   # generation, compilation, .c size
    assert text.count("bar: ") == 12 + navigation + compile_bars
    assert text.count("bar: scaled: ") == 3
    data = json.loads(json.dumps(result.as_json()))
    assert len(data["rows"]) == len(result.rows)
    assert len(data["bars"]) == 12 + navigation   # the compile bars are in the text only
    assert "two dependent fmas here take" in text
    assert "start-up of the command line" in text and "derive --help" in text
    assert len(data["startup"]) == len(result.startup) > 0


def test_generated_c_rows_carry_the_latency_bound_of_their_chain(result):
    latency = result.machine["latency"]
    assert set(latency) == set(probe.PROBES) and all(v > 0 for v in latency.values())
    for case in CASES:
        row = result.row(case.label, "generated C")
        found = case_bound(case, latency)
        assert row.bound == found[0] and found[1] in row.note
    # three axes in turn: three times one axis's chain
    assert result.row("KF mpt3d_b x 3", "generated C").bound == pytest.approx(
        3 * result.row("KF mpt3d_a", "generated C").bound)


def test_bars_compare_ratios_upwards_and_times_downwards():
    assert Bar("r", 5.0, 4.0, "ratio").met and not Bar("r", 3.0, 4.0, "ratio").met
    assert Bar("t", 9e-9, 10e-9, "time").met and not Bar("t", 11e-9, 10e-9, "time").met
    assert Bar("t", None, 10e-9, "time").met is None
    assert Bar("t", 11e-9, 10e-9, "time", "why").text() == "bar: t: 11 ns (<= 10 ns: NOT met); why"


def test_scaled_bars_use_the_reference_points_measured_in_the_run(result):
    scaled = {b.claim.split(",")[0]: b for b in result.bars() if b.claim.startswith("scaled:")}
    casadi = result.row("KF mpt3d_a", "CasADi C").timing.median
    kf = scaled["scaled: generated C KF mpt3d_a per step"]
    assert kf.bar == pytest.approx(BARS["kf_c_step"] * casadi / REFERENCE["casadi_kf_step"])
    assert kf.value == result.row("KF mpt3d_a", "generated C").timing.median
    sskf = scaled["scaled: generated C SSKF mpt3d_a per step"]
    assert sskf.bar == pytest.approx(BARS["sskf_over_two_fmas"] * 2
                                     * result.machine["latency"]["fma"])
    filterpy = result.row("KF mpt3d_a", "FilterPy").timing.median
    py = scaled["scaled: generated pure-Python KF mpt3d_b x 3 per step"]
    assert py.bar == pytest.approx(BARS["kf_python_step_scaled"] * filterpy
                                   / REFERENCE["filterpy_kf_step"])


def _numbers(expression: ast.AST) -> list[float]:
    """The numbers written in an expression, but 0 (a default, never a bar)."""
    return [n.value for n in ast.walk(expression) if isinstance(n, ast.Constant)
            and type(n.value) in (int, float) and n.value != 0]


def test_the_bars_are_one_table():
    """Every number the bench holds a measurement to is an entry of derive.apps.bench.bars:
    no module of the bench binds a name of a bar to a number or passes one as a bar."""
    bench = Path(bar_table.__file__).parent
    found = []
    for path in sorted(bench.rglob("*.py")):
        if path == Path(bar_table.__file__):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id.endswith(("_BAR", "_BARS"))
                    for t in node.targets):
                found += [(path.name, node.lineno, n) for n in _numbers(node.value)]
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") in (
                    "Bar", "bar_type") and len(node.args) > 2:
                found += [(path.name, node.lineno, n) for n in _numbers(node.args[2])]
    assert not found, f"bars written outside derive/apps/bench/bars.py: {found}"
    assert all(isinstance(v, float) and v > 0 for v in BARS.values())


def test_catalog_generation_is_timed_when_asked(tmp_path):
    seconds = time_catalog_generation(tmp_path / "out")
    assert seconds > 0 and (tmp_path / "out" / "mpt3d_a" / "kf.c").is_file()
    r = BenchResult(Settings(catalog_generation=True), {"latency": {}}, [], [], seconds)
    assert r.bars()[-1].claim.startswith("generating the whole catalog")
    assert r.bars()[-1].value == seconds


def test_timing_median_and_range(monkeypatch):
    clock = iter([0.0, 1.0, 1.0, 4.0, 4.0, 6.0, 6.0, 7.0])   # runs of 3, 2, 1 s
    monkeypatch.setattr(timing.time, "perf_counter", lambda: next(clock))
    t = timing.measure(lambda: None, steps=10, repeats=3)
    assert (t.median, t.low, t.high) == (0.2, 0.1, 0.3)
    assert timing.human(2.5e-8) == "25 ns" and timing.human(3.2e-5) == "32 µs"


def test_vectorised_numpy_kf_equals_the_reference():
    b = batch.make_batch(tracks=4, steps=12)
    out = batch.numpy_kf(b)
    for t in range(4):
        np.testing.assert_allclose(out[t], batch.batch_reference(b, t), rtol=0, atol=1e-12)


def test_states_joins_copies():
    a, b = np.ones((5, 2)), np.zeros((5, 2))
    assert states([a, b], 3).shape == (3, 4)
    assert states(a, 5).shape == (5, 2)


def test_bench_command_prints_the_table(result, monkeypatch, capsys):
    """The command runs the bench with --quick's settings and prints its JSON; the bench
    itself is the one the fixture ran (a second run of it would double the file's time)."""
    asked = []
    monkeypatch.setattr("derive.apps.bench.run.Settings.quick", classmethod(lambda cls: TINY))
    monkeypatch.setattr("derive.apps.bench.run.run_bench",
                        lambda settings, progress=None: asked.append(settings) or result)
    assert cli.main(["bench", "--quick", "--json"]) == 0
    assert asked == [TINY]
    data = json.loads(capsys.readouterr().out)
    assert {r["case"] for r in data["rows"]} == {c.label for c in CASES}
    assert cli.main(["bench", "--repeats", "0"]) == 2


def test_the_larger_bound_applies_and_both_are_printed():
    """A run streaming more bytes than the cache holds is bound by the memory, whatever its
    chain: the chain bars compare with the larger bound and name it."""
    timing_ = timing.Timing(3e-9, 2.9e-9, 3.1e-9, 100, 3)
    chain = Row("SSKF mpt3d_a", "generated C", timing_, 1.0, 0.0, bound=1e-9, memory=2.5e-9)
    assert chain.limit == (2.5e-9, "memory traffic")
    assert Row("KF mpt3d_a", "generated C", timing_, 1.0, 0.0, bound=8e-9,
               memory=1e-9).limit == (8e-9, "chain")
    assert Row("x", "generated C", timing_, 1.0, 0.0, bound=8e-9).limit == (8e-9, "chain")
    kf = Row("KF mpt3d_a", "generated C", timing_, 1.0, 0.0, bound=2e-9, memory=1e-9)
    bars = BenchResult(TINY, {"latency": {}}, [kf, chain])._chain_bars()
    assert [b.bar for b in bars[:2]] == [pytest.approx(BARS["kf_over_bound"] * 2e-9),
                                         pytest.approx(BARS["sskf_over_bound"] * 2.5e-9)]
    assert bars[1].value == timing_.low   # the fastest repeat, as the probes are least times
    assert "chain bound 1 ns, memory-traffic bound 2.5 ns: the memory traffic applies" in \
        bars[1].note and bars[1].met


def test_generated_c_rows_carry_the_memory_traffic_of_their_run(result):
    for case in CASES:
        row = result.row(case.label, "generated C")
        assert row.memory > 0 and "memory-traffic bound" in row.note


def test_only_catalog_runs_the_cases_and_the_batch_alone(monkeypatch):
    import derive.apps.bench.run as bench_run

    ran = []
    monkeypatch.setattr(bench_run, "_case_rows", lambda case, *a: ran.append(case) or [])
    monkeypatch.setattr(bench_run, "_batch_rows", lambda *a: ran.append("batch") or [])
    monkeypatch.setattr(bench_run, "machine_info", lambda: {"latency": {}})
    for section in ("_navigation", "time_catalog_generation"):
        monkeypatch.setattr(bench_run, section, lambda *a, s=section: pytest.fail(s))
    r = run_bench(replace(Settings(), only="catalog", scale_tracks=0))
    assert ran == [*CASES, "batch"] and r.navigation is None and not r.generation
    assert not r.compile and not r.startup and not r.schedule and r.generation_seconds is None


def test_turns_time_each_run_in_every_repeat(monkeypatch):
    clock = iter([0.0, 1.0, 1.0, 3.0, 3.0, 4.0, 4.0, 7.0])   # a 1 s, b 2 s, a 1 s, b 3 s
    monkeypatch.setattr(timing.time, "perf_counter", lambda: next(clock))
    order = []
    a, b = timing.measure_turns([lambda: order.append("a"), lambda: order.append("b")], 10, 2)
    assert order == ["a", "b"] * 3   # a warm-up each, then in turns
    assert (a.low, a.high, b.low, b.high) == (0.1, 0.1, 0.2, 0.3)
