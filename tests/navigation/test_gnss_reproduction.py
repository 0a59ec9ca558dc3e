"""The simulated reproduction of the GNSS paper's RMSE table (derive.apps.gnss.sim) and the
`derive gnss` command."""

import numpy as np
import pytest

from derive.apps.gnss.sim import PAPER, TIMES, reproduce
from derive.cli import main
from derive.errors import ModelError


@pytest.fixture(scope="module")
def table():
    return reproduce(runs=200, steps=500, seed=2024)


def test_the_papers_trend(table):
    assert table.times == TIMES
    for name in ("EKF", "UKF"):
        rmse = table.rmse[name]
        assert rmse.shape == (5, 4) and np.all(np.isfinite(rmse))
        position = rmse[:, :3].mean(axis=1)
        # errors shrink monotonically, from metres at 20 s to about 1 m at 500 s
        assert np.all(np.diff(position) < 0)
        assert 2.5 < position[0] < 8.0
        assert 0.7 < position[-1] < 2.0
        assert position[0] / position[-1] > 2.5
    # UKF not worse than EKF (beyond the Monte Carlo error of the ratio)
    assert table.worst_ratio() <= 1.0 + 1.0 / np.sqrt(2 * table.runs)


def test_rmse_matches_the_filters_own_covariance(table):
    """Consistency: the Monte Carlo RMSE is at most the sqrt of P's diagonal (P hardly
    depends on the noise draw), and close to it early on; later it is below, since the
    truth is static while the filter's Q = 0.01 I4 lets P expect a random walk."""
    from derive import catalog
    from derive.apps.simulate import gnss_scenario
    from derive.reference import ekf

    sc = gnss_scenario(500, 2024, moving=True, init_std=10.0)
    fns = catalog.load("gnss_pseudorange").numeric_functions()
    res = ekf(None, None, fns["h"], fns["H"], fns["Q"], fns["R"], sc.x0, sc.P0,
              sc.pseudoranges, inputs=list(sc.satellites.reshape(500, 12)))
    sigma = np.sqrt(np.diagonal(res.Ps[[t - 1 for t in TIMES]], axis1=1, axis2=2))
    np.testing.assert_allclose(table.rmse["EKF"][:2], sigma[:2], rtol=0.15)
    assert np.all(table.rmse["EKF"] <= 1.1 * sigma)
    assert np.all(table.rmse["EKF"][-1] < 0.9 * sigma[-1])


def test_table_prints_the_papers_numbers_beside(table):
    text = table.table()
    for value in (PAPER["EKF"][0, 0], PAPER["UKF"][-1, 0], PAPER["EKF"][2, 3]):
        assert f"{value:5.2f}" in text
    row = next(line for line in text.splitlines() if line.startswith("   20 |"))
    assert row.split("|")[1].split() == [f"{v:.2f}" for v in table.rmse["EKF"][0]]
    assert row.split("|")[2].split() == [f"{v:.2f}" for v in PAPER["EKF"][0]]
    assert "UKF not worse than EKF" in text


def test_deterministic_and_language_independent():
    a = reproduce(runs=4, steps=100, seed=5)
    b = reproduce(runs=4, steps=100, seed=5)
    c = reproduce(runs=4, steps=100, seed=5, lang="c")
    assert a.times == (20, 100)
    for name in ("EKF", "UKF"):
        np.testing.assert_array_equal(a.rmse[name], b.rmse[name])
        np.testing.assert_allclose(c.rmse[name], a.rmse[name], rtol=1e-9)
    assert not np.array_equal(reproduce(runs=4, steps=100, seed=6).rmse["EKF"], a.rmse["EKF"])


def test_bad_arguments():
    with pytest.raises(ModelError, match="runs"):
        reproduce(runs=1)
    with pytest.raises(ModelError, match="steps"):
        reproduce(steps=10)
    with pytest.raises(ModelError, match="lang"):
        reproduce(lang="fortran")


def test_command_sim(capsys):
    assert main(["gnss", "--runs", "20", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "EKF paper" in out and "4.07" in out and "Monte Carlo" in out


def test_command_real_without_the_data_package_is_bad_input(monkeypatch, capsys):
    import derive.apps.gnss.data as data

    def missing(name):
        raise ModuleNotFoundError("the real GNSS data come from the package gnss-benchmark",
                                  name="gnss_benchmark")

    monkeypatch.setattr(data, "dataset_file", missing)
    assert main(["gnss", "--real", "--implementation", "numpy"]) == 2
    assert "gnss-benchmark" in capsys.readouterr().err
