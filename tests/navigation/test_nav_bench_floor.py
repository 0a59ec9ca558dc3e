"""What decides the per-call bars of the navigation rows (derive.apps.bench.peers.navigation):
the scalar throughput kernels compute the chains they claim to run
(derive.apps.bench.machine.scalar_throughput), the floor of a count is its slowest pipe's
bound, and a bar whose need is below that floor says so. No wall-clock assertions: the
timings below are made up, only the arithmetic on them is checked."""

from __future__ import annotations

import math
from dataclasses import fields
from fractions import Fraction

import pytest

from derive.apps.bench import generated
from derive.apps.bench.machine import scalar_throughput as throughput
from derive.apps.bench.machine.scalar_throughput import CHAINS, Throughput
from derive.apps.bench.peers.navigation import PEER_BARS, TIMED, CountRow, NavigationResult, TimeRow
from derive.apps.bench.run import Bar
from derive.apps.bench.timing import Timing
from derive.trees import OpCount


def _fma(a: float, b: float, c: float) -> float:
    """a * b + c rounded once (Fraction is exact; float() rounds to nearest even)."""
    return float(Fraction(a) * Fraction(b) + Fraction(c))


@pytest.mark.parametrize("kind", sorted(CHAINS))
def test_throughput_kernel_runs_its_chains(kind):
    pytest.importorskip("cffi")
    kernel = throughput.kernels(generated.CFLAGS)[kind]
    multiplies, adds = throughput.start_values(kind)
    assert (len(multiplies), len(adds)) == CHAINS[kind]
    iterations = 7
    for _ in range(iterations):
        multiplies = [_fma(a, throughput.B, throughput.C) for a in multiplies]
        adds = [s + throughput.C for s in adds]
    expected = 0.0
    for value in multiplies + adds:   # C sums left to right
        expected += value
    assert kernel(iterations, throughput.B, throughput.C) == expected


def _count() -> OpCount:
    return OpCount(add=3, sub=4, mul=5, div=1, sqrt=1, fma=6, neg=2, cmp=1)


@pytest.mark.parametrize("rates", [(2.0, 1.0, 0.25), (1.0, 3.0, 0.25), (1.0, 1.0, 0.9)])
def test_floor_is_the_slowest_pipe_bound(rates):
    t = Throughput(*(r * 1e-9 for r in rates))
    count = _count()
    bounds = [(count.mul + count.fma) * t.fma, (count.add + count.sub) * t.add,
              (count.mul + count.fma + count.add + count.sub) * t.mixed]
    assert t.floor_seconds(count) == max(bounds)
    # each parameter set makes a different bound the largest
    assert bounds.index(max(bounds)) == [(2.0, 1.0, 0.25), (1.0, 3.0, 0.25),
                                         (1.0, 1.0, 0.9)].index(rates)
    assert t.per_ns("fma") == pytest.approx(1.0 / rates[0], rel=1e-15)
    assert t.floor_text(count).startswith(f"{t.floor_seconds(count) * 1e9:.0f} ns (11 mul+fma")


def _timing(fastest: float) -> Timing:
    """A timing whose fastest repeat is ``fastest`` and whose median is a quarter slower
    (a loaded machine)."""
    return Timing(1.25 * fastest, fastest, 1.5 * fastest, 1, 3)


def _result(base: float, peers: dict[str, float], t: Throughput | None) -> NavigationResult:
    result = NavigationResult(throughput=t)
    for function in TIMED:
        result.counts.append(CountRow(function, _count(), None, None))
        result.times.append(TimeRow(function, "generated C", _timing(base), 1.0, None))
        for peer, fastest in peers.items():
            result.times.append(TimeRow(function, peer, _timing(fastest), fastest / base,
                                        None))
    return result


def test_bars_carry_the_need_and_the_floor():
    t = Throughput(1e-9, 1e-9, 0.5e-9)
    floor = t.floor_seconds(_count())
    # FilterPy's bar needs a time below the floor, CasADi's one above it; from the fastest
    # repeats: the medians, a quarter slower, would put FilterPy's need above the floor
    filterpy_ratio, casadi_ratio = dict(PEER_BARS)["FilterPy"], dict(PEER_BARS)["CasADi C"]
    peers = {"FilterPy": 0.9 * floor * filterpy_ratio, "CasADi C": 3.0 * floor * casadi_ratio}
    result = _result(5 * floor, peers, t)
    bars = {b.claim: b for b in result.bars(Bar)}
    for function in TIMED:
        assert result.floor_seconds(function) == floor
        below = bars[f"generated C ins_gnss {function} faster per call than FilterPy"]
        above = bars[f"generated C ins_gnss {function} faster per call than CasADi C"]
        assert result.needed_seconds(function, "FilterPy", filterpy_ratio) == pytest.approx(
            0.9 * floor, rel=1e-15)
        assert "out of reach of scalar code" in below.note
        assert "out of reach" not in above.note and "floor of scalar code" in above.note
    lines = result.decisive_lines()
    assert [line.split(":")[0] for line in lines] == list(TIMED)
    assert all(t.floor_text(_count()) in line for line in lines)
    assert result.as_json()["floors"] == {f: floor for f in TIMED}
    assert set(result.as_json()["throughput"]) == {f.name for f in fields(Throughput)}


def test_without_a_throughput_the_bars_have_no_floor():
    result = _result(1e-7, {"FilterPy": 1e-5, "CasADi C": 3e-7}, None)
    assert all(b.note == "" for b in result.bars(Bar) if "per call" in b.claim)
    assert all("floor of scalar code with its count here n/a" in line
               for line in result.decisive_lines())


def test_measured_throughput_is_per_operation():
    pytest.importorskip("cffi")
    t = throughput.measure_throughput(generated.CFLAGS, repeats=1, scale=0.01)
    assert all(math.isfinite(v) and v > 0 for v in (t.fma, t.add, t.mixed))
