"""From RINEX records to filter inputs: per epoch, the satellites above the elevation mask,
their ECEF positions in the frame of reception, and corrected pseudoranges

    ρ_corr = C1C + c·Δt_sv − T − I,   modelled as   ρ_corr = ||s − r|| + b

(Δt_sv: broadcast clock with relativistic term and TGD; T: Saastamoinen troposphere;
I: Klobuchar ionosphere). Sagnac rotation, elevations and delays use one approximate
receiver position, which moves them by millimetres per 10 m of its error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.gnss.constants import SPEED_OF_LIGHT
from derive.apps.gnss.corrections import (
    ecef_to_geodetic,
    elevation_azimuth,
    klobuchar_delay,
    troposphere_delay,
)
from derive.apps.gnss.ephemeris import sagnac, transmission_state
from derive.apps.gnss.errors import GnssDataError
from derive.apps.gnss.lsq import LsqFix, least_squares_fix
from derive.apps.gnss.rinex import GpsNavigation, GpsObservations

_NEAR_SURFACE = 6.0e6   # m from the Earth's centre: below this a position is "not yet known"


@dataclass(frozen=True)
class CorrectionOptions:
    """Elevation mask (deg) and which atmospheric delays to remove."""

    elevation_mask_deg: float = 10.0
    troposphere: bool = True
    ionosphere: bool = True


@dataclass(frozen=True)
class Epoch:
    """One epoch's filter input. t: receiver time tag (continuous GPS s); prns (sorted);
    satellites (m, 3) ECEF m in the frame of reception; pseudoranges (m,) corrected, m;
    elevations_deg (m,); troposphere, ionosphere (m,): the delays removed, m."""

    t: float
    prns: tuple[str, ...]
    satellites: np.ndarray
    pseudoranges: np.ndarray
    elevations_deg: np.ndarray
    troposphere: np.ndarray
    ionosphere: np.ndarray


def prepare_epoch(obs: GpsObservations, nav: GpsNavigation, k: int, receiver,
                  options: CorrectionOptions = CorrectionOptions()) -> Epoch:
    """Epoch k of `obs` with the approximate receiver position `receiver` (ECEF m). While
    the receiver is not yet near the Earth's surface (|r| < 6000 km, e.g. the Earth's
    centre at a cold start) no mask and no atmospheric delays are applied."""
    receiver = np.asarray(receiver, dtype=float).reshape(3)
    known = np.linalg.norm(receiver) > _NEAR_SURFACE
    lat, lon, height = ecef_to_geodetic(receiver) if known else (0.0, 0.0, 0.0)
    t = float(obs.times[k])
    rows = []
    for prn, raw in zip(obs.prns, obs.pseudoranges[k]):
        if not np.isfinite(raw):
            continue
        tx = transmission_state(nav, prn, t, raw)
        sat = sagnac(tx.position, np.linalg.norm(tx.position - receiver) / SPEED_OF_LIGHT)
        el, az = elevation_azimuth(receiver, sat) if known else (np.pi / 2, 0.0)
        if known and np.degrees(el) < options.elevation_mask_deg:
            continue
        tropo = troposphere_delay(lat, height, el) if known and options.troposphere else 0.0
        iono = 0.0
        if known and options.ionosphere and nav.klobuchar_alpha and nav.klobuchar_beta:
            iono = klobuchar_delay(nav.klobuchar_alpha, nav.klobuchar_beta, lat, lon, el, az, t)
        rows.append((prn, sat, raw + SPEED_OF_LIGHT * tx.clock - tropo - iono,
                     np.degrees(el), tropo, iono))
    if not rows:
        return Epoch(t, (), np.empty((0, 3)), *(np.empty(0) for _ in range(4)))
    prns, sats, rho, el, tropo, iono = zip(*rows)
    return Epoch(t, tuple(prns), np.array(sats), np.array(rho), np.array(el),
                 np.array(tropo), np.array(iono))


def bootstrap_fix(obs: GpsObservations, nav: GpsNavigation, k: int = 0,
                  options: CorrectionOptions = CorrectionOptions(),
                  max_rounds: int = 10, tolerance: float = 1e-3) -> LsqFix:
    """A cold-start least-squares fix of epoch k: start at the Earth's centre, then
    alternate preparing the epoch at the current position and fixing, until the position
    moves less than `tolerance` metres."""
    x = np.zeros(4)
    for _ in range(max_rounds):
        epoch = prepare_epoch(obs, nav, k, x[:3], options)
        fix = least_squares_fix(epoch.satellites, epoch.pseudoranges, x)
        moved = np.linalg.norm(fix.state[:3] - x[:3])
        x = fix.state
        if moved < tolerance:
            return fix
    raise GnssDataError(f"cold-start fix of epoch {k} of {obs.path} did not settle in "
                        f"{max_rounds} rounds (last move {moved:.3g} m)")
