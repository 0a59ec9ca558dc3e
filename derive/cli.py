"""The command line: `derive SUBCOMMAND ...`.

Errors are one line on stderr: exit status 2 for bad input (a ModelError), 1 for a
failed verification. Each subcommand lives in a function ``cmd_<name>``; the work
itself is done by library modules.
"""

from __future__ import annotations

import argparse
import sys
import textwrap

from . import __version__
from .errors import ModelError, NumericalError, VerificationError


def _load(ref: str):
    """A model by catalog name or model-file path."""
    from . import catalog

    if ref.endswith(".toml") or "/" in ref or "\\" in ref:
        from .modelfile import load_model_file

        return load_model_file(ref)
    return catalog.load(ref)


def _short_source(text: str, width: int = 48) -> str:
    head = text.split(":")[0].strip()
    return head if len(head) <= width else head[: width - 3] + "..."


def cmd_list(args) -> int:
    from . import catalog
    from .filters import available

    rows = []
    for name in catalog.names():
        model = catalog.load(name)
        rows.append((name, model.kind, str(model.n), str(model.m),
                     ", ".join(available(model)), _short_source(model.source)))
    head = ("model", "kind", "n", "m", "filters", "source")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(5)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  source")
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[5])
    return 0


def cmd_show(args) -> int:
    import sympy

    model = _load(args.model)
    print(f"{model.name}: {model.kind} model, n = {model.n}, m = {model.m}")
    if model.description:
        print(textwrap.fill(model.description, 88))
    if model.source:
        print(f"source: {model.source}")
    print(f"states: {', '.join(model.states)}")
    print(f"measurements: {', '.join(model.measurements)}")
    print("values: " + (", ".join(f"{k} = {v}" for k, v in model.values.items()) or "none"))
    print("free parameters (p order): " + (", ".join(p.name for p in model.parameters)
                                           or "none"))
    mats = ("F", "G", "H", "Q", "R") if model.kind == "linear" else ("f", "h", "F_jacobian",
                                                                    "H_jacobian", "Q", "R")
    for k in mats:
        print(f"{k} =")
        print(textwrap.indent(sympy.pretty(getattr(model, k), use_unicode=False), "    "))
    return 0


def cmd_check(args) -> int:
    from . import catalog
    from .checks import run_checks

    names = catalog.names() if args.model in (None, "all") else [args.model]
    failed = 0
    for name in names:
        model = _load(name)
        for check in run_checks(model, steps=args.steps, seed=args.seed):
            print(check.line())
            failed += not check.passed
    if failed:
        raise VerificationError(f"{failed} equivalence check(s) failed")
    return 0


def cmd_reproduce(args) -> int:
    """The main job: list the catalog, then check, generate and verify every model."""
    cmd_list(args)
    print()
    args.model, args.steps, args.seed = "all", 500, 1
    return cmd_check(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="derive",
        description="Derive specialised, unrolled Python and C99 Kalman-family filters from "
                    "SymPy state-space models, with exact flop counts.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  derive list\n  derive check mpt3d_a",
    )
    parser.add_argument("--version", action="version", version=f"derive {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def add(name, func, help_, example):
        p = sub.add_parser(name, help=help_, description=help_,
                           epilog=f"example:\n  {example}",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        p.set_defaults(func=func)
        return p

    add("list", cmd_list, "list the catalog models with n, m and the filters available",
        "derive list")
    p = add("show", cmd_show, "print a model's matrices, values and free parameters",
            "derive show cv")
    p.add_argument("model", help="catalog name or model-file path")
    p = add("check", cmd_check,
            "run the NumPy reference filters on simulated data and print the papers' "
            "equivalence checks", "derive check mpt3d_a")
    p.add_argument("model", nargs="?", default="all", help="catalog name, path, or 'all'")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--seed", type=int, default=1)
    add("reproduce", cmd_reproduce,
        "the main job: regenerate, verify and report the seed catalog", "derive reproduce")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ModelError as exc:
        print(f"derive: error: {exc}", file=sys.stderr)
        return 2
    except (VerificationError, NumericalError) as exc:
        print(f"derive: verification failed: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
