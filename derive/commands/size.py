"""`derive size MODEL [--filter F] [--target cortex-m4] [--qemu]` (or `--all`): the generated
C cross-compiled for a microcontroller, its code and data size per function read from the
object; with ``--qemu``, also built for arm-linux-gnueabihf, run under qemu-arm and compared
with the NumPy reference."""

from . import add_filter_options

NAME = "size"
ORDER = 65
HELP = ("cross-compile generated C for ARM (Cortex-M4F): code and data bytes per function "
        "at -Os and -O2, float and double (or --precision); --qemu: run it under qemu-arm "
        "against the reference")
EXAMPLE = "derive size mpt3d_a --filter kf\n  derive size --all --qemu"


def add_arguments(parser) -> None:
    parser.add_argument("model", nargs="?", help="catalog name or model-file path")
    parser.add_argument("--all", action="store_true",
                        help="every catalog model with every filter that applies")
    parser.add_argument("--filter", action="append", dest="filters", metavar="F",
                        help="a filter name (repeatable; default: all that apply)")
    parser.add_argument("--target", default="cortex-m4", choices=("cortex-m4", "arm-linux"),
                        help="cortex-m4 (arm-none-eabi-gcc, default) or arm-linux "
                             "(arm-linux-gnueabihf-gcc)")
    parser.add_argument("--level", action="append", dest="levels", metavar="OX",
                        choices=("Os", "O2", "O3", "O1", "O0"),
                        help="optimisation level, as gcc's -OX without the dash (repeatable; "
                             "default: Os and O2)")
    parser.add_argument("--qemu", action="store_true",
                        help="also run each filter under qemu-arm (arm-linux-gnueabihf, "
                             "static) on the verification data and compare with the "
                             "reference")
    add_filter_options(parser)


def run(args) -> int:
    from .. import catalog
    from ..apps.targets.arm import run_under_qemu, size_table, sizes
    from ..apps.targets.data import require_examples
    from ..apps.targets.toolchains import SIZE_LEVELS, TARGETS
    from ..errors import FilterError, VerificationError
    from ..generation import resolve_model
    from ..options import from_arguments

    if args.all == bool(args.model):
        raise FilterError("give a MODEL or --all (not both)")
    options = from_arguments(args)
    refs = catalog.names() if args.all else [args.model]
    levels = tuple(f"-{v}" for v in args.levels) if args.levels else SIZE_LEVELS
    target = TARGETS[args.target]
    if args.qemu:   # the runs need every free parameter's example: before any work
        for ref in refs:
            require_examples(resolve_model(ref))
    target.require()   # every tool named before any work
    if args.qemu:
        TARGETS["arm-linux"].require(run=True)
    print(f"{target.name}: {target.cc} {' '.join(target.flags)} (bytes read from each object "
          f"by {target.size} and {target.nm} --size-sort -S)")
    # both precisions unless --precision names one: float32 is what a Cortex-M4F's FPU runs
    precisions = [options["precision"]] if "precision" in options else ["float", "double"]
    rows = [row for ref in refs for p in precisions
            for row in sizes(ref, args.filters, {**options, "precision": p}, args.target,
                             levels)]
    print(size_table(rows))
    if not args.qemu:
        return 0
    runs = []
    for ref in refs:
        for p in precisions:
            for r in run_under_qemu(ref, args.filters, {**options, "precision": p}):
                print(r.line(), flush=True)
                runs.append(r)
    failed = [r for r in runs if not r.passed]
    if failed:
        raise VerificationError(f"{len(failed)} of {len(runs)} runs under qemu-arm failed "
                                f"(beyond the tolerance, or a float32 bound of 1 or more): "
                                f"{failed[0].line()}")
    return 0
