"""Readers for the GPS part of RINEX 3 observation and navigation files.

Only what the GPS pseudorange solution needs: one code observable (e.g. C1C) per GPS
satellite and epoch, the header's APPROX POSITION XYZ and ANTENNA: DELTA H/E/N, the GPS
LNAV broadcast ephemerides and the GPSA/GPSB (Klobuchar) ionosphere coefficients.
Times are continuous GPS seconds (constants.gps_seconds). Other systems are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from derive.apps.gnss.constants import SECONDS_PER_WEEK, gps_seconds
from derive.apps.gnss.errors import GnssDataError

_EVENT_FLAGS = {2, 3, 4, 5}   # header or special records follow the epoch line
_OBS_WIDTH = 16               # F14.3 + LLI + SSI
_OBS_EPOCH_COLUMNS = ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18))   # seconds: [18:29]
_NAV_EPOCH_COLUMNS = ((4, 8), (9, 11), (12, 14), (15, 17), (18, 20), (21, 23))


@dataclass(frozen=True)
class GpsObservations:
    """One code observable of the GPS satellites of a RINEX 3 observation file.

    times: (K,) receiver time tags in continuous GPS seconds; prns: sorted names ('G02', …);
    pseudoranges: (K, len(prns)) metres, NaN where a satellite has no value at an epoch."""

    path: str
    code: str
    marker: str
    approx_position: np.ndarray     # APPROX POSITION XYZ, ECEF m
    antenna_delta_hen: np.ndarray   # ANTENNA: DELTA H/E/N, m
    times: np.ndarray
    prns: tuple[str, ...]
    pseudoranges: np.ndarray


@dataclass(frozen=True)
class GpsEphemeris:
    """One GPS LNAV broadcast record (RINEX 3 field names; angles in rad, times in s).
    toc is continuous GPS time; toe is seconds of the GPS week `week`."""

    prn: str
    toc: float
    af0: float
    af1: float
    af2: float
    iode: float
    crs: float
    delta_n: float
    m0: float
    cuc: float
    e: float
    cus: float
    sqrt_a: float
    toe: float
    cic: float
    omega0: float
    cis: float
    i0: float
    crc: float
    omega: float
    omega_dot: float
    idot: float
    week: float
    accuracy: float
    health: float
    tgd: float
    iodc: float
    fit_interval_h: float

    @property
    def toe_time(self) -> float:
        """toe as continuous GPS seconds."""
        return self.week * SECONDS_PER_WEEK + self.toe


@dataclass(frozen=True)
class GpsNavigation:
    """Broadcast GPS ephemerides per satellite (sorted by toe) and the Klobuchar
    coefficients alpha0..3, beta0..3 from the header (None when absent)."""

    path: str
    ephemerides: dict[str, tuple[GpsEphemeris, ...]]
    klobuchar_alpha: tuple[float, ...] | None
    klobuchar_beta: tuple[float, ...] | None


def _float(text: str, path, lineno: int, what: str) -> float:
    text = text.strip().replace("D", "E").replace("d", "e")
    if not text:
        return float("nan")
    try:
        return float(text)
    except ValueError:
        raise GnssDataError(f"{path}:{lineno}: {what} is not a number: {text!r}") from None


def _read_lines(path) -> list[str]:
    p = Path(path)
    if not p.is_file():
        raise GnssDataError(f"RINEX file not found: {p}")
    return p.read_text(encoding="ascii", errors="replace").splitlines()


def _header(lines: list[str], path, kind: str) -> tuple[list[tuple[str, str]], int]:
    """(label, content) pairs and the index of the first data line; checks version 3."""
    records = []
    for line in lines:
        label = line[60:].strip()
        records.append((label, line[:60]))
        if label == "END OF HEADER":
            break
    else:
        raise GnssDataError(f"{path}: no END OF HEADER line")
    label, content = records[0]
    if label != "RINEX VERSION / TYPE":
        raise GnssDataError(f"{path}:1: expected RINEX VERSION / TYPE, got {label!r}")
    version = _float(content[:9], path, 1, "RINEX version")
    if not 3.0 <= version < 4.0 or content[20:21] != kind:
        raise GnssDataError(f"{path}:1: need a RINEX 3 {kind!r} file, got version "
                            f"{version:g} type {content[20:21]!r}")
    return records, len(records)


def _gps_obs_types(records, path) -> list[str]:
    types: list[str] = []
    system = None
    for label, content in records:
        if label != "SYS / # / OBS TYPES":
            continue
        if content[0] != " ":
            system = content[0]
        if system == "G":
            types += content[7:].split()
    if not types:
        raise GnssDataError(f"{path}: header lists no GPS observation types")
    return types


def _vector(records, label, path) -> np.ndarray:
    for lab, content in records:
        if lab == label:
            return np.array([_float(content[i:i + 14], path, 0, label)
                             for i in (0, 14, 28)])
    raise GnssDataError(f"{path}: header has no {label!r} line")


def read_gps_observations(path, code: str = "C1C",
                          max_epochs: int | None = None) -> GpsObservations:
    """GPS `code` observations (metres) of a RINEX 3 observation file, epoch by epoch.
    max_epochs stops after that many epochs (None: all). Epochs with event flags 2–5
    are skipped with their special records."""
    lines = _read_lines(path)
    records, i = _header(lines, path, "O")
    types = _gps_obs_types(records, path)
    if code not in types:
        raise GnssDataError(f"{path}: GPS observation type {code!r} not in the header "
                            f"(have {', '.join(types)})")
    col = 3 + _OBS_WIDTH * types.index(code)
    marker = next((c.strip() for lab, c in records if lab == "MARKER NAME"), "")
    approx = _vector(records, "APPROX POSITION XYZ", path)
    delta = next((np.array([_float(c[k:k + 14], path, 0, "ANTENNA: DELTA H/E/N")
                            for k in (0, 14, 28)])
                  for lab, c in records if lab == "ANTENNA: DELTA H/E/N"), np.zeros(3))
    times: list[float] = []
    epochs: list[dict[str, float]] = []
    while i < len(lines) and (max_epochs is None or len(times) < max_epochs):
        line = lines[i]
        if not line.startswith(">"):
            raise GnssDataError(f"{path}:{i + 1}: expected an epoch line starting with '>'")
        try:
            y, mo, d, h, mi = (int(line[a:b]) for a, b in _OBS_EPOCH_COLUMNS)
            sec = float(line[18:29])
            flag, count = int(line[31]), int(line[32:35])
        except ValueError:
            raise GnssDataError(f"{path}:{i + 1}: malformed epoch line {line!r}") from None
        body = lines[i + 1:i + 1 + count]
        i += 1 + count
        if flag in _EVENT_FLAGS or flag == 6:
            continue
        values = {}
        for offset, rec in enumerate(body, start=i - count + 1):
            if rec[:1] == "G":
                v = _float(rec[col:col + 14], path, offset, f"{rec[:3]} {code}")
                if np.isfinite(v) and v != 0.0:
                    values[rec[:3].replace(" ", "0")] = v
        times.append(gps_seconds(y, mo, d, h, mi, sec))
        epochs.append(values)
    if not times:
        raise GnssDataError(f"{path}: no observation epochs")
    prns = tuple(sorted({p for e in epochs for p in e}))
    table = np.full((len(times), len(prns)), np.nan)
    index = {p: j for j, p in enumerate(prns)}
    for k, e in enumerate(epochs):
        for p, v in e.items():
            table[k, index[p]] = v
    return GpsObservations(str(path), code, marker, approx, delta, np.array(times),
                           prns, table)


_NAV_FIELDS = ("iode", "crs", "delta_n", "m0", "cuc", "e", "cus", "sqrt_a", "toe", "cic",
               "omega0", "cis", "i0", "crc", "omega", "omega_dot", "idot", None, "week",
               None, "accuracy", "health", "tgd", "iodc", None, "fit_interval_h")


def _klobuchar(records, label, path):
    for lab, content in records:
        if lab == "IONOSPHERIC CORR" and content[:4] == label:
            return tuple(_float(content[5 + 12 * k:17 + 12 * k], path, 0, label)
                         for k in range(4))
    return None


def read_gps_navigation(path) -> GpsNavigation:
    """GPS LNAV ephemerides of a RINEX 3 navigation file (other systems skipped)."""
    lines = _read_lines(path)
    records, i = _header(lines, path, "N")
    ephs: dict[str, list[GpsEphemeris]] = {}
    sizes = {"G": 8, "E": 8, "C": 8, "J": 8, "I": 8, "R": 4, "S": 4}
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        system = line[0]
        if system not in sizes:
            raise GnssDataError(f"{path}:{i + 1}: unknown record start {line[:3]!r}")
        block = lines[i:i + sizes[system]]
        if system == "G":
            ephs.setdefault(line[:3], []).append(_gps_record(block, path, i + 1))
        i += sizes[system]
    for prn in ephs:
        ephs[prn].sort(key=lambda e: e.toe_time)
    return GpsNavigation(str(path), {p: tuple(ephs[p]) for p in sorted(ephs)},
                         _klobuchar(records, "GPSA", path), _klobuchar(records, "GPSB", path))


def _gps_record(block: list[str], path, lineno: int) -> GpsEphemeris:
    if len(block) != 8:
        raise GnssDataError(f"{path}:{lineno}: truncated GPS navigation record")
    head = block[0]
    try:
        y, mo, d, h, mi, s = (int(head[a:b]) for a, b in _NAV_EPOCH_COLUMNS)
    except ValueError:
        raise GnssDataError(f"{path}:{lineno}: malformed epoch in {head!r}") from None
    clock = [_float(head[23 + 19 * k:42 + 19 * k], path, lineno, "clock field")
             for k in range(3)]
    values = [_float(row[4 + 19 * k:23 + 19 * k], path, lineno + r, "orbit field")
              for r, row in enumerate(block[1:], start=1) for k in range(4)]
    fields = {name: v for name, v in zip(_NAV_FIELDS, values) if name}
    for name in ("sqrt_a", "e", "toe", "week", "m0", "i0", "omega0"):
        if not np.isfinite(fields[name]):
            raise GnssDataError(f"{path}:{lineno}: {head[:3]} record lacks {name}")
    return GpsEphemeris(prn=head[:3], toc=gps_seconds(y, mo, d, h, mi, s), af0=clock[0],
                        af1=clock[1], af2=clock[2], **fields)
