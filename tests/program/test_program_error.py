"""ProgramError is a bug in a derivation (a program built wrongly), not bad input: it is
not a ModelError, so the CLI reports it as an internal error (exit 70), not as exit 2."""

from __future__ import annotations

import pytest

from derive import cli
from derive.errors import ModelError
from derive.program import Port, Program, ProgramError


def test_program_error_is_an_internal_error():
    assert issubclass(ProgramError, RuntimeError)
    assert not issubclass(ProgramError, ModelError)


def test_a_program_built_wrongly_is_not_caught_as_bad_input():
    prog = Program("f", inputs=[Port("x", (2,))], outputs=[Port("y", (2,))])
    with pytest.raises(ProgramError, match="no port 'z'"):
        try:
            prog.port("z")
        except ModelError:  # what the CLI and the API treat as bad input
            pytest.fail("ProgramError caught as ModelError")


def test_cli_reports_a_program_error_as_internal(monkeypatch, capsys):
    def broken(argv):
        raise ProgramError("program 'step': outputs ['P_new'] were never set")

    monkeypatch.setattr(cli, "_main", broken)
    monkeypatch.delenv("DERIVE_DEBUG", raising=False)
    assert cli.main(["generate", "cv"]) == 70
    err = capsys.readouterr().err
    assert "internal error: ProgramError" in err and "\n" == err[-1] and err.count("\n") == 1
