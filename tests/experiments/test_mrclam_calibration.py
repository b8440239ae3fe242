"""The MRCLAM filters' noise learned from the data (jaxnav.experiments.mrclam.calibration) and the
``jaxnav mrclam --calibrate`` command line. The data is read from ``$JAXNAV_DATA`` (default
``../shared/data``); the tests that need it skip, saying so, only when the folder is absent."""

from __future__ import annotations

import numpy as np
import pytest

from jaxnav import cli
from jaxnav.io import mrclam as data

try:
    data.data_dir()
    _MISSING = None
except FileNotFoundError as err:  # pragma: no cover - depends on the machine
    _MISSING = str(err)

needs_data = pytest.mark.skipif(_MISSING is not None, reason=f"MRCLAM data not found: {_MISSING}")


@pytest.fixture(scope="module")
def segment():
    from jaxnav.experiments import mrclam as xp

    s = xp.MRCLAMSettings()
    return s, data.to_filter_steps(data.load_robot(1), dt=s.dt, duration=20.0, max_obs=s.max_obs, keep_outliers=True)


@needs_data
@pytest.mark.slow
@pytest.mark.parametrize("method", ["mcl", "ekf"])
def test_fit_noise_moves_the_learned_fields_only(segment, method):
    from jaxnav.experiments.mrclam import calibration as cal

    settings, seq = segment
    fit = cal.fit_noise(seq, settings, method=method, steps=3, num_particles=64)
    learned = fit.settings
    assert fit.result.losses.shape == (3,) and np.all(np.isfinite(fit.result.losses))
    assert learned.alphas[4:] == (0.0, 0.0)  # α₅, α₆ kept
    assert learned.alphas[:4] != settings.alphas[:4] and learned.sensor_sd != settings.sensor_sd
    assert all(v > 0 for v in (*learned.alphas[:4], *learned.pose_sd, *learned.sensor_sd))
    assert (learned.dt, learned.max_obs, learned.mcl_particles) == (
        settings.dt,
        settings.max_obs,
        settings.mcl_particles,
    )


@needs_data
def test_compare_scores_each_filter_and_setting(segment):
    from jaxnav.experiments.mrclam import calibration as cal

    settings, _ = segment
    wider = type(settings)(sensor_sd=(0.4, 0.1))
    rows = cal.compare({"a": settings, "b": wider}, robots=(1,), algorithms=("ekf", "mcl"), duration=10.0)
    assert [(r.label, r.algorithm) for r in rows] == [("a", "ekf"), ("a", "mcl"), ("b", "ekf"), ("b", "mcl")]
    ekf_a, mcl_a, ekf_b, _ = rows
    assert 0 < ekf_a.position_rmse < 1.0 and 0 < mcl_a.position_rmse < 1.0
    assert np.isfinite(ekf_a.nees) and np.isfinite(ekf_a.nis) and np.isnan(mcl_a.nees)
    assert ekf_b.nis < ekf_a.nis  # a wider sensor noise: smaller normalised innovations
    table = cal.format_comparison(rows)
    assert table.count("\n") == 1 + len(rows) and "| 1 | EKF | a |" in table


def test_fit_noise_and_compare_refuse_unknown_names():
    from jaxnav.experiments.mrclam import calibration as cal

    with pytest.raises(ValueError, match="method"):
        cal.fit_noise(None, method="ukf")
    with pytest.raises(ValueError, match="algorithm"):
        cal.compare({}, algorithms=("fastslam1",))


def test_cli_calibrate_refuses_a_filter_without_a_known_map(capsys):
    assert cli.main(["mrclam", "--calibrate", "mcl", "--algorithms", "ekf_slam", "--out", ""]) == 2
    assert "--algorithms" in capsys.readouterr().err
