"""Real GPS data for the GNSS filters (the GNSS paper): RINEX 3 reading, broadcast ephemerides,
atmospheric corrections, least-squares fixes and a driver for scalar-update filters.

The data set comes from the optional package gnss-benchmark 2.3.0; everything else here
needs only NumPy. `python -m derive.apps.gnss` prints the real-data table.
"""

from derive.apps.gnss.errors import GnssDataError
from derive.apps.gnss.lsq import LsqFix, least_squares_fix
from derive.apps.gnss.measurements import CorrectionOptions, Epoch, bootstrap_fix, prepare_epoch
from derive.apps.gnss.run import (
    REPORT_TIMES,
    FilterSettings,
    RealRunResult,
    Track,
    drive,
    numpy_filters,
    run_real,
)
from derive.apps.gnss.scalar_updates import (
    ScalarEkf,
    ScalarUkf,
    ScalarUpdate,
    ekf_predict,
    ekf_update1,
    ukf_update1,
)

__all__ = [
    "REPORT_TIMES",
    "CorrectionOptions",
    "Epoch",
    "FilterSettings",
    "GnssDataError",
    "LsqFix",
    "RealRunResult",
    "ScalarEkf",
    "ScalarUkf",
    "ScalarUpdate",
    "Track",
    "bootstrap_fix",
    "drive",
    "ekf_predict",
    "ekf_update1",
    "least_squares_fix",
    "numpy_filters",
    "prepare_epoch",
    "run_real",
    "ukf_update1",
]
