"""Drive scalar-update GNSS filters over real epochs and compare them with per-epoch
least-squares fixes against the station's known position.

A filter is a pair of callables for the state X = [x, y, z, b] (ECEF m, clock bias m):
predict(X, P) -> (X, P) (identity dynamics, P + Q) and update1(X, P, rho, sat_xyz) ->
(X, P) or (X, P, innovation, variance) for one pseudorange. The NumPy pair of
derive.apps.gnss.scalar_updates (the reference) and derive's generated code
(derive.apps.gnss.generated.generated_filters) both fit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from derive.apps.gnss.corrections import ecef_to_geodetic
from derive.apps.gnss.data import RealData, load_real_data
from derive.apps.gnss.errors import GnssDataError
from derive.apps.gnss.lsq import least_squares_fix
from derive.apps.gnss.measurements import CorrectionOptions, Epoch, bootstrap_fix, prepare_epoch
from derive.apps.gnss.report import format_table
from derive.apps.gnss.scalar_updates import ScalarEkf, ScalarUkf
from derive.apps.simulate import enu_basis, pseudorange_jacobian
from derive.errors import ModelError, NumericalError

REPORT_TIMES = (20.0, 100.0, 200.0, 300.0, 500.0)
"""Seconds after the first epoch at which errors are reported (and at the last epoch)."""

Predict = Callable[[np.ndarray, np.ndarray], tuple]
Update1 = Callable[[np.ndarray, np.ndarray, float, np.ndarray], tuple]


@dataclass(frozen=True)
class FilterSettings:
    """Noise settings (defaults and why).

    sigma = 3 m: C1C pseudorange error budget (receiver noise, multipath, broadcast
    orbit/clock and atmosphere residuals). q_position = 1e-6 m² per 1 s epoch: the station
    is static (3.5 cm random walk over 20 min only keeps P from collapsing; 1e-4 lets the
    estimate follow the slowly wandering error of the broadcast solution). q_clock = 1 m²
    per epoch: the receiver clock bias drifts (this receiver steers its clock: LS biases
    change by cm per second, at most 0.25 m), so its random walk is much looser than the
    position's. p0_std = 100 m for every state. alpha, beta, kappa: UKF weights
    (kappa=None: 3 − n, the plain UKF of the GNSS paper)."""

    sigma: float = 3.0
    q_position: float = 1e-6
    q_clock: float = 1.0
    p0_std: float = 100.0
    alpha: float = 1.0
    beta: float = 0.0
    kappa: float | None = None

    def __post_init__(self):
        for name in ("sigma", "p0_std", "alpha"):
            if not getattr(self, name) > 0:
                raise ModelError(f"FilterSettings.{name} must be > 0, got "
                                 f"{getattr(self, name)!r}")
        for name in ("q_position", "q_clock"):
            if not getattr(self, name) >= 0:
                raise ModelError(f"FilterSettings.{name} must be >= 0, got "
                                 f"{getattr(self, name)!r}")

    @property
    def Q(self) -> np.ndarray:
        return np.diag([self.q_position] * 3 + [self.q_clock])

    @property
    def P0(self) -> np.ndarray:
        return self.p0_std ** 2 * np.eye(4)


def numpy_filters(settings: FilterSettings | None = None) -> dict[str, tuple]:
    """{'EKF': (predict, update1), 'UKF': (predict, update1)} from scalar_updates."""
    settings = FilterSettings() if settings is None else settings
    ekf = ScalarEkf(settings.Q, settings.sigma)
    ukf = ScalarUkf(settings.Q, settings.sigma, settings.alpha, settings.beta, settings.kappa)
    return {"EKF": (ekf.predict, ekf.update1), "UKF": (ukf.predict, ukf.update1)}


@dataclass(frozen=True)
class Track:
    """A filter's run over epochs. states[k], covariances[k]: after epoch k;
    innovations[k, j], normalized_innovations[k, j]: of satellite prns[j] at epoch k
    (NaN where not used); within an epoch the pseudoranges are processed in PRN order, so
    each innovation is taken after the updates with the lower PRNs of that epoch."""

    prns: tuple[str, ...]
    states: np.ndarray
    covariances: np.ndarray
    innovations: np.ndarray
    normalized_innovations: np.ndarray


def drive(predict: Predict, update1: Update1, epochs: Sequence[Epoch], x0, P0,
          sigma: float, prns: Sequence[str] | None = None) -> Track:
    """Run predict once and update1 once per pseudorange (PRN order) for every epoch.
    If update1 returns only (X, P), the innovation variance recorded is the first-order
    H P Hᵀ + sigma² at the state before that update."""
    prns = tuple(sorted({p for e in epochs for p in e.prns})) if prns is None else tuple(prns)
    column = {p: j for j, p in enumerate(prns)}
    x = np.asarray(x0, dtype=float).reshape(4).copy()
    P = np.asarray(P0, dtype=float).reshape(4, 4).copy()
    K = len(epochs)
    states, covs = np.empty((K, 4)), np.empty((K, 4, 4))
    nu, var = np.full((K, len(prns)), np.nan), np.full((K, len(prns)), np.nan)
    for k, epoch in enumerate(epochs):
        x, P = (np.asarray(a, dtype=float) for a in predict(x, P))
        for i in np.argsort(epoch.prns, kind="stable"):
            prn, rho, sat = epoch.prns[i], float(epoch.pseudoranges[i]), epoch.satellites[i]
            try:
                out = update1(x, P, rho, sat)
            except NumericalError as exc:
                raise NumericalError(f"epoch {k} (t = {epoch.t}), {prn}: {exc}") from exc
            if len(out) == 4:
                nu[k, column[prn]], var[k, column[prn]] = out[2], out[3]
            else:
                H = pseudorange_jacobian(x, sat[None, :])[0]
                nu[k, column[prn]] = rho - (np.linalg.norm(sat - x[:3]) + x[3])
                var[k, column[prn]] = H @ P @ H + sigma ** 2
            x, P = (np.asarray(a, dtype=float) for a in out[:2])
        states[k], covs[k] = x, P
    return Track(prns, states, covs, nu, nu / np.sqrt(var))


@dataclass(frozen=True)
class RealRunResult:
    """Errors of per-epoch least squares ('LS') and the filters against the truth.

    times: (K,) s after the first epoch; satellite_counts: (K,); lsq_states: (K, 4), NaN
    where an epoch had < 4 satellites; tracks: per filter, row 0 is the initial state
    (the LS fix of epoch 0) and row k the state after epoch k; enu: rows east, north, up
    at the truth."""

    data_name: str
    start_gps_seconds: float
    times: np.ndarray
    truth: np.ndarray
    enu: np.ndarray
    prns: tuple[str, ...]
    satellite_counts: np.ndarray
    lsq_states: np.ndarray
    tracks: dict[str, Track]
    settings: FilterSettings
    corrections: CorrectionOptions
    troposphere_mean: float = 0.0
    ionosphere_mean: float = 0.0

    def states(self, name: str) -> np.ndarray:
        return self.lsq_states if name == "LS" else self.tracks[name].states

    def errors_enu(self, name: str) -> np.ndarray:
        """(K, 3) east, north, up error (m) of 'LS' or a filter."""
        return (self.states(name)[:, :3] - self.truth) @ self.enu.T

    def errors_3d(self, name: str) -> np.ndarray:
        return np.linalg.norm(self.errors_enu(name), axis=1)

    @property
    def lsq_rms_3d(self) -> float:
        """RMS over the epochs with a fix of the LS fixes' 3-D error (m)."""
        e = self.errors_3d("LS")
        return float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))

    def final_3d(self, name: str) -> float:
        return float(self.errors_3d(name)[-1])

    def report_rows(self) -> list[int]:
        """Epoch indices at REPORT_TIMES within the run, and the last epoch."""
        rows = [int(np.argmin(np.abs(self.times - t))) for t in REPORT_TIMES
                if t <= self.times[-1]]
        return sorted(set(rows) | {len(self.times) - 1})

    def innovation_summary(self, name: str) -> dict[str, tuple[int, float, float]]:
        """Per satellite: (count, mean, RMS) of the normalised innovations of a filter."""
        track = self.tracks[name]
        out = {}
        for j, prn in enumerate(track.prns):
            v = track.normalized_innovations[1:, j]
            v = v[np.isfinite(v)]
            if len(v):
                out[prn] = (len(v), float(v.mean()), float(np.sqrt(np.mean(v ** 2))))
        return out

    def table(self) -> str:
        return format_table(self)


def run_real(filters: Mapping[str, tuple[Predict, Update1]] | None = None, *,
             max_epochs: int | None = None, settings: FilterSettings | None = None,
             corrections: CorrectionOptions | None = None,
             data: RealData | None = None) -> RealRunResult:
    """Run filters (default: numpy_filters(settings)) and per-epoch least squares over the
    GPS C1C pseudoranges of the real data set, first `max_epochs` epochs (or of `data`,
    e.g. from load_real_data with other RINEX files).
    Satellite positions, clocks and delays are computed once at the cold-start fix of
    epoch 0, which also initialises every filter (P0 = settings.P0); the filters update
    from epoch 1 on."""
    settings = FilterSettings() if settings is None else settings
    corrections = CorrectionOptions() if corrections is None else corrections
    data = load_real_data(max_epochs) if data is None else data
    obs, nav = data.observations, data.navigation
    if len(obs.times) < 2:
        raise GnssDataError(f"need at least 2 epochs, got {len(obs.times)}")
    start = bootstrap_fix(obs, nav, 0, corrections)
    epochs = [prepare_epoch(obs, nav, k, start.state[:3], corrections)
              for k in range(len(obs.times))]
    lsq = np.full((len(epochs), 4), np.nan)
    guess = start.state
    for k, epoch in enumerate(epochs):
        if len(epoch.prns) >= 4:
            lsq[k] = guess = least_squares_fix(epoch.satellites, epoch.pseudoranges,
                                               guess).state
    filters = numpy_filters(settings) if filters is None else filters
    tracks = {}
    for name, (predict, update1) in filters.items():
        run = drive(predict, update1, epochs[1:], start.state, settings.P0, settings.sigma,
                    obs.prns)
        tracks[name] = Track(run.prns, np.vstack([start.state, run.states]),
                             np.concatenate([settings.P0[None], run.covariances]),
                             np.vstack([np.full(len(obs.prns), np.nan), run.innovations]),
                             np.vstack([np.full(len(obs.prns), np.nan),
                                        run.normalized_innovations]))
    lat, lon, _ = ecef_to_geodetic(data.truth)
    tropo = np.concatenate([e.troposphere for e in epochs])
    iono = np.concatenate([e.ionosphere for e in epochs])
    return RealRunResult(
        data_name=obs.marker or obs.path, start_gps_seconds=float(obs.times[0]),
        times=obs.times - obs.times[0], truth=data.truth, enu=enu_basis(lat, lon),
        prns=obs.prns, satellite_counts=np.array([len(e.prns) for e in epochs]),
        lsq_states=lsq, tracks=tracks, settings=settings, corrections=corrections,
        troposphere_mean=float(tropo.mean()) if len(tropo) else 0.0,
        ionosphere_mean=float(iono.mean()) if len(iono) else 0.0)
