"""`derive audit [--json]`: the papers' burden numbers against formulas and generated code."""

NAME = "audit"
ORDER = 55
HELP = ("audit the papers' burden numbers: printed, formula, derive's paper-mode code and "
        "derive's specialised code; flags, speedups, FIR order and break-even interval")
EXAMPLE = "derive audit\n  derive audit --json"


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print JSON")


def run(args) -> int:
    import json

    from ..apps.audit import as_json, run_audit, text

    audit = run_audit()
    if args.json:
        print(json.dumps(as_json(audit), indent=2))
    else:
        print(text(audit), end="")
    return 0
