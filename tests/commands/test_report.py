"""`derive reproduce --quick`: one reduced run of the whole job, then its files checked:
every figure and table the issue lists, HTML that parses and points at existing files,
no failed verification; plus the page renderer and the command's exit statuses."""

from __future__ import annotations

import html.parser
import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

from derive import catalog, cli
from derive.apps.report import page, provenance
from derive.apps.report.document import Figure, Section, Table, Text, Todo

FIGURES = ["mpt3d_fig1_estimates", "gsm2d_fig1_estimates", "gsm2d_fig2_fir_vs_sskf",
           "sspred_fig1_cv_estimation", "sspred_fig2_cv_prediction",
           "sspred_fig3_ca_estimation", "sspred_fig4_ca_prediction",
           "mdkf_fig4_6_estimates", "mdkf_fig7_errors", "gnss_estimates",
           "gnss_innovations", "ins_errors", "ins_nis", "ins_biases", "burden_bars"]
TABLES = ["Generated code against the NumPy reference", "Equivalence checks (max differences)",
          "MPT3D: equivalence of the implementations", "GSM2D: equivalence of the implementations",
          "GSM2D §7: FIR steady-state filter", "SSPRED Table 1",
          "Generated N-step predictors against F^N", "MDKF Table 1",
          "MDKF: the two algebraic forms agree", "Generated GNSS filters against the reference",
          "GNSS Tables 1–5, EKF", "GNSS Tables 1–5, UKF", "Burden audit",
          "The papers' speedups", "FIR steady-state filter: order N",
          "The papers' burden formulas beside the formulas derived",
          "Whole-flight agreement with the hand-written NumPy EKF", "NIS per sensor",
          "The generated EKF against the truth"]
REAL_DATA = importlib.util.find_spec("gnss_benchmark") is not None


_RUNS: dict[str, tuple] = {}   # the one quick run per process, shared by test_report*.py


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """Run `derive reproduce --quick` once per process (test_report_browser.py imports
    this fixture); (exit status, stdout, report directory)."""
    if "quick" not in _RUNS:
        out = tmp_path_factory.mktemp("report")
        import contextlib
        import io

        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            status = cli.main(["reproduce", "--quick", "--no-progress", "--out", str(out)])
        _RUNS["quick"] = (status, buffer.getvalue(), out)
    return _RUNS["quick"]


def md_table(text: str, caption: str) -> list[list[str]]:
    """The body rows of the Markdown table under the caption starting with ``caption``."""
    block = text[text.index(f"**{caption}"):]
    lines = [line for line in block.split("\n\n", 2)[1].splitlines() if line.startswith("|")]
    return [[c.strip() for c in line.strip("|").split(" | ")] for line in lines[2:]]


def test_reproduce_exits_0_with_a_one_screen_summary(report):
    status, stdout, out = report
    assert status == 0, stdout
    lines = stdout.strip().splitlines()
    assert len(lines) <= 24
    assert lines[0].startswith("derive reproduce: done in ")
    n_models = len(catalog.names())
    assert f"filters of {n_models} catalog models" in stdout
    assert re.search(r"verified  : \d+ runs .* max rel error \S+, 0 failed", stdout)
    assert "equivalence claims measured, 0 failed" in stdout
    assert str(out / "index.html") in stdout


def test_every_figure_is_a_png(report):
    out = report[2]
    names = FIGURES + (["gnss_real_errors"] if REAL_DATA else [])
    for name in names:
        data = (out / "figures" / f"{name}.png").read_bytes()
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 5000, name
    assert sorted(p.stem for p in (out / "figures").glob("*.png")) == sorted(names)


def test_every_table_is_in_index_md(report):
    text = (report[2] / "index.md").read_text(encoding="utf-8")
    for caption in TABLES + (["Real data: 3-D position error"] if REAL_DATA else []):
        assert f"**{caption}" in text, caption
        assert md_table(text, caption), caption
    assert "**FAIL**" not in text and "**DIFFERENT**" not in text
    for fig in FIGURES:
        assert f"(figures/{fig}.png)" in text


class _Html(html.parser.HTMLParser):
    VOID = {"img", "meta", "br"}

    def __init__(self):
        super().__init__()
        self.stack, self.images, self.tables, self.errors = [], [], 0, []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        if tag == "table":
            self.tables += 1
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.errors.append(tag)


def test_html_renders_the_same_report(report):
    out = report[2]
    parser = _Html()
    parser.feed((out / "index.html").read_text(encoding="utf-8"))
    parser.close()
    assert not parser.errors and not parser.stack
    md = (out / "index.md").read_text(encoding="utf-8")
    assert parser.tables == len(re.findall(r"\n\|(---|--:)", md))
    assert len(parser.images) == md.count("![")
    for src, path in zip(parser.images, re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)):
        assert (out / path).is_file(), path     # index.md: the figures folder beside it
        assert src.startswith("data:image/png;base64,")    # index.html: embedded


def test_sspred_metric_reproduces_the_papers_table(report):
    """With K = 10,000 steps our percent error matches SSPRED Table 1 (CV: to 5e-4)."""
    rows = md_table((report[2] / "index.md").read_text(encoding="utf-8"), "SSPRED Table 1")
    assert len(rows) == 6
    cv_ours = [float(r[1]) for r in rows]
    cv_paper = [float(r[3]) for r in rows]
    ca_ours = [float(r[4]) for r in rows]
    assert np.max(np.abs(np.subtract(cv_ours, cv_paper))) < 5e-4
    assert all(a < b for a, b in zip(cv_ours[1:], cv_ours[2:]))   # grows with N
    assert all(a < b for a, b in zip(ca_ours[1:], ca_ours[2:]))


def test_gnss_rmse_shrinks_and_mdkf_forms_agree(report):
    text = (report[2] / "index.md").read_text(encoding="utf-8")
    for label in ("EKF", "UKF"):
        rows = md_table(text, f"GNSS Tables 1–5, {label}")
        first, last = (np.mean([float(v) for v in r[1:4]]) for r in (rows[0], rows[-1]))
        assert last < first
    for row in md_table(text, "MDKF: the two algebraic forms agree"):
        assert float(row[1]) < 1e-12 and float(row[2]) < 1e-12


def test_sspred_percent_error_definition():
    from derive.apps.report.sspred import percent_error

    truth = np.array([[3.0, 4.0], [6.0, 8.0]])           # |p| = 5, 10
    est = truth + np.array([[0.5, 0.0], [0.0, -0.2]])     # errors 0.5, 0.2
    assert percent_error(est, truth) == pytest.approx(100 * (0.5 / 5 + 0.2 / 10) / 2)


def test_page_escapes_and_checks_tables(tmp_path):
    with pytest.raises(ValueError, match="has 1 cells, expected 2"):
        Table(("a", "b"), (("only",),))
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "f.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    s = Section("k", "T <1>", [Text("a `x|y` and **b**"), Todo("later"),
                               Table(("c|1", "d"), (("<x>", "1"),), "cap"),
                               Figure("figures/f.png", "a <fig>")])
    md_path, html_path = page.write_page(tmp_path, "Title", ["intro"], [s],
                                         provenance.collect("derive reproduce"))
    md, doc = md_path.read_text(), html_path.read_text()
    assert "| c\\|1 | d |" in md and "> **TODO (lead):** later" in md
    assert "<code>x|y</code>" in doc and "<strong>b</strong>" in doc
    assert "&lt;x&gt;" in doc and "T &lt;1&gt;" in doc and 'class="todo"' in doc


def test_failed_verification_exits_1_after_writing(monkeypatch, tmp_path, capsys):
    from derive.apps.report.generation import GenerationResult
    from derive.apps.report.job import ReportResult
    from derive.apps.verify import Verification

    def fake_run(out, generated=None, quick=False, progress=True, command=None,
                 results=None):
        result = ReportResult(Path(out), None)
        result.generation = GenerationResult(["m"], [], [Verification("m", "kf", "c", 10, 1.0,
                                                                      1e-12)], [])
        result.index, result.page = page.write_page(Path(out), "t", [], [],
                                                    provenance.collect(command))
        return result

    monkeypatch.setattr("derive.apps.report.job.run", fake_run)
    status = cli.main(["reproduce", "--out", str(tmp_path), "--no-progress"])
    captured = capsys.readouterr()
    assert status == 1
    assert "FAIL" in captured.out and (tmp_path / "index.html").is_file()
    assert captured.err.count("\n") == 1 and "verification failed" in captured.err


def test_verify_built_equals_derive_verify():
    """The report's verification of built modules is derive verify's comparison."""
    from derive.apps.report.generation import verify_built
    from derive.apps.verify import verify_filter
    from derive.pipeline import load_generated

    model = catalog.load("mpt3d_b")
    kf = load_generated("mpt3d_b", "kf")
    modules = {"python": kf.python, "c": kf.c}
    ours = verify_built(model, "kf", modules, 300, 7)
    theirs = verify_filter(model, "kf", steps=300, seed=7)
    assert [(v.lang, v.tolerance) for v in ours] == [(v.lang, v.tolerance) for v in theirs]
    for a, b in zip(ours, theirs):
        assert a.error == pytest.approx(b.error, rel=1e-9, abs=1e-18)


def test_unwritable_output_is_bad_input(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert cli.main(["reproduce", "--quick", "--no-progress", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write the report" in err


def test_the_error_state_peer_is_a_note_where_symforce_is_not_installed(monkeypatch):
    """A full run (not quick) compares the error-state predict with SymForce's; where
    SymForce is missing the section says so and the job goes on (it was an internal error,
    exit 70, for the README's first command, whose extra did not install SymForce)."""
    from derive.apps.report import error_state
    from derive.modelfile import tomllib

    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "symforce" else found(name, *a))
    s = Section("ins_eskf", "INS/GNSS, error state")
    error_state.peer_flops(None, s)
    (todo,) = [b for b in s.blocks if isinstance(b, Todo)]
    assert todo.text.startswith("SymForce is not installed")
    extras = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml")
                           .read_text())["project"]["optional-dependencies"]
    assert any(dep.startswith("symforce") for dep in extras["report"])
