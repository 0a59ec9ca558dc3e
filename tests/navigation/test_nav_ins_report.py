"""The report's INS/GNSS section (derive.apps.report.navigation) on the generated EKF:
its figures (errors with 3σ, NIS with the chi-square band, biases), its tables, and its
outcomes — the whole-flight agreement and the 3σ bar — matched."""

from __future__ import annotations

import pytest

from derive.apps.report import navigation
from derive.apps.report.context import Context
from derive.apps.report.document import MATCHED, Figure, Table
from derive.pipeline import load_generated


@pytest.fixture(scope="module")
def section(tmp_path_factory):
    pytest.importorskip("matplotlib")
    root = tmp_path_factory.mktemp("report")
    ctx = Context(root / "out", root / "generated", root / "scratch")
    generated = load_generated("ins_gnss", "ekf", {}, "all", root / "generated")
    ctx.c[("ins_gnss", "ekf")] = generated.c
    ctx.python[("ins_gnss", "ekf")] = generated.python
    return ctx, navigation.section(ctx)


def test_figures_are_written(section):
    ctx, s = section
    names = [f.path for f in s.blocks if isinstance(f, Figure)]
    assert names == ["figures/ins_errors.png", "figures/ins_nis.png", "figures/ins_biases.png"]
    for name in names:
        data = (ctx.out / name).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > 5000


def test_outcomes_are_matched_with_measured_evidence(section):
    _, s = section
    assert [o.verdict for o in s.outcomes] == [MATCHED, MATCHED]
    agreement, inside = s.outcomes
    assert "largest relative difference" in agreement.evidence
    assert "of 600 epochs" in inside.evidence


def test_tables(section):
    _, s = section
    captions = [t.caption for t in s.blocks if isinstance(t, Table)]
    assert captions[0].startswith("Whole-flight agreement with the hand-written NumPy EKF")
    assert captions[1:] == ["NIS per sensor", "The generated EKF against the truth"]
    nis = next(t for t in s.blocks if isinstance(t, Table) and t.caption == "NIS per sensor")
    assert [row[:3] for row in nis.rows] == [("gnss", "6", "600"), ("baro", "1", "2400")]
