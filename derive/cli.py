"""The command line: `derive COMMAND ...` (commands live in derive/commands/).

Errors are one line on stderr: exit status 2 for bad input (a ModelError), 1 for a
failed verification or a numerical failure.
"""

from __future__ import annotations

import argparse
import difflib
import sys

from . import __version__
from .errors import ModelError, NumericalError, VerificationError


class _Parser(argparse.ArgumentParser):
    """Usage errors are one line on stderr, exit status 2; an unknown flag close to a known
    one names it."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}"
                     f"{_flag_hint(self, message)}\n")


def _flag_hint(parser: argparse.ArgumentParser, message: str) -> str:
    """`` (did you mean --joseph?)`` for an unrecognized ``--jospeh`` (flags of every
    command are candidates: argparse reports unknown ones from the top parser)."""
    prefix = "unrecognized arguments: "
    if not message.startswith(prefix):
        return ""
    parsers = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            parsers += list(action.choices.values())
    flags = sorted({s for p in parsers for a in p._actions for s in a.option_strings})
    hints = []
    for arg in message[len(prefix):].split():
        close = difflib.get_close_matches(arg.split("=")[0], flags, n=1)
        if arg.startswith("--") and close:
            hints.append(f"{arg.split('=')[0]}: did you mean {close[0]}?")
    return f" ({'; '.join(hints)})" if hints else ""


def build_parser() -> argparse.ArgumentParser:
    from . import commands

    parser = _Parser(
        prog="derive",
        description="Derive specialised, unrolled Python and C99 Kalman-family filters from "
                    "SymPy state-space models, with exact flop counts.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  derive list\n  derive generate mpt3d_a --filter kf --lang c\n"
               "  derive reproduce",
    )
    parser.add_argument("--version", action="version", version=f"derive {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in commands.modules():
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP,
                           epilog=f"example:\n  {module.EXAMPLE}",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(func=module.run)
    return parser




def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: usage errors are bad input (2), --help is 0
        return int(exc.code or 0)
    try:
        return int(args.func(args) or 0)
    except ModelError as exc:
        print(f"derive: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (VerificationError, NumericalError) as exc:
        print(f"derive: verification failed: {_one_line(exc)}", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


if __name__ == "__main__":
    sys.exit(main())
