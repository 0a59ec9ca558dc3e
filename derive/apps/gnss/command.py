"""The command `python -m derive.apps.gnss` (and `derive gnss --real`): run the filters on the
real data and print the error table.

--implementation c (default) or python runs derive's generated EKF and UKF
(derive.apps.gnss.generated) and checks them against the NumPy stand-ins of
derive.apps.gnss.scalar_updates on the same epochs; numpy runs the stand-ins only."""

from __future__ import annotations

import argparse
import sys

from derive.apps.gnss.measurements import CorrectionOptions
from derive.apps.gnss.run import FilterSettings
from derive.errors import ModelError, NumericalError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of the gnss command."""
    d = FilterSettings()
    parser.add_argument("--epochs", type=int, default=None,
                        help="use only the first N epochs (default: all 1200)")
    parser.add_argument("--mask", type=float, default=CorrectionOptions().elevation_mask_deg,
                        help="elevation mask, degrees (default %(default)s)")
    parser.add_argument("--no-iono", action="store_true", help="skip the Klobuchar correction")
    parser.add_argument("--no-tropo", action="store_true",
                        help="skip the Saastamoinen correction")
    parser.add_argument("--sigma", type=float, default=d.sigma,
                        help="pseudorange std, m (default %(default)s)")
    parser.add_argument("--q-position", type=float, default=d.q_position,
                        help="position random-walk variance per epoch, m² (default %(default)s)")
    parser.add_argument("--q-clock", type=float, default=d.q_clock,
                        help="clock random-walk variance per epoch, m² (default %(default)s)")
    parser.add_argument("--kappa", type=float, default=None,
                        help="UKF kappa (default 3 - n = -1)")
    parser.add_argument("--obs", default=None, help="another RINEX 3 observation file")
    parser.add_argument("--nav", default=None, help="another RINEX 3 navigation file")
    parser.add_argument("--implementation", choices=("c", "python", "numpy"), default="c",
                        help="generated C (default) or Python filters, or the NumPy "
                             "stand-ins only")


def _filters(settings, implementation: str):
    """(filters for run_real, note) for --implementation; C falls back to Python when
    it cannot be built."""
    from derive.apps.gnss.generated import generated_filters

    if implementation == "numpy":
        return None, ""
    if implementation == "c":
        from derive.build import BuildError

        try:
            return generated_filters(settings, "c"), ""
        except BuildError as exc:
            note = f"note: C build failed ({str(exc).splitlines()[0]}); generated Python used"
            return generated_filters(settings, "python"), note
    return generated_filters(settings, "python"), ""


def run_command(args: argparse.Namespace) -> int:
    """Print the table of run_real for parsed arguments; 0 on success."""
    from dataclasses import replace

    import numpy as np

    from derive.apps.gnss.data import load_real_data
    from derive.apps.gnss.run import numpy_filters, run_real

    settings = FilterSettings(sigma=args.sigma, q_position=args.q_position,
                              q_clock=args.q_clock, kappa=args.kappa)
    corrections = CorrectionOptions(args.mask, troposphere=not args.no_tropo,
                                    ionosphere=not args.no_iono)
    data = load_real_data(args.epochs, args.obs, args.nav)
    implementation = getattr(args, "implementation", "numpy")
    generated, note = _filters(settings, implementation)
    if note:
        print(note, file=sys.stderr)
    if generated is None:
        print(run_real(settings=settings, corrections=corrections, data=data).table())
        return 0
    stand_ins = {f"{name} numpy": pair for name, pair in numpy_filters(settings).items()}
    result = run_real({**generated, **stand_ins}, settings=settings, corrections=corrections,
                      data=data)
    shown = replace(result, tracks={name: result.tracks[name] for name in generated})
    print(shown.table())
    lang = "C" if implementation == "c" and not note else "Python"
    gaps = []
    for name in generated:
        gap = np.abs(result.tracks[name].states - result.tracks[f"{name} numpy"].states)
        gaps.append(f"{name} {gap.max():.1e} m")
    print(f"filters: derive's generated {lang} code; largest state difference from the NumPy "
          f"stand-ins (derive.apps.gnss.scalar_updates) over all epochs: {', '.join(gaps)}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m derive.apps.gnss", description=__doc__)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_command(args)
    except (ModelError, ModuleNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except NumericalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
