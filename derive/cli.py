"""The command line: `derive COMMAND ...` (commands live in derive/commands/).

Every failure is one line on stderr, never a traceback (:func:`main` is the one place
that turns exceptions into lines and exit statuses):

- 2: bad input (a ModelError, a usage error, an argument that is not valid UTF-8), a
  file or directory that cannot be read or written (an OSError: the line names the
  path), no C compiler (the line names the compiler looked for) or an unsafe cache
  of compiled modules (see derive.build.cache_dir);
- 1: a failed verification or a numerical failure;
- 130: interrupted (Ctrl-C): ``derive: interrupted``;
- 141: standard output closed early (``derive list | head``): nothing is printed, as a
  Unix tool killed by SIGPIPE;
- 70: an internal error (a bug): one line with the exception, and a hint to report it;
  ``DERIVE_DEBUG=1`` lets the traceback through.
"""

from __future__ import annotations

import argparse
import difflib
import os
import re
import sys

from . import commands
from .errors import ModelError, NumericalError, VerificationError


class _Parser(argparse.ArgumentParser):
    """Usage errors are one line on stderr, exit status 2, with the prefix of every other
    error (``derive: error:``, whichever command's parser found it); an unknown flag or a
    choice close to a known one names it."""

    def error(self, message: str):
        message = " ".join(message.split())
        self.exit(2, f"derive: error: {message}{_choice_hint(message)}"
                     f"{_flag_hint(self, message)}\n")


_INVALID_CHOICE = re.compile(r"invalid choice: '(.*?)' \(choose from (.*)\)$")


def _choice_hint(message: str) -> str:
    """`` (did you mean 'diagonal'?)`` for argparse's ``invalid choice: 'diag' (choose from
    'dense', ...)`` (a command: ``verfy``; a choice of an option: ``--P0-pattern diag``)."""
    found = _INVALID_CHOICE.search(message)
    if found is None:
        return ""
    choices = re.findall(r"'([^']*)'", found[2])
    close = difflib.get_close_matches(found[1], choices, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _flag_hint(parser: argparse.ArgumentParser, message: str) -> str:
    """`` (did you mean --joseph?)`` for an unrecognized ``--jospeh`` (flags of every
    command are candidates: argparse reports unknown ones from the top parser)."""
    prefix = "unrecognized arguments: "
    if not message.startswith(prefix):
        return ""
    unknown = [arg.split("=")[0] for arg in message[len(prefix):].split()
               if arg.startswith("--")]
    if not unknown:   # no flag to match: the other commands' parsers stay unbuilt
        return ""
    parsers = [parser, *_command_parsers(parser)]
    for command_parser in parsers[1:]:
        command_parser.complete()   # the flags of commands not given are candidates too
    flags = sorted({s for p in parsers for a in p._actions for s in a.option_strings})
    hints = []
    for flag in unknown:
        owners = [p.prog for p in parsers[1:]
                  if any(flag in a.option_strings for a in p._actions)]
        if owners:   # spelt right, given to a command that does not take it
            hints.append(f"{flag} is an option of {', '.join(owners)} only")
            continue
        close = difflib.get_close_matches(flag, flags, n=1)
        if close:
            hints.append(f"{flag}: did you mean {close[0]}?")
    return f" ({'; '.join(hints)})" if hints else ""


class _Version(argparse.Action):
    """``--version``: derive's version and its key dependencies' (read when asked, so the
    parser stays fast to build)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from .apps.report.provenance import version_text

        sys.stdout.write(version_text() + "\n")
        parser.exit(0)


class _CommandParser(_Parser):
    """The parser of one command: the command's arguments are added when it is first
    used (its command parses, or its help or usage is shown), so that ``derive`` imports
    what a command's arguments need (derive.options and the filter registry, for one)
    only for the command that runs."""

    def __init__(self, *args, command=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._command = command

    def complete(self) -> None:
        """Add the command's arguments (once)."""
        command, self._command = self._command, None
        if command is not None:
            command.add_arguments(self)
            self.set_defaults(func=command.run)

    def parse_known_args(self, args=None, namespace=None):
        self.complete()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self.complete()
        return super().format_usage()

    def format_help(self) -> str:
        self.complete()
        return super().format_help()


def build_parser(*, complete: bool = True) -> argparse.ArgumentParser:
    """The parser of ``derive`` and of every command. ``complete=False`` (what
    :func:`main` uses): each command's arguments are added when that command is used."""
    parser = _Parser(
        prog="derive",
        description="Derive specialised, unrolled Python and C99 Kalman-family filters from "
                    "SymPy state-space models, with exact flop counts.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  derive list\n  derive generate mpt3d_a --filter kf --lang c\n"
               "  derive reproduce",
    )
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="print the versions of derive, Python and the key dependencies "
                             "and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND",
                                parser_class=_CommandParser)
    sub.required = True
    for module in commands.modules():
        sub.add_parser(module.NAME, help=module.HELP, description=module.HELP,
                       epilog=f"example:\n  {module.EXAMPLE}",
                       formatter_class=argparse.RawDescriptionHelpFormatter, command=module)
    if complete:
        for command_parser in _command_parsers(parser):
            command_parser.complete()
    return parser


def _command_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    return [p for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for p in action.choices.values()]


def main(argv=None) -> int:
    try:
        status = _main(sys.argv[1:] if argv is None else argv)
        sys.stdout.flush()   # a closed pipe shows here rather than at exit
        return status
    except BrokenPipeError:
        _discard_stdout()
        return 141
    except KeyboardInterrupt:
        print("derive: interrupted", file=sys.stderr)
        return 130
    except ModelError as exc:
        print(f"derive: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (VerificationError, NumericalError) as exc:
        print(f"derive: verification failed: {_one_line(exc)}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"derive: error: {_os_error(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:
        build = sys.modules.get("derive.build")   # loaded if a compiler was looked for
        if build is not None and isinstance(exc, build.BuildEnvironmentError):
            print(f"derive: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        if os.environ.get("DERIVE_DEBUG"):
            raise
        print(f"derive: internal error: {type(exc).__name__}: {_one_line(exc)} (a bug in "
              "derive: please report it; DERIVE_DEBUG=1 shows the traceback)",
              file=sys.stderr)
        return 70


def _main(argv: list[str]) -> int:
    for arg in argv:
        _check_utf8(arg)
    parser = build_parser(complete=False)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: usage errors are bad input (2), --help is 0
        return int(exc.code or 0)
    return int(args.func(args) or 0)


def _check_utf8(arg: str) -> None:
    """Refuse an argument with bytes that are not UTF-8 (decoded as surrogates): paths
    are stated in the generated files, which are UTF-8."""
    try:
        arg.encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(arg).decode("utf-8", "backslashreplace")
        raise ModelError(f"argument '{shown}' is not valid UTF-8 (derive states its paths "
                         "in the files it writes, which are UTF-8)") from None


def _os_error(exc: OSError) -> str:
    """``PATH: reason`` (both paths of a rename), or the reason alone."""
    reason = exc.strerror or _one_line(exc)
    names = [os.fsdecode(n) for n in (exc.filename, exc.filename2) if n is not None]
    return f"{' -> '.join(names)}: {reason}" if names else reason


def _discard_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


if __name__ == "__main__":
    sys.exit(main())
