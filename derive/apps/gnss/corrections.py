"""Receiver-side geometry and atmospheric delays for GPS L1 pseudoranges.

Troposphere: Saastamoinen (1972) zenith delays from a standard atmosphere (pressure and
temperature from the height, 70 % relative humidity, as RTKLIB's tropmodel), mapped with
1/cos(zenith). Ionosphere: the GPS broadcast Klobuchar model (IS-GPS-200, 20.3.3.5.2.5).
Both are delays: they are subtracted from the measured pseudorange.
"""

from __future__ import annotations

import math

import numpy as np

from derive.apps.gnss.constants import GPS_PI, SPEED_OF_LIGHT, seconds_of_week
from derive.apps.simulate import WGS84_A, WGS84_E2, enu_basis

_HUMIDITY = 0.7


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[float, float, float]:
    """WGS-84 latitude, longitude (degrees) and ellipsoidal height (m) of an ECEF point
    (fixed-point iteration on the latitude, converged to < 1e-12 rad)."""
    x, y, z = (float(v) for v in xyz)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - WGS84_E2))
    for _ in range(20):
        n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
        new = math.atan2(z + WGS84_E2 * n * math.sin(lat), p)
        if abs(new - lat) < 1e-12:
            lat = new
            break
        lat = new
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    height = (p / math.cos(lat) - n if abs(lat) < math.radians(89.0)
              else z / math.sin(lat) - n * (1.0 - WGS84_E2))
    return math.degrees(lat), math.degrees(math.atan2(y, x)), height


def elevation_azimuth(receiver: np.ndarray, satellite: np.ndarray) -> tuple[float, float]:
    """Elevation and azimuth (radians, azimuth clockwise from north) of a satellite seen
    from an ECEF receiver position, on the WGS-84 ellipsoid normal."""
    lat, lon, _ = ecef_to_geodetic(receiver)
    east, north, up = enu_basis(lat, lon) @ (satellite - receiver)
    return math.atan2(up, math.hypot(east, north)), math.atan2(east, north) % (2.0 * math.pi)


def troposphere_delay(lat_deg: float, height: float, elevation: float) -> float:
    """Saastamoinen slant delay (m) at a standard atmosphere for an elevation (rad);
    0 for heights outside −100 m … 10 km or non-positive elevations."""
    if not (-100.0 <= height <= 1e4) or elevation <= 0.0:
        return 0.0
    h = max(height, 0.0)
    pressure = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568                  # hPa
    temperature = 15.0 - 6.5e-3 * h + 273.16                               # K
    vapour = 6.108 * _HUMIDITY * math.exp((17.15 * temperature - 4684.0)
                                          / (temperature - 38.45))         # hPa
    zenith = math.pi / 2.0 - elevation
    hydro = 0.0022768 * pressure / (1.0 - 0.00266 * math.cos(2.0 * math.radians(lat_deg))
                                    - 0.00028 * h / 1e3)
    wet = 0.002277 * (1255.0 / temperature + 0.05) * vapour
    return (hydro + wet) / math.cos(zenith)


def klobuchar_delay(alpha, beta, lat_deg: float, lon_deg: float, elevation: float,
                    azimuth: float, t: float) -> float:
    """Klobuchar L1 ionospheric delay (m) for the broadcast coefficients alpha0..3 and
    beta0..3, a receiver latitude/longitude (deg), satellite elevation/azimuth (rad) and
    continuous GPS time t (s)."""
    el = elevation / GPS_PI                                   # semicircles
    psi = 0.0137 / (el + 0.11) - 0.022
    phi_i = min(max(lat_deg / 180.0 + psi * math.cos(azimuth), -0.416), 0.416)
    lam_i = lon_deg / 180.0 + psi * math.sin(azimuth) / math.cos(phi_i * GPS_PI)
    phi_m = phi_i + 0.064 * math.cos((lam_i - 1.617) * GPS_PI)
    local = (4.32e4 * lam_i + seconds_of_week(t)) % 86_400.0
    slant = 1.0 + 16.0 * (0.53 - el) ** 3
    amp = max(sum(a * phi_m ** n for n, a in enumerate(alpha)), 0.0)
    per = max(sum(b * phi_m ** n for n, b in enumerate(beta)), 72_000.0)
    x = 2.0 * math.pi * (local - 50_400.0) / per
    night = 5e-9
    delay = night + amp * (1.0 - x ** 2 / 2.0 + x ** 4 / 24.0) if abs(x) < 1.57 else night
    return SPEED_OF_LIGHT * slant * delay
