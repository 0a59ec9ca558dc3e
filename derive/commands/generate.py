"""`derive generate MODEL --filter F ... --lang L --out DIR` (or `--all` for the catalog).

The filter options' flags come from their declarations (derive.options); each option
given applies to the filters that take it."""

from functools import partial

from . import add_filter_options

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
                        help="a filter name, as `derive list` shows them (repeatable; "
                             "default: all that apply)")
    parser.add_argument("--lang", default="all", choices=("python", "c", "all"),
                        help="which code to write: python, c, or all (default)")
    parser.add_argument("--out", default="generated", help="output directory (generated)")
    parser.add_argument("--layout", default="files", choices=("files", "library"),
                        help="files: the filters' files (default); library: their C with a "
                             "test program per filter, a CMakeLists.txt and a Makefile "
                             "(docs/embedded.md)")
    add_filter_options(parser)


def horizon_line(unit, options: dict) -> str | None:
    """``  fir: order N = 33 ...`` for a FIR or a predictor (None for other filters), given
    the options of the command line."""
    from ..options import DEFAULT_EPS  # here, not at the top: `derive` starts without NumPy

    if unit.run.window:
        rule = (" (--order)" if "order" in options else
                f", the least with ||A^N||_2 < {options.get('eps', DEFAULT_EPS)!r}")
        return f"  {unit.filter}: order N = {unit.window}{rule}"
    if "horizon" in unit.options:
        return f"  {unit.filter}: horizon N = {unit.options['horizon']}"
    return None


def run(args) -> int:
    from .. import catalog
    from ..errors import FilterError
    from ..generation import generate_summaries
    from ..options import from_arguments

    if args.all == bool(args.model):
        raise FilterError("give a MODEL or --all (not both)")
    options = from_arguments(args)
    refs = catalog.names() if args.all else [args.model]
    total = 0
    for ref in refs:
        if args.layout == "library":
            from ..apps.targets.library import generate_library

            if args.lang == "python":
                raise FilterError("--layout library writes C (with its build files and test "
                                  "programs); --lang python does not apply")
            paths, units = generate_library(ref, args.filters, args.out, options)
            lines = [horizon_line(unit, options) for unit in units]
        else:
            paths, lines = generate_summaries(ref, args.filters, args.lang, args.out, options,
                                              summary=partial(horizon_line, options=options))
        total += len(paths)
        print(f"{ref}: {len(paths)} files in {paths[0].parent if paths else args.out}")
        for line in lines:
            if line:
                print(line)
    print(f"wrote {total} files")
    return 0
