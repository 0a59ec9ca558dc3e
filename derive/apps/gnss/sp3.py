"""A reader for SP3-c/d precise orbit files (GPS satellites) and Lagrange interpolation.

Used as an independent check of the broadcast ephemeris: precise orbits refer to the
satellite's centre of mass, broadcast ones to its antenna, so the two differ by the
antenna offset (about a metre) plus the broadcast orbit error (about a metre).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from derive.apps.gnss.constants import gps_seconds
from derive.apps.gnss.errors import GnssDataError

_BAD_CLOCK = 999_999.0   # µs; SP3 marks an unknown clock with 999999.999999


@dataclass(frozen=True)
class PreciseOrbits:
    """times (T,) continuous GPS s; prns sorted; positions (T, N, 3) ECEF m and clocks
    (T, N) s, NaN where a value is missing."""

    path: str
    times: np.ndarray
    prns: tuple[str, ...]
    positions: np.ndarray
    clocks: np.ndarray

    def interpolate(self, prn: str, t: float, order: int = 9) -> tuple[np.ndarray, float]:
        """(position m, clock s) of `prn` at continuous GPS time t by Lagrange interpolation
        over the order + 1 samples nearest t."""
        if prn not in self.prns:
            raise GnssDataError(f"{self.path}: no precise orbit for {prn}")
        j = self.prns.index(prn)
        nearest = np.argsort(np.abs(self.times - t), kind="stable")[:order + 1]
        nodes = np.sort(nearest)
        if not self.times[nodes[0]] <= t <= self.times[nodes[-1]]:
            raise GnssDataError(f"{self.path}: time {t:.1f} is outside the samples for {prn}")
        ts = self.times[nodes]
        weights = np.array([np.prod([(t - ts[m]) / (ts[i] - ts[m])
                                     for m in range(len(ts)) if m != i])
                            for i in range(len(ts))])
        pos = weights @ self.positions[nodes, j]
        clock = weights @ self.clocks[nodes, j]
        if not np.all(np.isfinite(pos)):
            raise GnssDataError(f"{self.path}: missing precise positions of {prn} near {t:.1f}")
        return pos, float(clock)


def read_sp3(path) -> PreciseOrbits:
    """GPS ('PG..') position and clock records of an SP3-c/d file in GPS time."""
    p = Path(path)
    if not p.is_file():
        raise GnssDataError(f"SP3 file not found: {p}")
    lines = p.read_text(encoding="ascii", errors="replace").splitlines()
    if not lines or lines[0][:2] not in ("#c", "#d"):
        raise GnssDataError(f"{p}:1: not an SP3-c/d file")
    system = next((ln[9:12] for ln in lines if ln.startswith("%c")), "GPS")
    if system != "GPS":
        raise GnssDataError(f"{p}: time system {system!r}, need GPS")
    times: list[float] = []
    records: list[dict[str, tuple[float, ...]]] = []
    for lineno, line in enumerate(lines, start=1):
        try:
            if line.startswith("* "):
                y, mo, d, h, mi = (int(v) for v in line[2:].split()[:5])
                times.append(gps_seconds(y, mo, d, h, mi, float(line[2:].split()[5])))
                records.append({})
            elif line.startswith("PG") and records:
                x, yy, z, clk = (float(line[k:k + 14]) for k in (4, 18, 32, 46))
                records[-1][line[1:4].replace(" ", "0")] = (x, yy, z, clk)
        except (ValueError, IndexError):
            raise GnssDataError(f"{p}:{lineno}: malformed record {line!r}") from None
    prns = tuple(sorted({prn for rec in records for prn in rec}))
    pos = np.full((len(times), len(prns), 3), np.nan)
    clk = np.full((len(times), len(prns)), np.nan)
    for k, rec in enumerate(records):
        for prn, (x, yy, z, c) in rec.items():
            j = prns.index(prn)
            if (x, yy, z) != (0.0, 0.0, 0.0):
                pos[k, j] = np.array([x, yy, z]) * 1e3
            if c < _BAD_CLOCK:
                clk[k, j] = c * 1e-6
    return PreciseOrbits(str(p), np.array(times), prns, pos, clk)
