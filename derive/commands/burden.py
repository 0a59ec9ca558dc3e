"""`derive burden MODEL [--filter F] [--paper] [--json]`: exact operation counts by kind;
`derive burden [MODEL] --formula --filter F [--paper | --family dense|blocks]`: the polynomial
in the sizes that the counts obey, derived by exact interpolation."""

from . import add_filter_options

NAME = "burden"
ORDER = 50
HELP = ("exact operation counts of the generated code, by kind, per filter and language "
        "(--paper: also the papers' dense algorithm; --formula: the polynomial in n, m they "
        "obey)")
EXAMPLE = ("derive burden mpt3d_a --filter kf\n  derive burden cv --paper --json\n"
           "  derive burden --formula --paper --filter kf\n"
           "  derive burden mpt3d_b --formula --family blocks --filter kf")

KINDS = ("add", "sub", "mul", "div", "sqrt", "fma", "neg", "cmp", "select", "calls")


def add_fit_arguments(parser) -> None:
    """The arguments of a derived formula (derive.apps.burden_formula), for burden and audit."""
    parser.add_argument("--family", choices=("dense", "blocks"), default=None,
                        help="with --formula and without --paper: derive's specialised code on "
                             "dense random n x m models (default) or on k copies of MODEL "
                             "(blocks)")
    parser.add_argument("--degree", type=int, default=3, metavar="D",
                        help="first bound on the total degree of the fit (default 3)")
    parser.add_argument("--max-degree", type=int, default=5, metavar="D",
                        help="highest bound tried while a check size disagrees (default 5, "
                             "at most 6)")
    parser.add_argument("--check", action="append", metavar="SIZES",
                        help="repeatable: a size the fit must reproduce, not used to fit it, "
                             "as comma-separated integers in the family's variables (n,m; "
                             "N,n,m for the FIR; k for blocks); default: 5,5 6,3 12,6 (FIR: "
                             "7,3,2 4,6,3 9,2,5; blocks: 8 11)")
    parser.add_argument("--from", dest="minimum", type=int, default=1, metavar="S",
                        help="fit on sizes >= S only (default 1)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the dense random models (default 0)")


def check_sizes(args):
    """``--check`` as tuples of ints (None: the family's default)."""
    from ..errors import ModelError

    if not args.check:
        return None
    out = []
    for text in args.check:
        try:
            out.append(tuple(int(part) for part in text.split(",")))
        except ValueError:
            raise ModelError(f"--check {text!r}: expected comma-separated integers, e.g. "
                             "12,6") from None
    return out


def formula_family(args, name: str, model):
    """The family --formula derives for filter ``name``: paper mode, dense models, or
    copies of ``model`` (the filter options of the call for derive's specialised code)."""
    from ..apps import burden_formula
    from ..errors import ModelError
    from ..options import from_arguments, per_filter

    family = "paper" if args.paper else (args.family or "dense")
    if args.paper and args.family:
        raise ModelError("--paper is a family of its own: give --paper or --family, not both")
    if family == "blocks" and model is None:
        raise ModelError("--family blocks needs MODEL: the block it copies k times")
    if family != "blocks" and model is not None:
        raise ModelError(f"the {family} family takes no MODEL (its sizes are the variables); "
                         "MODEL is the block of --family blocks")
    options = from_arguments(args)
    if family == "paper" and options:
        raise ModelError("paper mode takes no filter options (its algorithm is the papers'); "
                         f"got {', '.join(sorted(options))}")
    if family == "dense" and name == "fir" and {"order", "eps"} & set(options):
        raise ModelError("the FIR's order N is a variable of its dense family: give no "
                         "--order or --eps")
    per_filter([name], options, named=True)  # refuses an option the filter does not take
    return burden_formula.family(name, family, model, options, args.seed)


def refuse_fit_arguments(args, applies: str) -> None:
    """A fit's arguments given without --formula: refused, not ignored."""
    from ..errors import ModelError

    given = [flag for flag, on in (
        ("--family", args.family is not None), ("--degree", args.degree != 3),
        ("--max-degree", args.max_degree != 5), ("--check", bool(args.check)),
        ("--from", args.minimum != 1), ("--seed", args.seed != 0)) if on]
    if given:
        raise ModelError(f"{given[0]} applies to {applies} only")


def derive_args(args) -> dict:
    return {"degree": args.degree, "max_degree": args.max_degree,
            "check": check_sizes(args), "minimum": args.minimum}


def add_arguments(parser) -> None:
    parser.add_argument("model", nargs="?", default=None,
                        help="catalog name or model-file path (with --formula: the block of "
                             "--family blocks)")
    parser.add_argument("--filter", action="append", dest="filters", metavar="F",
                        help="repeatable; default: every filter that applies")
    parser.add_argument("--paper", action="store_true",
                        help="add the paper-mode rows: the dense, unspecialised filter exactly "
                             "as the papers count it")
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--measure", action="store_true",
                        help="chains in ns with operation latencies measured here (needs gcc) "
                             "instead of the reference cycle counts")
    parser.add_argument("--formula", action="store_true",
                        help="derive the polynomial the step's counts obey, by kind and in "
                             "flops, by exact interpolation over sizes (needs --filter)")
    add_fit_arguments(parser)
    add_filter_options(parser)


def units(model, filters, options: dict):
    """``[(filter, Unit)]`` of ``filters`` (default: all that apply) with the options of
    the call (each filter given those it takes, as `derive generate` does)."""
    from ..filters import available, check_before_deriving, derive_unit, kind
    from ..options import per_filter

    names = list(filters) if filters else available(model)
    for name in names:
        kind(name)
    typed = per_filter(names, options, named=bool(filters))
    check_before_deriving(model, names, typed, named=bool(filters))
    return [(name, derive_unit(model, name, typed[name])) for name in names]


def _rows(filter_name: str, mode: str, unit, formula) -> list[dict]:
    from ..flops import count

    rows = []
    for program_name, program in unit.programs.items():
        for lang in ("python", "c"):
            n = count(program, lang)
            rows.append({"filter": filter_name, "mode": mode, "program": program_name,
                         "lang": lang, **n.as_dict(), "flops": n.flops,
                         "instructions": n.instructions,
                         "papers": formula if program_name == "step" else None})
    return rows


def _formula(name: str, unit):
    from ..apps import formulas

    if name == "fir":
        return formulas.fir(unit.window, unit.n, unit.m)
    if name in formulas.FORMULAS:
        return formulas.burden(name, unit.n, unit.m)
    return None


def burden_rows(model, derived: list, paper: bool) -> list[dict]:
    """One row per (filter, mode, program, language) of the ``derived`` ``[(filter,
    Unit)]``: counts by kind, flops, instructions and the papers' formula for the step
    (None where the papers give none)."""
    from ..apps import paper as paper_mode

    rows = []
    for name, unit in derived:
        rows += _rows(name, "specialised", unit, _formula(name, unit))
        if paper and name in paper_mode.PAPER_FILTERS:
            punit = paper_mode.model_unit(model, name, N=unit.window if name == "fir" else
                                          unit.options.get("horizon"))
            rows += _rows(name, "paper", punit, _formula(name, punit))
    return rows


def chain_rows(derived: list, latency: dict | None = None) -> list[dict]:
    """Per filter of ``derived`` ``[(filter, Unit)]`` (in their default schedule): the
    carried chain of its generated C run loop (derive.apps.latency), per step, in the
    units of ``latency`` (default: derive.apps.latency.REFERENCE_CYCLES); and the same in
    the latency schedule (derive.schedule) with the flops per step it adds (None where it
    does not apply)."""
    from ..apps.latency import REFERENCE_CYCLES, schedule_bounds

    rows = []
    for name, unit in derived:
        both = schedule_bounds(unit, latency or REFERENCE_CYCLES)
        bound, fast = both.default, both.latency
        rows.append({"filter": name, "steps_per_pass": 1 if bound is None else bound.steps,
                     "per_step": None if bound is None else bound.per_step,
                     "operations_per_pass": None if bound is None else dict(bound.operations),
                     "chain": None if bound is None else bound.describe(),
                     "latency_schedule_note": both.note or None,
                     "latency_schedule": None if fast is None else {
                         "per_step": fast.per_step, "chain": fast.describe(),
                         "operations_per_pass": dict(fast.operations),
                         "flops_added": both.flops_added}})
    return rows


def _chain_text(rows: list[dict], measured: bool) -> list[str]:
    from ..apps.latency import REFERENCE_CYCLES

    unit = "ns" if measured else "cycles"
    model = ("operation latencies measured here" if measured else "reference latencies in "
             "cycles: " + ", ".join(f"{k} {v:g}" for k, v in REFERENCE_CYCLES.items()))
    lines = ["", f"carried chain of the C run loop, per step ({model}): the bound on the time "
                 "per step however wide the core; default schedule, then the latency schedule "
                 "(--latency-schedule) and the flops per step it adds"]
    scale = 1e9 if measured else 1
    for r in rows:
        if r["per_step"] is None:
            lines.append(f"  {r['filter']}: no carried state")
            continue
        lines.append(f"  {r['filter']}: {r['per_step'] * scale:.3g} {unit} ({r['chain']})")
        fast = r["latency_schedule"]
        if r["latency_schedule_note"]:
            lines.append(f"  {r['filter']}: {r['latency_schedule_note']}")
        if fast is not None:
            ratio = fast["per_step"] / r["per_step"]
            lines.append(f"  {r['filter']} --latency-schedule: {fast['per_step'] * scale:.3g} "
                         f"{unit} ({fast['chain']}; {ratio:.2f}x the default's), "
                         f"{fast['flops_added']:+d} flops per step")
    return lines


def _text(model, rows: list[dict]) -> str:
    head = ["filter", "mode", "program", "lang", *KINDS, "flops", "instr", "papers"]
    body = [[r["filter"], r["mode"], r["program"], r["lang"], *(str(r[k]) for k in KINDS),
             str(r["flops"]), str(r["instructions"]),
             "-" if r["papers"] is None else str(r["papers"])] for r in rows]
    widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i < 4 else '>'}{w}}}" for i, w in enumerate(widths))
    lines = [f"{model.name}: n = {model.n}, m = {model.m}. Operations per call of the generated "
             "code, counted on what is emitted.",
             "flops = add + sub + mul + div + sqrt + 2 fma (an fma: 2 flops, 1 instruction); "
             "neg, cmp, select and calls are not flops; instr = every operation but calls.",
             "papers: the papers' burden formula for this n, m (MPT3D Tables 2-3); mode paper: "
             "derive's dense, unspecialised code as the papers count it.", "",
             fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in body]
    return "\n".join(lines)


def run_formula(args) -> int:
    import json

    from ..apps import burden_formula
    from ..errors import ModelError
    from . import load_model

    if not args.filters:
        raise ModelError("--formula needs --filter F (repeatable): the filter whose formula "
                         "is derived")
    if args.measure:
        raise ModelError("--measure applies to the chains of derive burden MODEL, not to "
                         "--formula")
    model = load_model(args.model) if args.model is not None else None
    derived = [burden_formula.derive_formula(formula_family(args, name, model),
                                             **derive_args(args)) for name in args.filters]
    if args.json:
        print(json.dumps([burden_formula.derived_json(d) for d in derived], indent=2))
    else:
        print("\n\n".join("\n".join(burden_formula.formula_lines(d)) for d in derived))
    return 0


def run(args) -> int:
    import json

    from ..errors import ModelError
    from ..options import from_arguments
    from . import load_model

    if args.formula:
        return run_formula(args)
    refuse_fit_arguments(args, "--formula")
    if args.model is None:
        raise ModelError("derive burden needs MODEL (a catalog name or model-file path), or "
                         "--formula")
    model = load_model(args.model)
    derived = units(model, args.filters, from_arguments(args))
    rows = burden_rows(model, derived, args.paper)
    latency = None
    if args.measure:
        from ..apps.bench.generated import CFLAGS
        from ..apps.bench.machine.probe import measure_latencies

        latency = measure_latencies(CFLAGS)
    options = from_arguments(args)
    plain = derived if not options.get("latency_schedule") else units(
        model, args.filters, {**options, "latency_schedule": False})   # chains: both schedules
    chains = chain_rows(plain, latency)
    if args.json:
        print(json.dumps({"model": model.name, "n": model.n, "m": model.m, "rows": rows,
                          "chains": chains, "chain_unit": "s" if latency else "cycles"},
                         indent=2))
    else:
        print("\n".join([_text(model, rows), *_chain_text(chains, latency is not None)]))
    return 0
