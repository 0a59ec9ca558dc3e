"""Physical constants of GPS (IS-GPS-200, Table 20-IV) and time-scale helpers."""

from __future__ import annotations

import datetime as _dt

SPEED_OF_LIGHT = 299_792_458.0
"""m/s."""
GM_EARTH = 3.986005e14
"""WGS-84 Earth gravitational constant for GPS, m³/s²."""
OMEGA_EARTH = 7.2921151467e-5
"""WGS-84 Earth rotation rate, rad/s."""
GPS_PI = 3.1415926535898
"""The value of pi IS-GPS-200 prescribes for the orbit and ionosphere algorithms."""
RELATIVITY_F = -4.442807633e-10
"""F = −2 sqrt(μ)/c², s/m^½ (relativistic clock term Δt_r = F e sqrt(A) sin E)."""
SECONDS_PER_WEEK = 604_800.0

_GPS_EPOCH = _dt.date(1980, 1, 6)


def gps_seconds(year: int, month: int, day: int, hour: int, minute: int,
                second: float) -> float:
    """Continuous GPS time in seconds since 1980-01-06 00:00:00 for a calendar epoch
    already in the GPS time scale (no leap seconds)."""
    days = (_dt.date(year, month, day) - _GPS_EPOCH).days
    return days * 86_400.0 + hour * 3600.0 + minute * 60.0 + float(second)


def seconds_of_week(t: float) -> float:
    """Seconds into the GPS week of continuous GPS time t."""
    return t % SECONDS_PER_WEEK
