"""The filter registry is built from one spec per filter, declared beside its derivation;
emit switches on the run-loop kind only, with one template per kind per language."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import derive.filters as filters
from derive import catalog
from derive.filters import FILTERS, MISSING_FILTERS, derive_unit
from derive.filters.spec import FilterSpec
from derive.flops import LANGUAGES
from derive.options import taken_by
from derive.runs import kinds
from derive.runs.unit import RUN_KINDS

ROOT = Path(__file__).resolve().parents[2]
GENERATED = ROOT / "generated"
EMIT = ROOT / "derive" / "emit"
#: Templates that are no run loop: the shared layout and the plain-functions files.
LAYOUT = {"base", "functions", "header", "run"}


def _family_modules():
    for info in pkgutil.iter_modules(filters.__path__):
        module = importlib.import_module(f"derive.filters.{info.name}")
        if hasattr(module, "SPECS"):
            yield module


def test_registry_is_the_union_of_the_family_specs():
    declared = [spec for module in _family_modules() for spec in module.SPECS]
    assert all(isinstance(spec, FilterSpec) for spec in declared)
    assert sorted(s.name for s in declared) == sorted(FILTERS)
    assert len({s.name for s in declared}) == len(declared), "a filter declared twice"
    for module in _family_modules():
        for spec in module.SPECS:
            assert spec.derive.__module__ == module.__name__, spec.name
            assert spec.run_kind in RUN_KINDS, spec.name


def test_one_title_per_filter():
    titles = [spec.title for spec in FILTERS.values()]
    assert len(set(titles)) == len(titles)


def test_missing_filters_are_those_whose_spec_says_so():
    assert MISSING_FILTERS == tuple(n for n, s in FILTERS.items() if s.missing)
    for name, spec in FILTERS.items():
        assert ("missing" in taken_by(name)) == spec.missing, name


def test_every_run_kind_has_its_builder_and_templates_only_the_frame():
    """Every kind's loop is built as data (derive.runs.kinds, one builder a kind) and
    printed into the frame ``run.jinja`` of each language: no template per kind."""
    assert set(kinds.BUILDERS) == set(RUN_KINDS)
    for lang in LANGUAGES:
        stems = {p.stem for p in (ROOT / "templates" / lang).glob("*.jinja")}
        assert "run" in stems and stems <= LAYOUT, lang


def test_no_filter_name_in_emit():
    words = "|".join(sorted(FILTERS, key=len, reverse=True))
    upper = "|".join(n.upper() for n in FILTERS)
    pattern = re.compile(rf"\b({words}|{upper})\b")
    hits = [f"{p.name}:{i}: {line.strip()}" for p in sorted(EMIT.glob("*.py"))
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert hits == []


@pytest.mark.parametrize("name", list(FILTERS))
def test_generated_files_state_the_one_title(name):
    """Line 1, the ``filter:`` line and the step's and run's descriptions name the filter
    by its spec's title (a variant spelling anywhere fails)."""
    title = FILTERS[name].title
    files = sorted(GENERATED.glob(f"*/{name}.py")) + sorted(GENERATED.glob(f"*/{name}.h"))
    assert files, name
    for path in files:
        text = path.read_text()
        first = next(line for line in text.splitlines() if line.strip('"/* ')).strip('"/* ')
        assert first == f"{title[:1].upper()}{title[1:]} for the model {path.parent.name}."
        assert f"filter: {name} ({title})" in text
        for phrase in re.findall(r"(?:one step of the|Run the) ([\w -]*?filter)\b", text,
                                 flags=re.IGNORECASE):
            assert phrase == title, (path, phrase)


def test_unit_carries_run_kind_carried_state_and_run_tracks():
    model = catalog.load("mpt3d_b")
    for name, missing in (("kf", True), ("sskf", False)):
        unit = derive_unit(model, name)
        spec = FILTERS[name]
        assert unit.kind == spec.run_kind and unit.title == spec.title
        assert unit.carried == RUN_KINDS[spec.run_kind].carried
        assert unit.run_tracks == spec.run_tracks
        assert spec.missing == missing
    assert not derive_unit(model, "kf", {"run_tracks": False}).run_tracks
