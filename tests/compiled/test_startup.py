"""The command line starts fast: help, --version and the refusals of bad arguments import
no SymPy, NumPy, Jinja2 or cffi (read from ``python -X importtime -m derive ...``, the
modules the real command loads); ``import derive`` loads its API names on first use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import derive
from derive import cli, commands
from derive.apps.bench.costs import startup

ROOT = Path(__file__).resolve().parents[2]

#: What the start-up must not load: the numeric and symbolic stack, the templates' engine,
#: the C builds, and derive's own heavy layers (the filter registry, the generator, the
#: applications).
HEAVY = ("sympy", "numpy", "jinja2", "cffi", "scipy", "derive.filters", "derive.emit",
         "derive.generation", "derive.build", "derive.apps")


def _run(*argv: str) -> tuple[subprocess.CompletedProcess, set[str]]:
    """``python -X importtime -m derive ARGV``, and the modules it imported."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "derive", *argv],
                          capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
    imported = {line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines()
                if line.startswith("import time:") and line.count("|") == 2}
    return done, imported


def _heavy(imported: set[str]) -> list[str]:
    return sorted(m for m in imported if any(m == h or m.startswith(h + ".") for h in HEAVY))


def test_the_import_log_is_read():
    """The parse sees derive's modules (a test that reads nothing could not fail)."""
    done, imported = _run("--help")
    assert done.returncode == 0, done.stderr
    assert {"derive", "derive.cli", "derive.commands", "argparse"} <= imported


#: The modules of derive.apps --version reads (the versions of the key dependencies, from
#: their installed metadata, not by importing them).
VERSION_TEXT = {"derive.apps", "derive.apps.report", "derive.apps.report.provenance"}

LIGHT_CALLS = {
    "help": (["--help"], 0),
    "version": (["--version"], 0),
    "a light command's help": (["list", "--help"], 0),
    "unknown command": (["frobnicate"], 2),
    "no command": (["--bogus"], 2),
    "missing argument": (["show"], 2),
    "unrecognized argument": (["list", "extra"], 2),
}


@pytest.mark.parametrize("case", sorted(LIGHT_CALLS))
def test_start_up_imports_nothing_heavy(case):
    argv, status = LIGHT_CALLS[case]
    done, imported = _run(*argv)
    assert done.returncode == status, done.stderr
    assert _heavy(imported - (VERSION_TEXT if case == "version" else set())) == []


def test_light_command_helps_import_nothing_heavy():
    """Every command whose arguments need nothing heavy shows its help without it (the
    commands that take filter options need the registry, whose specs name the filters in
    the options' help; gnss reads its defaults from derive.apps.gnss)."""
    for module in commands.modules():
        if module.NAME in ("generate", "verify", "burden", "size", "gnss"):
            continue
        done, imported = _run(module.NAME, "--help")
        assert done.returncode == 0, (module.NAME, done.stderr)
        assert _heavy(imported) == [], module.NAME


def test_list_loads_no_generator(tmp_path, monkeypatch):
    """`derive list` needs the models and the filter registry, not the code generator, its
    templates or the C builds; once its rows are cached for this very derive (the key
    hashes the package's files, so the entry cannot go stale), it loads neither SymPy nor
    the registry (it took 1.3 to 1.9 s) and prints the same rows. An entry others could
    write is computed again."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    done, imported = _run("list")
    assert done.returncode == 0, done.stderr
    assert "derive.filters" in imported
    assert sorted(imported & {"jinja2", "cffi", "derive.emit.render", "derive.generation",
                              "derive.build"}) == []
    again, cached = _run("list")
    assert again.returncode == 0 and again.stdout == done.stdout
    assert sorted(cached & {"sympy", "numpy", "derive.filters", "derive.catalog"}) == []
    (entry,) = (tmp_path / "derive").glob("list-*.json")
    entry.chmod(0o666)
    third, loaded = _run("list")
    assert third.stdout == done.stdout and "derive.filters" in loaded
    assert entry.stat().st_mode & 0o022 == 0       # replaced by a private entry


def test_a_command_is_completed_when_it_runs():
    """The command that runs has its arguments; the others' stay unbuilt."""
    parser = cli.build_parser(complete=False)
    args = parser.parse_args(["show", "cv"])
    show = next(m for m in commands.modules() if m.NAME == "show")
    assert args.model == "cv" and args.func is show.run
    built = {p.prog for p in cli._command_parsers(parser) if p._command is None}
    assert built == {"derive show"}


def test_lazy_help_and_usage_are_the_complete_parsers():
    """Each command's usage and help, built on use, are those of the parser built whole."""
    complete = {p.prog: p for p in cli._command_parsers(cli.build_parser())}
    lazy = cli._command_parsers(cli.build_parser(complete=False))
    assert sorted(p.prog for p in lazy) == sorted(complete)
    for parser in lazy:
        assert parser.format_usage() == complete[parser.prog].format_usage(), parser.prog
        assert parser.format_help() == complete[parser.prog].format_help(), parser.prog


def test_a_flag_hint_still_names_another_commands_flag(capsys):
    """An unknown flag given to a command whose parser is light is matched against every
    command's flags (generate's filter options among them)."""
    assert cli.main(["list", "--jospeh"]) == 2
    assert "did you mean --joseph?" in capsys.readouterr().err


def test_import_derive_loads_no_sympy():
    code = ("import sys\nimport derive\n"
            "print(sorted(m for m in ('sympy', 'numpy', 'jinja2') if m in sys.modules))\n"
            "assert derive.LinearModel.__module__ == 'derive.model'\n"
            "print('sympy' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["[]", "True"]


def test_the_api_names_are_the_modules_objects():
    from derive import build, generation, model, pipeline, version

    assert derive.generate is generation.generate
    assert derive.build_c is build.build_c and derive.load_python is build.load_python
    assert (derive.LinearModel, derive.NonlinearModel, derive.Sensor) == (
        model.LinearModel, model.NonlinearModel, model.Sensor)
    assert derive.load_generated is pipeline.load_generated
    assert derive.__version__ == version.__version__
    assert derive.catalog.load("cv").n == 2
    assert set(derive.__all__) <= set(dir(derive))
    assert all(hasattr(derive, name) for name in derive.__all__)


def test_an_unknown_api_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="'no_such_name'"):
        derive.no_such_name  # noqa: B018
    assert not hasattr(derive, "no_such_name")



def test_the_bench_times_every_start_up_call(tmp_path, monkeypatch, capsys):
    """`derive bench`'s start-up rows: the floor, each call and each command's help, with
    the exit status the same call gives in this process."""
    rows = startup.startup_rows(1, tmp_path)
    assert [r.call for r in rows] == [startup.FLOOR, *(name for name, _ in startup.CALLS),
                                      *(f"derive {m.NAME} --help" for m in commands.modules())]
    monkeypatch.chdir(tmp_path)
    expected = [0]
    for argv in [args for _, args in startup.CALLS] + [(m.NAME, "--help")
                                                       for m in commands.modules()]:
        expected.append(cli.main(list(argv)))
        capsys.readouterr()
    assert [r.returncode for r in rows] == expected
    assert 2 in expected and 0 in expected
    assert all(r.seconds > 0 and r.cpu_seconds >= 0 for r in rows)
