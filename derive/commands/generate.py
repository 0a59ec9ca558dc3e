"""`derive generate MODEL --filter F ... --lang L --out DIR` (or `--all` for the catalog)."""

NAME = "generate"
ORDER = 40
HELP = "generate specialised Python and C99 filters for a model (or the whole catalog)"
EXAMPLE = ("derive generate mpt3d_a --filter kf --filter sskf --lang c --out generated\n"
           "  derive generate --all")


def add_arguments(parser) -> None:
    parser.add_argument("model", nargs="?", help="catalog name or model-file path")
    parser.add_argument("--all", action="store_true",
                        help="every catalog model with every filter that applies")
    parser.add_argument("--filter", action="append", dest="filters", metavar="F",
                        help="kf, lf, jklf, ikf, sskf, sslf, jssklf, fir, pred, ekf, ukf "
                             "(repeatable; default: all that apply)")
    parser.add_argument("--lang", default="all", choices=("python", "c", "all"))
    parser.add_argument("--out", default="generated", help="output directory (generated)")
    parser.add_argument("--eps", type=float, default=None,
                        help="FIR: order N is the least with ||A^N||_2 < eps (1e-6)")
    parser.add_argument("--order", type=int, default=None, help="FIR: order N directly")
    parser.add_argument("--horizon", type=int, default=None, help="pred: steps ahead N (1)")
    parser.add_argument("--joseph", action="store_true", help="KF: Joseph-form update")
    parser.add_argument("--missing", action="store_true",
                        help="kf, lf, jklf, ikf: a NaN in z skips that measurement")
    parser.add_argument("--alpha", type=float, default=None, help="UKF sigma-point alpha (1)")
    parser.add_argument("--beta", type=float, default=None, help="UKF sigma-point beta (0)")
    parser.add_argument("--kappa", type=float, default=None,
                        help="UKF sigma-point kappa (3 - n: the paper's n + kappa = 3)")
    parser.add_argument("--no-run-tracks", dest="run_tracks", action="store_false",
                        help="C: leave out MODEL_FILTER_run_tracks (smaller files)")
    parser.add_argument("--P0-pattern", dest="P0_pattern", default=None,
                        choices=("dense", "zero", "diagonal", "block"),
                        help="declared sparsity of P0 (default: the model's)")


def options_from(args) -> tuple[dict, dict]:
    """(options for every filter, per-filter options) from the parsed arguments."""
    common = {}
    if args.joseph:
        common["joseph"] = True
    if args.P0_pattern:
        common["P0_pattern"] = args.P0_pattern
    if not args.run_tracks:
        common["run_tracks"] = False
    per = {"fir": {}, "pred": {}, "ukf": {}}
    if args.missing:
        from ..filters.common import MISSING_FILTERS

        for name in MISSING_FILTERS:
            per.setdefault(name, {})["missing"] = True
    for key in ("alpha", "beta", "kappa"):
        if getattr(args, key) is not None:
            per["ukf"][key] = getattr(args, key)
    if args.eps is not None:
        per["fir"]["eps"] = args.eps
    if args.order is not None:
        per["fir"]["N"] = args.order
    if args.horizon is not None:
        per["pred"]["N"] = args.horizon
    return common, per


def run(args) -> int:
    from .. import catalog
    from ..errors import FilterError
    from ..generation import generate

    if args.all == bool(args.model):
        raise FilterError("give a MODEL or --all (not both)")
    common, per = options_from(args)
    if args.missing and args.filters:
        from ..filters.common import MISSING_FILTERS

        bad = [f for f in args.filters if f not in MISSING_FILTERS]
        if bad:
            raise FilterError(f"--missing applies to {', '.join(MISSING_FILTERS)}, not to "
                              f"{', '.join(bad)}")
    refs = catalog.names() if args.all else [args.model]
    total = 0
    for ref in refs:
        paths = generate(ref, args.filters, args.lang, args.out, common, per)
        total += len(paths)
        print(f"{ref}: {len(paths)} files in {paths[0].parent if paths else args.out}")
    print(f"wrote {total} files")
    return 0
