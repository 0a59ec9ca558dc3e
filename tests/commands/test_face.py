"""The face of derive: the distribution's name and extras, casadi optional and verify's
CasADi Jacobian witness (present and absent), the summaries of verify, progress lines on a
terminal only, help on every option, and verify's help stating its real bars."""

from __future__ import annotations

import argparse
import os
import pty
import re
import select
import subprocess
import sys
from pathlib import Path

import pytest

from derive import catalog, cli
from derive.apps import verify as verify_app
from derive.apps.casadi_bridge import JacobianCheck
from derive.apps.report.generation import witness_verdict
from derive.apps.report.job import witness_text
from derive.commands.verify import summary_line
from derive.version import DISTRIBUTION

ROOT = Path(__file__).resolve().parents[2]
PYPI_NAMES = Path("/work/.library/env/packages/pypi.tsv")

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: Runs the CLI with casadi unimportable (as if the casadi extra were not installed).
WITHOUT_CASADI = ("import sys; sys.modules['casadi'] = None; "
                  "from derive.cli import main; sys.exit(main(sys.argv[1:]))")


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]


def _env(**extra) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DERIVE_PROGRESS", None)
    env.update(extra)
    return env


def _requirement_names(requirements) -> list[str]:
    return [re.split(r"[\s<>=!;\[]", r, maxsplit=1)[0].lower() for r in requirements]


def normalised(name: str) -> str:
    """PEP 503."""
    return re.sub(r"[-_.]+", "-", name).lower()


# --- packaging ---------------------------------------------------------------------------

def test_distribution_name_is_derive_filters_and_metadata_reads_it():
    project = _project()
    assert project["name"] == DISTRIBUTION == "derive-filters"
    assert project["scripts"] == {"derive": "derive.cli:main"}
    version_source = (ROOT / "derive" / "version.py").read_text(encoding="utf-8")
    assert "version(DISTRIBUTION)" in version_source
    assert 'version("derive")' not in version_source


@pytest.mark.skipif(not PYPI_NAMES.is_file(), reason="no list of package-index names here")
def test_distribution_name_is_free_on_the_package_index():
    with PYPI_NAMES.open(encoding="utf-8") as names:
        taken = {normalised(line.split("\t", 1)[0]) for line in names}
    assert "derive" in taken          # why the distribution is not called derive
    assert normalised(DISTRIBUTION) not in taken


def test_casadi_is_an_extra_pulled_by_test_bench_and_report():
    project = _project()
    assert "casadi" not in _requirement_names(project["dependencies"])
    extras = project["optional-dependencies"]
    assert _requirement_names(extras["casadi"]) == ["casadi"]
    for extra in ("test", "bench", "report"):
        assert f"{DISTRIBUTION}[casadi]" in extras[extra], extra


def test_setuptools_at_run_time_on_python_312_and_georinex_only_for_tests():
    project = _project()
    runtime = [r for r in project["dependencies"] if r.startswith("setuptools")]
    assert runtime and "python_version >= '3.12'" in runtime[0]
    assert "scipy" in _requirement_names(project["dependencies"])
    extras = project["optional-dependencies"]
    assert "gnss" not in extras
    holders = [name for name, reqs in extras.items() if "georinex" in _requirement_names(reqs)]
    assert holders == ["test"]


def test_py_typed_ships():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "py.typed" in config["tool"]["setuptools"]["package-data"]["derive"]
    assert (ROOT / "derive" / "py.typed").is_file()


# --- the CasADi witness ------------------------------------------------------------------

def test_verify_prints_the_casadi_witness():
    pytest.importorskip("casadi")
    out = subprocess.run([sys.executable, "-m", "derive", "verify", "gnss_pseudorange",
                          "--filter", "ekf", "--steps", "30"], capture_output=True,
                         text=True, env=_env(), timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    witness = [line for line in lines if "casadi" in line]
    assert len(witness) == 1 and witness[0].startswith("ok   gnss_pseudorange")
    assert "100 points" in witness[0] and "sympy Jacobians vs CasADi AD" in witness[0]
    assert lines[-1] == "derive verify: 3 passed, 0 failed (1 model)"


def test_verify_without_casadi_reports_the_witness_skipped():
    out = subprocess.run([sys.executable, "-c", WITHOUT_CASADI, "verify", "gnss_pseudorange",
                          "--filter", "ekf", "--steps", "30"], capture_output=True,
                         text=True, env=_env(), timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stderr == ""
    lines = out.stdout.splitlines()
    assert any(line.startswith("skip gnss_pseudorange") and "witness skipped: casadi is not "
               "installed (pip install 'derive-filters[casadi]')" in line for line in lines)
    assert lines[-1] == "derive verify: 2 passed, 0 failed, 1 skipped (1 model)"


def test_cli_imports_nothing_of_casadi_until_a_witness_is_due():
    out = subprocess.run([sys.executable, "-c", WITHOUT_CASADI, "verify", "mpt3d_b",
                          "--filter", "kf", "--steps", "20"], capture_output=True, text=True,
                         env=_env(), timeout=300)
    assert out.returncode == 0, out.stderr
    assert "casadi" not in out.stdout     # a linear model has no Jacobians to witness
    assert out.stdout.splitlines()[-1] == "derive verify: 2 passed, 0 failed (1 model)"


def test_witness_skipped_in_process_and_in_the_report_summary(monkeypatch):
    monkeypatch.setitem(sys.modules, "casadi", None)
    witness = verify_app.jacobian_witness(catalog.load("gnss_pseudorange"))
    assert witness.check is None and not witness.passed
    assert "casadi is not installed" in witness.skipped
    assert verify_app.jacobian_witness(catalog.load("mpt3d_b")) is None
    assert witness_text([witness]).startswith("CasADi witness skipped for 1 model(s): casadi")
    assert witness_verdict([witness]) is None    # no outcome counted for the papers
    ran = verify_app.JacobianWitness("m", JacobianCheck("m", 100, 0.0, 1e-15, 0.0, 0.0))
    assert witness_verdict([ran, witness]) == (
        "matched", "1 models, 0 failed, 1 skipped, largest relative difference 1.0e-15")


def test_a_failing_witness_fails_verify(monkeypatch, capsys):
    bad = verify_app.JacobianWitness(
        "gnss_pseudorange", JacobianCheck("gnss_pseudorange", 100, 0.0, 0.0, 0.0, 3e-9))
    assert not bad.passed and bad.line().startswith("FAIL gnss_pseudorange")
    monkeypatch.setattr(verify_app, "jacobian_witness", lambda model: bad)
    status = cli.main(["verify", "gnss_pseudorange", "--filter", "ekf", "--steps", "20"])
    out = capsys.readouterr()
    assert status == 1
    assert out.out.splitlines()[-1] == "derive verify: 2 passed, 1 failed (1 model)"
    assert "witness" in out.err


def test_summary_line():
    assert summary_line({"passed": 4, "failed": 1, "skipped": 0}, 2) == \
        "derive verify: 4 passed, 1 failed (2 models)"
    assert summary_line({"passed": 1, "failed": 0, "skipped": 2}, 1) == \
        "derive verify: 1 passed, 0 failed, 2 skipped (1 model)"


# --- progress on a terminal only ---------------------------------------------------------

def _run_with_stderr_on_a_pty(argv: list[str]) -> tuple[int, str, str]:
    """Run derive with stderr on a pseudo-terminal and stdout on a pipe."""
    leader, follower = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "derive", *argv], stdout=subprocess.PIPE,
                            stderr=follower, env=_env(), text=True)
    os.close(follower)
    chunks = []
    try:
        while True:
            ready, _, _ = select.select([leader], [], [], 300)
            if not ready:
                break
            try:
                data = os.read(leader, 4096)
            except OSError:     # the terminal closes when the process ends
                break
            if not data:
                break
            chunks.append(data.decode(errors="replace"))
        out = proc.stdout.read()
        proc.wait(timeout=300)
    finally:
        os.close(leader)
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, out, "".join(chunks)


def test_verify_shows_progress_on_a_terminal_only():
    argv = ["verify", "mpt3d_b", "--filter", "kf", "--filter", "sskf", "--steps", "20"]
    status, out, terminal = _run_with_stderr_on_a_pty(argv)
    assert status == 0
    assert "derive: verify [1/1] mpt3d_b: kf" in terminal
    assert "derive: verify [1/1] mpt3d_b: sskf" in terminal
    assert "derive:" not in out
    piped = subprocess.run([sys.executable, "-m", "derive", *argv], capture_output=True,
                           text=True, env=_env(), timeout=300)
    assert piped.returncode == 0 and piped.stderr == ""
    status, out, terminal = _run_with_stderr_on_a_pty(argv + ["--no-progress"])
    assert status == 0 and "derive: verify" not in terminal


@pytest.mark.parametrize("tty", [False, True])
def test_bench_progress_on_a_terminal_only(monkeypatch, capsys, tty):
    seen = {}

    def fake_bench(settings, progress=None):
        seen["progress"] = progress
        if progress is not None:
            progress("KF mpt3d_a: generated C")
        raise OSError("stop here")

    monkeypatch.delenv("DERIVE_PROGRESS", raising=False)
    monkeypatch.setattr("derive.apps.bench.run.run_bench", fake_bench)
    monkeypatch.setattr("sys.stderr.isatty", lambda: tty)
    cli.main(["bench", "--quick"])
    err = capsys.readouterr().err
    assert (seen["progress"] is not None) is tty
    assert ("derive: bench: KF mpt3d_a: generated C" in err) is tty


# --- help ----------------------------------------------------------------------------------

def test_every_option_of_every_command_has_help():
    parser = cli.build_parser()
    missing = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                missing += [f"{name} {a.option_strings or a.dest}" for a in sub._actions
                            if not a.help]
    assert missing == []


def test_verify_help_states_the_bars_it_applies():
    out = subprocess.run([sys.executable, "-m", "derive", "verify", "--help"],
                         capture_output=True, text=True, env=_env(), timeout=60).stdout
    text = " ".join(out.split())
    assert "1e-12 for linear filters" in text and "c u64 L G kappa" in text
    assert "1e-10" in text and "rounding floor" in text and "CasADi" in text
    assert verify_app.LINEAR_TOLERANCE == 1e-12 and verify_app.NONLINEAR_TOLERANCE == 1e-10
