"""The UWB range model's bias and spread learned from the log's first half
(jaxnav.experiments.uwb.calibration), and jaxnav.io.uwb.segment. The data is read from ``$JAXNAV_DATA``
(default ``../shared/data``); the tests skip, saying so, only when the folder is absent."""

from __future__ import annotations

import numpy as np
import pytest

from jaxnav.io import uwb as data

try:
    data.data_dir()
    _MISSING = None
except FileNotFoundError as err:  # pragma: no cover - depends on the machine
    _MISSING = str(err)

pytestmark = pytest.mark.skipif(_MISSING is not None, reason=f"UWB data not found: {_MISSING}")


def test_halves_start_where_the_robot_is():
    from jaxnav.experiments.uwb import calibration as cal

    seq = data.load_labyrinth()
    first, second = cal.halves(seq)
    assert first.times.size + second.times.size == seq.times.size
    np.testing.assert_array_equal(first.initial_pose, seq.initial_pose)
    np.testing.assert_array_equal(second.initial_pose[:2], seq.true_positions[first.times.size])
    assert second.controls[0, 2] == 0.0 and np.all(second.controls[1:, 2] > 0)
    np.testing.assert_array_equal(second.observations.z, seq.observations.z[first.times.size :])
    with pytest.raises(ValueError, match="start"):
        data.segment(seq, 5, 5)


@pytest.mark.slow
def test_the_learned_bias_localises_as_the_given_one_and_better_than_none():
    """The EKF's likelihood on the first half learns a bias near the residuals' +0.12 m (measured: 0.107 m)
    and a spread of 0.097 m; on the second half the EKF with it is as good as with the hand-set model
    (0.080 m both, measured) and better than without a bias (0.161 m)."""
    from jaxnav.experiments.uwb import calibration as cal

    fit, rows = cal.run_study("ekf", algorithms=("ekf",), runs=1)
    assert 0.05 < fit.settings.range_bias < 0.2 and 0.03 < fit.settings.range_sd < 0.3
    assert fit.result.losses[-1] < fit.result.losses[0]
    error = {r.label: float(np.mean(r.position_error)) for r in rows}
    assert error["learned"] < 0.75 * error["no bias"], error
    assert error["learned"] < 1.1 * error["given"], error
    assert "| EKF | learned |" in cal.format_table(rows)


def test_unknown_method_is_refused():
    from jaxnav.experiments.uwb import calibration as cal

    with pytest.raises(ValueError, match="method"):
        cal.fit_range_noise(None, method="ukf")


def test_cli_calibrate_refuses_an_unknown_algorithm(capsys):
    from jaxnav import cli

    assert cli.main(["uwb", "--calibrate", "ekf", "--algorithms", "kalman"]) == 2
    assert "--algorithms" in capsys.readouterr().err
