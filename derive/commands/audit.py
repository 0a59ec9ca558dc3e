"""`derive audit [--json]`: the papers' burden numbers against formulas and generated code;
`derive audit --formula EXPR --filter F [--paper] [--model MODEL]`: any burden formula against
the one derived from derive's generated code."""

from .burden import add_fit_arguments, refuse_fit_arguments

NAME = "audit"
ORDER = 55
HELP = ("audit the papers' burden numbers: printed, formula, derive's paper-mode code and "
        "derive's specialised code; flags, speedups, FIR order and break-even interval "
        "(--formula EXPR: audit any burden formula)")
EXAMPLE = ('derive audit\n  derive audit --json\n'
           '  derive audit --formula "2*n**2 + 2*n*m - n" --filter sskf --paper\n'
           '  derive audit --formula "2*n**2 + 2*n*m - n" --filter sskf --model cv')


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--formula", metavar="EXPR",
                        help="a burden formula in n, m (N: the FIR's order; k: copies, with "
                             "--family blocks), e.g. \"2*n**2 + 2*n*m - n\"; parsed, never "
                             "executed (one that starts with '-': --formula='-n + ...'). "
                             "Exit 1 where it differs from the derived one")
    parser.add_argument("--filter", dest="filter_name", metavar="F",
                        help="with --formula: the filter the formula claims to count")
    parser.add_argument("--paper", action="store_true",
                        help="with --formula: against derive's paper mode (the dense, "
                             "unspecialised algorithm), not derive's specialised code")
    parser.add_argument("--model", metavar="MODEL",
                        help="with --formula: a catalog name or model file fixing n and m "
                             "(the formula's value against the count of the code for it); "
                             "with --family blocks: the block")
    parser.add_argument("--kind", default="flops", metavar="SERIES",
                        help="with --formula: what it counts: flops (the papers' convention, "
                             "an fma two; default) or LANG.KIND, e.g. python.mul, c.fma")
    add_fit_arguments(parser)


def run_formula(args) -> int:
    import json

    from ..apps import burden_formula
    from ..errors import ModelError
    from . import load_model
    from .burden import derive_args, formula_family

    if not args.filter_name:
        raise ModelError("--formula needs --filter F: the filter the formula claims to count")
    if args.kind not in burden_formula.SERIES:
        raise ModelError(f"--kind {args.kind!r}: expected one of "
                         f"{', '.join(burden_formula.SERIES)}")
    model = load_model(args.model) if args.model is not None else None
    if model is not None and args.family != "blocks":
        check = burden_formula.audit_at_model(
            args.formula, args.filter_name, model, "paper" if args.paper else "dense",
            series=args.kind)
        what = "derive's paper-mode code" if args.paper else "derive's specialised code"
        if args.json:
            print(json.dumps({"formula": args.formula, "model": check.model,
                              "sizes": check.sizes, "series": args.kind,
                              "formula_value": str(check.claim), "count": check.count,
                              "equal": check.equal}, indent=2))
        else:
            sizes = ", ".join(f"{k} = {v}" for k, v in check.sizes.items())
            print(f"formula ({burden_formula.series_title(args.kind)}): {args.formula}\n"
                  f"{check.model} ({sizes}): the formula gives {check.claim}; {what} for it "
                  f"counts {check.count}: "
                  + ("equal" if check.equal else f"differs by {check.claim - check.count}"))
        return 0 if check.equal else 1
    family = formula_family(args, args.filter_name, model)
    check = burden_formula.audit_formula(args.formula, family, args.kind, **derive_args(args))
    if args.json:
        print(json.dumps(burden_formula.check_json(check), indent=2))
    else:
        print("\n".join(burden_formula.check_lines(check)))
    return 0 if check.equal else 1


def run(args) -> int:
    import json

    from ..errors import ModelError

    if args.formula is not None:
        return run_formula(args)
    given = [flag for flag, on in (("--filter", args.filter_name), ("--paper", args.paper),
                                   ("--model", args.model), ("--kind", args.kind != "flops"))
             if on]
    if given:
        raise ModelError(f"{given[0]} applies to --formula EXPR only")
    refuse_fit_arguments(args, "--formula EXPR")

    from ..apps.audit import as_json, run_audit, text

    audit = run_audit()
    if args.json:
        print(json.dumps(as_json(audit), indent=2))
    else:
        print(text(audit), end="")
    return 0
