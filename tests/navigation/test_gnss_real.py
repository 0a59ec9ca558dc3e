"""derive.apps.gnss on real data: the MARE station's GPS C1C pseudoranges shipped by
gnss-benchmark 2.3.0 (skipped when it is not installed), on short slices.

Independent numbers: georinex's parse of the same RINEX files, CODE's precise orbits and
clocks (COD21340.sp3, same package) for the broadcast ephemeris, and the station's known
position for the corrected pseudoranges.
"""

import numpy as np
import pytest

pytest.importorskip("gnss_benchmark")

from derive.apps.gnss import CorrectionOptions, FilterSettings, prepare_epoch, run_real  # noqa: E402
from derive.apps.gnss.command import main  # noqa: E402
from derive.apps.gnss.constants import SPEED_OF_LIGHT  # noqa: E402
from derive.apps.gnss.data import (  # noqa: E402
    NAVIGATION_FILE,
    OBSERVATION_FILE,
    PRECISE_ORBIT_FILE,
    dataset_file,
    load_real_data,
)
from derive.apps.gnss.ephemeris import (  # noqa: E402
    clock_polynomial,
    relativistic_clock,
    satellite_position,
    select_ephemeris,
)
from derive.apps.gnss.errors import GnssDataError  # noqa: E402
from derive.apps.gnss.measurements import bootstrap_fix  # noqa: E402
from derive.apps.gnss.sp3 import read_sp3  # noqa: E402

SLICE = 120


@pytest.fixture(scope="module")
def data():
    return load_real_data(SLICE)


@pytest.fixture(scope="module")
def result(data):
    return run_real(data=data)


@pytest.mark.filterwarnings("ignore::FutureWarning")   # georinex on current xarray
def test_reader_matches_georinex(data):
    gr = pytest.importorskip("georinex")
    obs = gr.load(dataset_file(OBSERVATION_FILE), use="G", meas=["C1C"],
                  tlim=("2020-11-29T12:40:00", "2020-11-29T12:41:59"))
    mine = data.observations
    assert len(obs.time) == SLICE == len(mine.times)
    assert np.all(np.diff(mine.times) == 1.0)
    table = obs.C1C.to_pandas().reindex(columns=list(mine.prns))
    np.testing.assert_array_equal(table.to_numpy(), mine.pseudoranges)
    np.testing.assert_array_equal(obs.position, mine.approx_position)
    nav = gr.load(dataset_file(NAVIGATION_FILE), use="G")
    alpha_beta = np.asarray(nav.attrs["ionospheric_corr_GPS"])
    np.testing.assert_array_equal(alpha_beta, data.navigation.klobuchar_alpha
                                  + data.navigation.klobuchar_beta)
    fields = {"sqrtA": "sqrt_a", "Eccentricity": "e", "Toe": "toe", "M0": "m0",
              "SVclockBias": "af0", "TGD": "tgd", "Omega0": "omega0", "IDOT": "idot"}
    count = 0
    for prn, ephs in data.navigation.ephemerides.items():
        for eph in ephs:
            rec = nav.sel(sv=prn).dropna("time", how="all", subset=["sqrtA"])
            row = rec.where(rec.Toe == eph.toe, drop=True)
            assert row.sizes["time"] == 1, (prn, eph.toe)
            for theirs, ours in fields.items():
                assert float(row[theirs].values[0]) == getattr(eph, ours), (prn, ours)
            count += 1
    assert count == sum(len(v) for v in data.navigation.ephemerides.values()) == 24


def test_broadcast_ephemeris_against_precise_orbits(data):
    """Broadcast (antenna) vs precise (centre of mass) positions differ by the antenna
    offset plus the broadcast error: observed at most 2.6 m; clocks agree up to one
    offset common to all satellites (observed spread ±1.5 m); the relativistic term
    equals −2 r·v/c² from the precise orbit (observed within 0.015 m)."""
    sp3 = read_sp3(dataset_file(PRECISE_ORBIT_FILE))
    nav = data.navigation
    for t in data.observations.times[[0, -1]]:
        clock_diff = []
        for prn in data.observations.prns:
            eph = select_ephemeris(nav, prn, t)
            pos = satellite_position(eph, t)
            precise, clock = sp3.interpolate(prn, t)
            assert 25.5e6 < np.linalg.norm(pos) < 27.6e6
            assert np.linalg.norm(pos - precise) < 4.0, prn
            clock_diff.append(clock_polynomial(eph, t) - clock)
            before, after = sp3.interpolate(prn, t - 0.5)[0], sp3.interpolate(prn, t + 0.5)[0]
            rel = -2.0 * ((before + after) / 2) @ (after - before) / SPEED_OF_LIGHT ** 2
            assert abs(relativistic_clock(eph, t) - rel) * SPEED_OF_LIGHT < 0.05, prn
        spread = (np.array(clock_diff) - np.mean(clock_diff)) * SPEED_OF_LIGHT
        assert np.max(np.abs(spread)) < 3.0


def test_ephemeris_selection(data):
    nav, t = data.navigation, data.observations.times[0]
    assert select_ephemeris(nav, "G15", t).toe == 50400.0      # only one, 80 min ahead
    assert select_ephemeris(nav, "G09", t).toe == 43184.0
    with pytest.raises(GnssDataError, match="G14"):           # unhealthy (health 63)
        select_ephemeris(nav, "G14", t)
    with pytest.raises(GnssDataError, match="G01"):
        select_ephemeris(nav, "G01", t)


def test_corrected_pseudoranges_fit_the_true_position(data):
    """After clocks, Sagnac and both delays, ρ − ||s − r_true|| is the receiver clock bias
    plus metre-level errors: all satellites within 5 m of their median (observed 2.3 m)."""
    fix = bootstrap_fix(data.observations, data.navigation)
    for k in (0, SLICE - 1):
        epoch = prepare_epoch(data.observations, data.navigation, k, fix.state[:3])
        residual = epoch.pseudoranges - np.linalg.norm(epoch.satellites - data.truth, axis=1)
        assert np.max(np.abs(residual - np.median(residual))) < 5.0
        assert np.all(epoch.elevations_deg >= 10.0) and len(epoch.prns) == 7
        assert np.all((epoch.troposphere > 2.0) & (epoch.troposphere < 15.0))
        assert np.all((epoch.ionosphere > 1.0) & (epoch.ionosphere < 20.0))


def test_filters_meet_the_bar_on_a_slice(result):
    lsq = result.errors_3d("LS")
    assert np.all(lsq < 20.0)
    rms = result.lsq_rms_3d
    for name in ("EKF", "UKF"):
        assert result.final_3d(name) <= rms
        # the filter removes the epoch-to-epoch scatter, not the common bias
        up_filter = result.errors_enu(name)[SLICE // 2:, 2]
        up_lsq = result.errors_enu("LS")[SLICE // 2:, 2]
        assert np.std(up_filter) < 0.5 * np.std(up_lsq)
        assert np.all(np.isfinite(result.tracks[name].normalized_innovations[1:, [1, 4]]))
    ekf, ukf = result.tracks["EKF"].states, result.tracks["UKF"].states
    assert np.max(np.abs(ekf - ukf)) < 0.01        # pseudoranges are nearly linear here
    assert [round(result.times[r]) for r in result.report_rows()] == [20, 100, SLICE - 1]
    table = result.table()
    assert "Klobuchar" in table and "Saastamoinen" in table and "UKF 3-D" in table


def test_a_setting_satellite_changes_the_count():
    """At a 6° mask G06 sets about 200 s in: 8 then 7 satellites."""
    result = run_real(max_epochs=240, corrections=CorrectionOptions(6.0))
    counts = result.satellite_counts
    assert counts[0] == 8 and counts[-1] == 7
    g06 = result.tracks["EKF"].innovations[:, result.prns.index("G06")]
    assert np.isfinite(g06[1:150]).all() and np.isnan(g06[-20:]).all()
    for name in ("EKF", "UKF"):
        assert result.final_3d(name) <= result.lsq_rms_3d


def test_plain_numpy_callables_drive_like_the_filters(data, result):
    """Any (predict, update1) pair with the generated signatures: here bare functions
    returning (X, P) only."""
    from derive.apps.gnss.scalar_updates import ekf_predict, ekf_update1

    s = FilterSettings()
    filters = {"mine": (lambda x, P: ekf_predict(x, P, s.Q),
                        lambda x, P, rho, sat: ekf_update1(x, P, rho, sat, s.sigma ** 2)[:2])}
    mine = run_real(filters, data=data)
    np.testing.assert_array_equal(mine.tracks["mine"].states, result.tracks["EKF"].states)


def test_command_prints_the_table(capsys):
    assert main(["--epochs", "25", "--no-iono"]) == 0
    out = capsys.readouterr().out
    assert "LS fixes' RMS 3-D error over 25 epochs" in out and "Klobuchar" not in out
    assert main(["--obs", "/nonexistent.rnx"]) == 2
    assert "RINEX file not found" in capsys.readouterr().err
