"""Which filters take an option follows their specs (issue 12, "The house"): a filter
takes the options of its spec's options class, a shared one only with the spec flag it
needs (covariance: P0_pattern, missing: missing, batch: run_tracks). derive/options.py
names no filter, so adding a family (with its options class in its own module) touches
nothing there."""

from __future__ import annotations

import ast
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from derive import options
from derive.errors import OptionError
from derive.filters import FILTERS
from derive.options import SharedOptions, option, per_filter, taken_by, takers, validate

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True, kw_only=True)
class ToyOptions(SharedOptions):
    """A family's own options, declared outside derive/options.py."""

    gain: float = option(1.0, flag="--toy-gain", kind=float, low=0.0, help="a toy gain")


@pytest.fixture
def toy_registered():
    """The registry plus a family 'toy': covariance and missing, no batch function."""
    toy = replace(FILTERS["kf"], name="toy", options=ToyOptions, covariance=True,
                  missing=True, run_tracks=False, sensors=False, start=False, loglik=None)
    options.use_filters({**FILTERS, "toy": toy})
    yield toy
    options.use_filters(FILTERS)


def test_options_py_names_no_filter():
    """No string literal in derive/options.py is a filter's name."""
    tree = ast.parse((ROOT / "derive" / "options.py").read_text(encoding="utf-8"))
    literals = {node.value for node in ast.walk(tree)
                if isinstance(node, ast.Constant) and isinstance(node.value, str)}
    assert sorted(literals & set(FILTERS)) == []


def test_the_takers_follow_the_flags_of_the_specs():
    for name, spec in FILTERS.items():
        taken = taken_by(name)
        assert ("P0_pattern" in taken) == spec.covariance, name
        assert ("missing" in taken) == spec.missing, name
        assert ("loglik" in taken) == (spec.loglik is not None), name
        assert ("run_tracks" in taken) == spec.run_tracks, name
        assert ("gate" in taken) == spec.sensors, name
        assert ("start" in taken) == spec.start, name
        own = [k for k in spec.options.specs() if k not in SharedOptions.specs()]
        assert [k for k in taken if k not in SharedOptions.specs()] == own, name


def test_a_new_family_takes_its_options_without_touching_options_py(toy_registered):
    assert taken_by("toy") == ["P0_pattern", "missing", "prefix", "precision", "run", "gain"]
    assert "toy" in takers("P0_pattern") and "toy" in takers("missing")
    assert "toy" not in takers("run_tracks") and takers("gain") == ["toy"]
    typed = validate("toy", {"missing": True, "gain": 2})
    assert isinstance(typed, ToyOptions) and typed.gain == 2.0 and typed.missing
    assert "gain" in options.all_specs()
    with pytest.raises(OptionError, match="option 'run_tracks' is taken by kf, .*not by toy"):
        validate("toy", {"run_tracks": False})
    with pytest.raises(OptionError, match=r"option 'gain' \(--toy-gain\) must be a finite "
                                          r"number >= 0"):
        validate("toy", {"gain": -1.0})
    both = per_filter(["kf", "toy"], {"missing": True, "gain": 3.0})
    assert both["kf"].missing and both["toy"].gain == 3.0


def test_an_option_of_a_family_is_checked_without_the_registry():
    """Building an options object checks its fields against its own class."""
    with pytest.raises(OptionError, match="gain"):
        ToyOptions(gain=-2.0)
