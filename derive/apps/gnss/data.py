"""The real data set: a static reference station's RINEX 3 files shipped by the PyPI
package gnss-benchmark 2.3.0 (install with `pip install --no-deps gnss-benchmark==2.3.0`).

MARE (ICGC, Leica GR50, near Barcelona), 2020-11-29 12:40:00–12:59:59 GPST at 1 Hz, the
broadcast navigation file CARD…_15H_MN.rnx and CODE's precise orbits COD21340.sp3.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from derive.apps.gnss.corrections import ecef_to_geodetic
from derive.apps.gnss.errors import GnssDataError
from derive.apps.gnss.rinex import (
    GpsNavigation,
    GpsObservations,
    read_gps_navigation,
    read_gps_observations,
)
from derive.apps.simulate import enu_basis

DATASET = "mosaicx5_multi_dynamic"
OBSERVATION_FILE = "MARE00ESP_R_20203341240_20M_01S_MO.rnx"
NAVIGATION_FILE = "CARD00ESP_R_20203340900_15H_MN.rnx"
PRECISE_ORBIT_FILE = "COD21340.sp3"
INSTALL_HINT = "pip install --no-deps gnss-benchmark==2.3.0"


def dataset_file(name: str) -> Path:
    """Path of a file of the gnss-benchmark data set `DATASET`."""
    try:
        root = resources.files("gnss_benchmark")
    except ModuleNotFoundError:
        raise ModuleNotFoundError(
            f"the real GNSS data come from the package gnss-benchmark; install it with "
            f"`{INSTALL_HINT}`", name="gnss_benchmark") from None
    path = Path(str(root.joinpath("datasets", DATASET, name)))
    if not path.is_file():
        raise GnssDataError(f"{name} is not in the installed gnss-benchmark ({path}); "
                            f"need version 2.3.0")
    return path


def antenna_reference_point(obs: GpsObservations) -> np.ndarray:
    """APPROX POSITION XYZ (the marker) plus ANTENNA: DELTA H/E/N turned into ECEF: the
    point the pseudoranges refer to (the antenna's phase-centre offset is not applied)."""
    lat, lon, _ = ecef_to_geodetic(obs.approx_position)
    up_east_north = enu_basis(lat, lon)[[2, 0, 1]]
    return obs.approx_position + obs.antenna_delta_hen @ up_east_north


@dataclass(frozen=True)
class RealData:
    """Observations, navigation data and the true antenna position (ECEF m)."""

    observations: GpsObservations
    navigation: GpsNavigation
    truth: np.ndarray


def load_real_data(max_epochs: int | None = None, observation_path=None,
                   navigation_path=None, code: str = "C1C") -> RealData:
    """Read the data set (or the given RINEX 3 files); truth = antenna_reference_point."""
    obs = read_gps_observations(observation_path or dataset_file(OBSERVATION_FILE), code,
                                max_epochs)
    nav = read_gps_navigation(navigation_path or dataset_file(NAVIGATION_FILE))
    return RealData(obs, nav, antenna_reference_point(obs))
