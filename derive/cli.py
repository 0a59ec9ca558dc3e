"""The command line: `derive COMMAND ...` (commands live in derive/commands/).

Errors are one line on stderr: exit status 2 for bad input (a ModelError), 1 for a
failed verification or a numerical failure.
"""

from __future__ import annotations

import argparse
import sys

from . import __version__
from .errors import ModelError, NumericalError, VerificationError


class _Parser(argparse.ArgumentParser):
    """Usage errors are one line on stderr, exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


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
