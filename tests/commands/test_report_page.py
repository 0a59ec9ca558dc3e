"""The report's page and the command line around it, without running the job: the
summary first with links, numeric columns right-aligned and unwrapped, text columns
left-aligned, long tables and console dumps folded, figures embedded, the provenance
footer, units on every axis, coinciding curves drawn once, results.md, `derive check`'s
summary line, `derive --version`, help on every option, and progress only on a terminal."""

from __future__ import annotations

import argparse
import base64
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from derive import __version__, cli
from derive.apps.report import figures, page, provenance
from derive.apps.report.document import (
    DIFFERS,
    MATCHED,
    NOT_COMPARABLE,
    Figure,
    Outcome,
    Preformatted,
    Section,
    Table,
    Text,
)

PNG = b"\x89PNG\r\n\x1a\n"


def _provenance() -> provenance.Provenance:
    return provenance.collect("derive reproduce --quick")


def _figure(folder: Path, name: str) -> Figure:
    fig, axes = figures.new(1, 1)
    axes[0, 0].plot([0, 1, 2], [0, 1, 4])
    axes[0, 0].set_xlabel("time (s)")
    axes[0, 0].set_ylabel("position (m)")
    return figures.save(fig, folder, name, f"a figure {name}")


def _sections(root: Path) -> list[Section]:
    paper = Section("p1", "P1: a paper", paper="P1")
    paper.outcome("claim one", MATCHED, "difference 1e-16")
    paper.outcome("Table 2", NOT_COMPARABLE, "data not available")
    paper.add(Text("text"), _figure(root / "figures", "one"),
              Table(("quantity", "ours", "paper"), (("RMSE x", "1.2e-06", "1.30"),
                                                    ("range", "0.0052–0.0074", "–")), "cap"),
              Preformatted("a very long console line " * 20, "console"))
    appendix = Section("appendix", "Appendix: checks")
    appendix.outcome("every filter verified", DIFFERS, "1 failed")
    appendix.add(Table(("model", "error", "status"),
                       tuple((f"m{i}", f"{i}e-16", "ok") for i in range(40)), "long table",
                       collapsed=True))
    return [paper, appendix]


@pytest.fixture
def written(tmp_path):
    (tmp_path / "figures").mkdir()
    sections = _sections(tmp_path)
    md, doc = page.write_page(tmp_path, "Title", ["intro"], sections, _provenance())
    return tmp_path, sections, md.read_text(encoding="utf-8"), doc.read_text(encoding="utf-8")


def test_numbers_are_recognised_and_text_is_not():
    for cell in ("1e-06", "1.2e-06", "−3.5", "0.0052–0.0074", "3, 4", "**504**", "1.2e-03 m",
                 "12.5 %", "–", "55.333", "1,000"):
        assert page.is_number(cell), cell
    for cell in ("ok", "KF = LF, model A", "equal to rounding", "mpt3d_a", "x (latitude)",
                 "**FAIL**", "prediction N = 1"):
        assert not page.is_number(cell), cell


def test_numeric_columns_right_aligned_unwrapped_text_columns_left(written):
    _, _, _, doc = written
    assert re.search(r"td\.num, th\.num \{[^}]*text-align: right;[^}]*white-space: nowrap", doc)
    assert re.search(r"th, td \{[^}]*text-align: left", doc)
    assert "<td>RMSE x</td><td class=\"num\">1.2e-06</td>" in doc
    assert '<td class="num">0.0052–0.0074</td>' in doc
    assert "<th>quantity</th>" in doc and '<th class="num">ours</th>' in doc


def test_scientific_numbers_in_text_never_wrap(written):
    _, _, _, doc = written
    assert ".nb { white-space: nowrap; }" in doc
    assert '<td>difference <span class="nb">1e-16</span></td>' in doc
    assert page._inline_html("x 2.5e-07 m, mpt3d_a, v1e-3") == \
        'x <span class="nb">2.5e-07</span> m, mpt3d_a, v1e-3'


def test_summary_comes_first_and_links_every_section(written):
    _, sections, md, doc = written
    summary = doc.index("Summary: what was reproduced")
    assert summary < doc.index('<section id="p1">') < doc.index("<figure>")
    for s in sections:
        assert f'<a href="#{s.key}">{s.short}</a>' in doc
        assert f'<section id="{s.key}">' in doc
    assert '<span class="matched">matched</span>' in doc
    assert '<span class="differs">differs</span>' in doc
    assert "Outcomes: 1 matched, 1 differ, 1 not comparable" in doc
    assert md.index("Summary: what was reproduced") < md.index("## P1: a paper")
    assert "[P1](#p1)" in md


def test_long_tables_and_console_dumps_are_folded(written):
    _, _, _, doc = written
    assert re.search(r"<details><summary>long table \(40 rows\)</summary>\s*<table>", doc)
    assert re.search(r"<details><summary>console</summary><pre>a very long", doc)
    assert "<details><summary>cap" not in doc     # short tables stay open


def test_figures_are_embedded_so_index_html_alone_is_complete(written):
    root, _, md, doc = written
    sources = re.findall(r'<img src="([^"]+)"', doc)
    assert len(sources) == 1
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        data = base64.b64decode(src.split(",", 1)[1])
        assert data.startswith(PNG) and data == (root / "figures" / "one.png").read_bytes()
    assert "(figures/one.png)" in md            # Markdown keeps the folder
    assert "self-contained" in doc


def test_footer_names_date_versions_machine_and_command(written):
    _, _, md, doc = written
    footer = doc[doc.index("<footer>"):]
    versions = provenance.versions()
    assert re.search(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", footer)
    for v in (__version__, versions["python"], versions["numpy"], versions["sympy"]):
        assert v in footer and v in md
    assert provenance.machine() in footer
    assert "<code>derive reproduce --quick</code>" in footer
    assert "- **command:** `derive reproduce --quick`" in md


def test_results_markdown_is_the_summary_with_command_and_date():
    sections = [Section("p", "P: x", paper="P", outcomes=[Outcome("claim", MATCHED, "1e-16")])]
    text = page.results_markdown("T", "intro", sections, _provenance())
    assert "| P | claim | matched | 1e-16 | P |" in text
    assert "`derive reproduce --quick`" in text and "Outcomes: 1 matched" in text


def test_an_outcome_needs_a_known_verdict():
    with pytest.raises(ValueError, match="unknown verdict"):
        Outcome("claim", "roughly", "")


def test_a_figure_without_units_is_refused(tmp_path):
    fig, axes = figures.new(1, 1)
    axes[0, 0].plot([0, 1], [0, 1])
    axes[0, 0].set_ylabel("position x")
    with pytest.raises(ValueError, match="without a unit: 'position x'"):
        figures.save(fig, tmp_path, "bad", "")
    axes[0, 0].set_ylabel("sat 1")
    axes[0, 0].set_xlabel("time (s)")
    assert figures.missing_units(fig) == ["'sat 1'"]
    axes[0, 0].set_ylabel("position x (m)")
    assert figures.missing_units(fig) == []


def test_coinciding_curves_are_drawn_once_and_named_together():
    fig, axes = figures.new(1, 1)
    t = np.arange(100.0)
    ekf = np.sin(t / 10)
    drawn = figures.plot_curves(axes[0, 0], t, {"EKF": ekf, "UKF": ekf + 1e-6,
                                                "LS": ekf + 0.5})
    assert drawn.groups == (("EKF", "UKF"), ("LS",)) and drawn.merged
    lines = axes[0, 0].get_lines()
    assert [line.get_label() for line in lines] == ["EKF = UKF", "LS"]
    assert lines[0].get_linestyle() != lines[1].get_linestyle()
    assert "EKF and UKF coincide (largest difference 1.0e-06 m" in \
        figures.coincidence_note([drawn], "m")
    apart = figures.plot_curves(axes[0, 0], t, {"EKF": ekf, "UKF": ekf + 0.1})
    assert not apart.merged
    assert figures.coincidence_note([apart], "m") == "Line styles tell the curves apart."


def test_version_lists_derive_and_its_key_dependencies(capsys):
    assert cli.main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"derive {__version__}"
    for name in ("python", "numpy", "sympy", "jinja2", "cffi", "casadi"):
        assert re.search(rf"^{name} \S+$", out, re.M), name


def test_check_ends_with_a_one_line_summary(capsys):
    assert cli.main(["check", "mpt3d_b", "--steps", "60"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert re.fullmatch(r"derive check: (\d+) passed, 0 failed \(1 model\)", lines[-1])
    assert int(lines[-1].split()[2]) == len(lines) - 1


def test_check_summary_counts_failures(monkeypatch, capsys):
    from derive.apps.checks import Check

    def fake(model, steps, seed):
        return [Check("m", "a claim", 1.0, 1e-10), Check("m", "another", 0.0, 1e-10)]

    monkeypatch.setattr("derive.apps.checks.run_checks", fake)
    assert cli.main(["check", "mpt3d_b"]) == 1
    captured = capsys.readouterr()
    assert captured.out.strip().splitlines()[-1] == \
        "derive check: 1 passed, 1 failed (1 model)"


# Options of commands outside the report's area that had no help text when this test was
# written (their owners add it); every other option must have help.
KNOWN_WITHOUT_HELP: set[tuple[str, str]] = set()


def test_every_option_has_help_text():
    parser = cli.build_parser()
    missing = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                missing += [(name, a.option_strings[0] if a.option_strings else a.dest)
                            for a in sub._actions if not a.help]
        elif not action.help and not isinstance(action, argparse._HelpAction):
            missing.append(("derive", action.option_strings[0]))
    assert set(missing) <= KNOWN_WITHOUT_HELP, sorted(set(missing) - KNOWN_WITHOUT_HELP)


@pytest.mark.parametrize("tty", [False, True])
def test_progress_only_on_a_terminal(monkeypatch, tmp_path, tty):
    seen = {}

    def fake_run(out, generated=None, quick=False, progress=True, command=None,
                 results=None):
        seen.update(progress=progress, command=command)
        raise OSError("stop here")

    monkeypatch.setattr("derive.apps.report.job.run", fake_run)
    monkeypatch.setattr("sys.stderr.isatty", lambda: tty)
    cli.main(["reproduce", "--quick", "--out", str(tmp_path)])
    assert seen["progress"] is tty
    assert seen["command"] == f"derive reproduce --out {tmp_path} --quick"


def test_progress_disabled_writes_nothing(capsys):
    from derive.apps.report.job import _Progress

    bar = _Progress(3, enabled=False)
    bar.stage("one")
    bar.advance()
    bar.close()
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("case", ["missing directory", "empty", "a directory", "/dev/full",
                                  "immutable directory"])
def test_a_results_path_that_cannot_be_written_is_bad_input_before_any_work(tmp_path, capsys,
                                                                          case):
    """--results is checked before the job (it failed only after the whole job, blaming
    "the report or the generated code"): one line naming it, exit 2, nothing written."""
    locked = tmp_path / "locked"
    locked.mkdir()
    target = {"missing directory": tmp_path / "no" / "results.md", "empty": "",
              "a directory": tmp_path, "/dev/full": "/dev/full",
              "immutable directory": locked / "results.md"}[case]
    if case == "immutable directory" and (shutil.which("chattr") is None or subprocess.run(
            ["chattr", "+i", str(locked)], capture_output=True).returncode != 0):
        pytest.skip("chattr +i is not available here")
    try:
        status = cli.main(["reproduce", "--quick", "--no-progress", "--out",
                           str(tmp_path / "r"), "--results", str(target)])
    finally:
        if case == "immutable directory":
            subprocess.run(["chattr", "-i", str(locked)], check=True)
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert err.startswith(f"derive: error: --results {target}") and "Traceback" not in err
    assert not (tmp_path / "r").exists() and not list(locked.iterdir())


def test_the_repositorys_results_file_is_written_by_the_command():
    """docs/results.md is `derive reproduce --results docs/results.md` output, not typed:
    the command's title, intro, summary columns, verdicts and provenance footer."""
    from derive.apps.report.job import TITLE

    text = (Path(__file__).parents[2] / "docs" / "results.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert lines[0] == f"# {TITLE}"
    assert lines[2].startswith("Written by `derive reproduce ") and \
        "--results docs/results.md" in lines[2]
    assert "| " + " | ".join(page.SUMMARY_COLUMNS) + " |" in lines
    rows = [line for line in lines if line.startswith("| ") and "| verdict |" not in line]
    assert rows and all(re.search(r" \| (matched|differs|not comparable) \| ", r) for r in rows)
    for label in ("date", "derive", "Python", "machine", "command"):
        assert re.search(rf"^- \*\*{label}:\*\* \S", text, re.M), label
