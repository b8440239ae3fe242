"""jaxnav.metrics: trajectory and map errors."""

from __future__ import annotations

import numpy as np
import pytest

from jaxnav import metrics


def test_align_rigid_recovers_a_known_motion():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 10, (7, 2))
    th = 0.4
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    estimate = truth @ rot.T + np.array([1.5, -2.0])
    err = metrics.map_errors(estimate, truth)
    assert float(err.rmse) > 1.0
    assert float(err.aligned_rmse) < 1e-5
    np.testing.assert_allclose(np.asarray(err.rotation), rot.T, atol=1e-5)


def test_aligned_error_of_noisy_map_and_mask():
    """Alignment never increases the error; masked landmarks are not scored."""
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 10, (8, 2))
    estimate = truth + rng.normal(0, 0.1, truth.shape)
    estimate[3] += 50.0
    mask = np.ones(8, bool)
    mask[3] = False
    err = metrics.map_errors(estimate, truth, mask)
    assert float(err.aligned_rmse) <= float(err.rmse) < 0.2


def test_a_map_with_nothing_to_score_has_nan_errors_not_zero():
    truth = np.zeros((4, 2))
    err = metrics.map_errors(truth + 1.0, truth, np.zeros(4, bool))
    assert np.isnan(float(err.rmse)) and np.isnan(float(err.aligned_rmse))


def test_reflection_is_not_allowed():
    """A mirrored map cannot be aligned by a rotation (det R = +1)."""
    truth = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 2.0], [3.0, 3.0]])
    mirrored = truth * np.array([1.0, -1.0])
    err = metrics.map_errors(mirrored, truth)
    assert float(err.aligned_rmse) > 0.5
    assert np.linalg.det(np.asarray(err.rotation)) == pytest.approx(1.0, abs=1e-5)


def test_absolute_trajectory_error_removes_only_a_rigid_motion():
    t = np.linspace(0, 2 * np.pi, 50)
    truth = np.stack([3 * np.cos(t), 2 * np.sin(t), t], axis=-1)
    th = 0.5
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    rotated = truth.copy()
    rotated[:, :2] = truth[:, :2] @ rot.T + np.array([0.3, -0.2])
    assert float(metrics.trajectory_rmse(rotated, truth).position_rmse) > 0.5
    assert float(metrics.absolute_trajectory_error(rotated, truth)) < 1e-5
    bent = truth.copy()
    bent[25:, 0] += 0.4  # not a rigid motion: half the path shifted
    assert float(metrics.absolute_trajectory_error(bent, truth)) > 0.1
