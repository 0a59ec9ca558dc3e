"""Fewer collector runs while derive derives and renders (derive.collection): the raised
thresholds hold inside a derivation and a rendering, and the caller's own settings are
back afterwards, whatever happened inside and however the uses nest."""

from __future__ import annotations

import gc

import pytest

from derive import catalog
from derive.collection import MIDDLE, OLDEST, YOUNG, few_collections
from derive.emit import render
from derive.errors import ModelError
from derive.filters import derive_unit
from derive.program import Program


@pytest.fixture
def own_thresholds():
    before = gc.get_threshold()
    gc.set_threshold(1234, 5, 6)
    yield (1234, 5, 6)
    gc.set_threshold(*before)


def test_nested_uses_share_one_setting_and_the_outermost_restores(own_thresholds):
    with few_collections():
        assert gc.get_threshold() == (YOUNG, MIDDLE, OLDEST)
        with few_collections():
            assert gc.get_threshold() == (YOUNG, MIDDLE, OLDEST)
        assert gc.get_threshold() == (YOUNG, MIDDLE, OLDEST)
    assert gc.get_threshold() == own_thresholds
    with pytest.raises(ModelError), few_collections():
        raise ModelError("inside")
    assert gc.get_threshold() == own_thresholds


def test_derivation_and_rendering_run_with_the_raised_thresholds(own_thresholds, monkeypatch):
    seen = []
    optimize, lowered = Program.optimize, render._lowered

    def optimizing(self):
        seen.append(("derive", gc.get_threshold()))
        return optimize(self)

    def lowering(*args, **kwargs):
        seen.append(("render", gc.get_threshold()))
        return lowered(*args, **kwargs)
    monkeypatch.setattr(Program, "optimize", optimizing)
    monkeypatch.setattr(render, "_lowered", lowering)
    unit = derive_unit(catalog.load("mpt3d_b"), "kf", {})
    assert gc.get_threshold() == own_thresholds
    render.render_python(unit)
    render.render_c(unit)
    assert {stage for stage, _ in seen} == {"derive", "render"}
    assert {thresholds for _, thresholds in seen} == {(YOUNG, MIDDLE, OLDEST)}
    assert gc.get_threshold() == own_thresholds
