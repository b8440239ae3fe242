"""Scoring of estimates against ground truth: trajectory and map errors.

* :func:`position_errors`, :func:`trajectory_rmse` — pose estimates ``[T, 3]``
  against the truth (heading residual wrapped).
* :func:`absolute_trajectory_error` — position RMSE after the best rigid
  alignment of the whole path (the ATE of Sturm et al., IROS 2012);
* :func:`align_rigid` — the least-squares rotation and translation taking one
  2-D point set onto another (Umeyama 1991 without scale; Horn 1987), and
  :func:`map_errors` — landmark errors raw and after that alignment. A SLAM
  map is only defined up to the frame it was started in; the aligned error
  measures its shape, the raw error adds the frame (gauge) drift.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_shape
from jaxnav.core.weights import wrap_angle

__all__ = [
    "TrajectoryError",
    "MapError",
    "position_errors",
    "trajectory_rmse",
    "absolute_trajectory_error",
    "align_rigid",
    "map_errors",
]


class TrajectoryError(NamedTuple):
    """Root-mean-square errors of a trajectory estimate.

    Attributes:
        position_rmse: ``√(mean ‖p̂ − p‖²)`` (m).
        heading_rmse: ``√(mean wrap(θ̂ − θ)²)`` (rad).
    """

    position_rmse: jax.Array
    heading_rmse: jax.Array


# ---------------------------------------------------------------------------
# files


def position_errors(estimates: jax.Array, truth: jax.Array) -> jax.Array:
    """Euclidean position error ``‖p̂_t − p_t‖`` (m) of poses ``[..., 3]`` (or ``[..., 2]``)."""
    estimates, truth = jnp.asarray(estimates), jnp.asarray(truth)
    d = estimates[..., :2] - truth[..., :2]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


def trajectory_rmse(estimates: jax.Array, truth: jax.Array, mask: jax.Array | None = None) -> TrajectoryError:
    """Position RMSE (m) and heading RMSE (rad, residual wrapped) of poses ``[T, 3]``.

    Args:
        estimates, truth: ``[T, 3]`` poses ``(x, y, θ)``.
        mask: optional ``[T]`` bool, the steps to score (all by default). An
            all-False mask gives 0.
    """
    check_shape("estimates", estimates, (None, 3))
    check_shape("truth", truth, np.shape(estimates))
    if mask is None:
        mask = np.ones(np.shape(estimates)[0], bool)
    check_shape("mask", mask, (np.shape(estimates)[0],))
    return _rmse(jnp.asarray(estimates), jnp.asarray(truth), jnp.asarray(mask))


@jax.jit
def _rmse(estimates: jax.Array, truth: jax.Array, mask: jax.Array) -> TrajectoryError:
    d = estimates - truth
    pos2 = d[:, 0] ** 2 + d[:, 1] ** 2
    head2 = wrap_angle(d[:, 2]) ** 2
    w = mask.astype(pos2.dtype)
    n = jnp.maximum(jnp.sum(w), 1.0)
    return TrajectoryError(jnp.sqrt(jnp.sum(w * pos2) / n), jnp.sqrt(jnp.sum(w * head2) / n))


class MapError(NamedTuple):
    """Landmark errors of a map estimate (over the landmarks in ``mask``).

    Attributes:
        rmse: ``√(mean ‖m̂ − m‖²)`` in the estimate's own frame (m).
        aligned_rmse: the same after the best rigid alignment (m).
        rotation: ``[2, 2]`` and translation ``[2]`` of that alignment (applied as ``R m̂ + t``).
        translation: see ``rotation``.
    """

    rmse: jax.Array
    aligned_rmse: jax.Array
    rotation: jax.Array
    translation: jax.Array


def align_rigid(source: jax.Array, target: jax.Array, mask: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Rotation ``R [2, 2]`` (det +1) and translation ``t [2]`` minimising ``Σ ‖R sᵢ + t − tᵢ‖²``.

    Closed form of Umeyama (1991) eqs. 39–42 without scale: the SVD of the
    cross-covariance of the centred points. ``mask [M]`` selects the points
    used (at least two distinct points are needed for a rotation).
    """
    source, target = jnp.asarray(source), jnp.asarray(target)
    w = jnp.ones(source.shape[0], source.dtype) if mask is None else jnp.asarray(mask, source.dtype)
    n = jnp.maximum(jnp.sum(w), 1.0)
    mu_s = jnp.sum(w[:, None] * source, axis=0) / n
    mu_t = jnp.sum(w[:, None] * target, axis=0) / n
    cross = ((target - mu_t) * w[:, None]).T @ (source - mu_s)
    u, _, vt = jnp.linalg.svd(cross)
    d = jnp.sign(jnp.linalg.det(u @ vt))
    rot = u @ jnp.diag(jnp.asarray([1.0, 1.0], source.dtype).at[1].set(d)) @ vt
    return rot, mu_t - rot @ mu_s


def map_errors(estimate: jax.Array, truth: jax.Array, mask: jax.Array | None = None) -> MapError:
    """Raw and rigidly aligned landmark RMSE of ``estimate [M, 2]`` against ``truth [M, 2]`` (m).

    Only the landmarks where ``mask`` is true are scored; with none, there is nothing to score and
    both errors are NaN (never 0).
    """
    check_shape("estimate", estimate, (None, 2))
    check_shape("truth", truth, np.shape(estimate))
    estimate, truth = jnp.asarray(estimate), jnp.asarray(truth)
    w = jnp.ones(estimate.shape[0], estimate.dtype) if mask is None else jnp.asarray(mask, estimate.dtype)
    n = jnp.maximum(jnp.sum(w), 1.0)
    rot, trans = align_rigid(estimate, truth, w)
    aligned = estimate @ rot.T + trans
    raw = jnp.sqrt(jnp.sum(w * jnp.sum((estimate - truth) ** 2, axis=-1)) / n)
    al = jnp.sqrt(jnp.sum(w * jnp.sum((aligned - truth) ** 2, axis=-1)) / n)
    scored = jnp.sum(w) > 0
    return MapError(jnp.where(scored, raw, jnp.nan), jnp.where(scored, al, jnp.nan), rot, trans)


def absolute_trajectory_error(estimates: jax.Array, truth: jax.Array) -> jax.Array:
    """Position RMSE (m) after rigidly aligning the estimated path to the true one (ATE, Sturm et al. 2012).

    A SLAM estimate that has the right shape in a rotated frame scores low
    here and high in :func:`trajectory_rmse`; a localization filter with a
    known map should score about the same in both.
    """
    check_shape("estimates", estimates, (None, 3))
    check_shape("truth", truth, np.shape(estimates))
    est, tru = jnp.asarray(estimates)[:, :2], jnp.asarray(truth)[:, :2]
    rot, trans = align_rigid(est, tru)
    d = est @ rot.T + trans - tru
    return jnp.sqrt(jnp.mean(jnp.sum(d * d, axis=-1)))
