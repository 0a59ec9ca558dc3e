"""GPS broadcast ephemeris evaluation (IS-GPS-200, 20.3.3.3.3 and Table 20-IV).

satellite_position gives the ECEF position (in the Earth-fixed frame of the given
time) of the satellite's antenna; satellite_clock the offset Δt_sv of its clock from GPS
time for an L1 C/A user (af0 + af1·dt + af2·dt² + relativistic term − TGD);
transmission_state finds the transmission time of a pseudorange, and sagnac rotates a
position given at transmission into the Earth-fixed frame of reception.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from derive.apps.gnss.constants import (
    GM_EARTH,
    OMEGA_EARTH,
    RELATIVITY_F,
    SECONDS_PER_WEEK,
    SPEED_OF_LIGHT,
)
from derive.apps.gnss.errors import GnssDataError
from derive.apps.gnss.rinex import GpsEphemeris, GpsNavigation

_KEPLER_TOL = 1e-14
_DEFAULT_FIT_HOURS = 4.0


def select_ephemeris(nav: GpsNavigation, prn: str, t: float) -> GpsEphemeris:
    """The healthy ephemeris of `prn` whose toe is closest to t (continuous GPS s) and
    whose fit interval (± half of the record's fit interval, 4 h when 0 or blank)
    contains t; the earlier record wins a tie."""
    best, best_gap = None, math.inf
    for eph in nav.ephemerides.get(prn, ()):
        fit = eph.fit_interval_h if eph.fit_interval_h > 0 else _DEFAULT_FIT_HOURS
        gap = abs(t - eph.toe_time)
        if eph.health == 0 and gap <= fit * 1800.0 and gap < best_gap:
            best, best_gap = eph, gap
    if best is None:
        raise GnssDataError(f"no healthy, valid broadcast ephemeris for {prn} at GPS week "
                            f"{int(t // SECONDS_PER_WEEK)} second {t % SECONDS_PER_WEEK:.1f} "
                            f"in {nav.path}")
    return best


def eccentric_anomaly(eph: GpsEphemeris, t: float) -> float:
    """E solving Kepler's equation M = E − e sin E at continuous GPS time t (Newton)."""
    a = eph.sqrt_a ** 2
    n = math.sqrt(GM_EARTH / a ** 3) + eph.delta_n
    m = eph.m0 + n * (t - eph.toe_time)
    e_anom = m
    for _ in range(30):
        step = (e_anom - eph.e * math.sin(e_anom) - m) / (1.0 - eph.e * math.cos(e_anom))
        e_anom -= step
        if abs(step) < _KEPLER_TOL:
            return e_anom
    raise GnssDataError(f"Kepler iteration did not converge for {eph.prn} (e = {eph.e:g})")


def satellite_position(eph: GpsEphemeris, t: float) -> np.ndarray:
    """ECEF position (m, WGS-84 frame at time t) at continuous GPS time t."""
    a = eph.sqrt_a ** 2
    tk = t - eph.toe_time
    e_anom = eccentric_anomaly(eph, t)
    nu = math.atan2(math.sqrt(1.0 - eph.e ** 2) * math.sin(e_anom), math.cos(e_anom) - eph.e)
    phi = nu + eph.omega
    s2, c2 = math.sin(2.0 * phi), math.cos(2.0 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = a * (1.0 - eph.e * math.cos(e_anom)) + eph.crs * s2 + eph.crc * c2
    inc = eph.i0 + eph.cis * s2 + eph.cic * c2 + eph.idot * tk
    xp, yp = r * math.cos(u), r * math.sin(u)
    node = eph.omega0 + (eph.omega_dot - OMEGA_EARTH) * tk - OMEGA_EARTH * eph.toe
    return np.array([xp * math.cos(node) - yp * math.cos(inc) * math.sin(node),
                     xp * math.sin(node) + yp * math.cos(inc) * math.cos(node),
                     yp * math.sin(inc)])


def clock_polynomial(eph: GpsEphemeris, t: float) -> float:
    """af0 + af1·dt + af2·dt² (s), dt = t − toc (continuous GPS s): the clock offset as
    IGS precise clocks give it (without the periodic relativistic term)."""
    dt = t - eph.toc
    return eph.af0 + eph.af1 * dt + eph.af2 * dt ** 2


def relativistic_clock(eph: GpsEphemeris, t: float) -> float:
    """Periodic relativistic clock term Δt_r = F·e·sqrt(A)·sin E (s), equal to −2 r·v/c²."""
    return RELATIVITY_F * eph.e * eph.sqrt_a * math.sin(eccentric_anomaly(eph, t))


def satellite_clock(eph: GpsEphemeris, t: float, apply_tgd: bool = True) -> float:
    """Δt_sv (s) at continuous GPS time t: the clock polynomial plus the relativistic term,
    minus TGD for an L1 (C/A) user when apply_tgd (IS-GPS-200 20.3.3.3.3.2)."""
    tgd = eph.tgd if apply_tgd and np.isfinite(eph.tgd) else 0.0
    return clock_polynomial(eph, t) + relativistic_clock(eph, t) - tgd


@dataclass(frozen=True)
class TransmissionState:
    """A satellite at the transmission of one pseudorange: t_tx (continuous GPS s), its
    position in the ECEF frame of t_tx (m) and its clock offset Δt_sv (s)."""

    prn: str
    t_tx: float
    position: np.ndarray
    clock: float


def transmission_state(nav: GpsNavigation, prn: str, t_rx: float,
                       pseudorange: float) -> TransmissionState:
    """Transmission time t_tx = t_rx − ρ/c − Δt_sv(t_tx) (exact in the receiver's clock
    error: ρ/c spans the receiver's reading and the satellite's clock), Δt_sv iterated
    twice; the ephemeris is selected at t_rx."""
    eph = select_ephemeris(nav, prn, t_rx)
    t_tx = t_rx - pseudorange / SPEED_OF_LIGHT
    clock = 0.0
    for _ in range(2):
        clock = satellite_clock(eph, t_tx - clock)
    t_tx -= clock
    return TransmissionState(prn, t_tx, satellite_position(eph, t_tx), clock)


def sagnac(position: np.ndarray, travel_time: float) -> np.ndarray:
    """Rotate an ECEF position of transmission time into the ECEF frame of reception,
    travel_time seconds later (the Earth turns by ω_E·τ about z meanwhile)."""
    theta = OMEGA_EARTH * travel_time
    c, s = math.cos(theta), math.sin(theta)
    x, y, z = position
    return np.array([c * x + s * y, -s * x + c * y, z])
