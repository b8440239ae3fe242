"""Landmark observation models: one protocol and its instances, for any landmark filter.

An :class:`ObservationModel` packs a sensor's measurement function ``h(pose, landmark)``,
its inverse (to initialise a landmark from one measurement), its noise covariance and
the circular components of a measurement; optional closed forms replace the generic
EKF update. FastSLAM (:mod:`jaxnav.slam.fastslam`) takes one as
``FastSLAMConfig.observation_model``; :data:`OBSERVATION_MODELS` names the built-in ones.

* :data:`RANGE_BEARING` — point landmarks seen by range and bearing
  (:mod:`jaxnav.models.landmarks`).
* :data:`HF_FOOTPRINT` — an HF-RFID reader's detection of a tag, its footprint as a
  Gaussian ([W] §3.2; :mod:`jaxnav.models.hf_rfid`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import kalman
from jaxnav.models import hf_rfid
from jaxnav.models import landmarks as lm

__all__ = ["ObservationModel", "RANGE_BEARING", "HF_FOOTPRINT", "OBSERVATION_MODELS"]


class ObservationModel(NamedTuple):
    """A landmark observation model (hashable: it lives in a filter's static config), used by FastSLAM.

    Attributes:
        name: label used in messages.
        obs_dim: ``dz``, size of one measurement.
        landmark_dim: ``D``, size of a landmark's state.
        mean: ``h(pose [3], landmark [D]) -> z [dz]``, smooth in both arguments.
        inverse: ``h⁻¹(pose [3], z [dz]) -> landmark [D]``, used to initialise.
        noise_cov: ``sensor_params -> R [dz, dz]``.
        angle_dims: components of ``z`` that are angles (residuals wrapped).
        validate: host-side check of the sensor parameters (raises ValueError).
        update: optional exact landmark update ``(pose, mean, cov, z, R) -> kalman.UpdateResult``
            used instead of the generic EKF (:func:`jaxnav.core.kalman.ekf_update` with the
            Jacobian of ``mean``), e.g. a closed form for a model linear in the landmark.
        initialise: optional ``(pose, z, R) -> (mean, cov)`` used instead of
            ``μ = h⁻¹(x, z)``, ``Σ = J R Jᵀ`` with ``J`` by automatic differentiation.
        pose_free_covariance: the landmark covariance that ``update`` and ``initialise`` return
            does not depend on the pose (``H_m`` constant and the noise, seen in the landmark's
            frame, pose-free). Every particle then holds the same covariance of a landmark, and
            FastSLAM keeps one per landmark (``FastSLAMConfig.covariance``).
    """

    name: str
    obs_dim: int
    landmark_dim: int
    mean: Callable[[jax.Array, jax.Array], jax.Array]
    inverse: Callable[[jax.Array, jax.Array], jax.Array]
    noise_cov: Callable[[Any], jax.Array]
    angle_dims: tuple[int, ...]
    validate: Callable[[Any], None]
    update: Callable[..., kalman.UpdateResult] | None = None
    initialise: Callable[..., tuple[jax.Array, jax.Array]] | None = None
    pose_free_covariance: bool = False


def _range_bearing_cov(sensor: lm.RangeBearingNoise) -> jax.Array:
    return jnp.diag(sensor.sd**2)


RANGE_BEARING = ObservationModel(
    "range_bearing", 2, 2, lm.predict, lm.inverse, _range_bearing_cov, (1,), lm.validate_noise
)
"""Point landmarks seen by range and bearing (:mod:`jaxnav.models.landmarks`), ``z = (r, φ)`` with the
bearing circular; sensor params :class:`jaxnav.models.landmarks.RangeBearingNoise`."""


HF_FOOTPRINT = ObservationModel(
    "hf_footprint",
    2,
    2,
    hf_rfid.robot_frame,
    hf_rfid.world_frame,
    hf_rfid.footprint_cov,
    (),
    hf_rfid.validate_params,
    hf_rfid.footprint_landmark_update,
    hf_rfid.footprint_landmark_initialise,
    pose_free_covariance=True,
)
"""The HF-RFID detection as a Gaussian measurement ([W] §3.2), ``z`` = the detecting reader's
position in the robot frame, ``h(x, m) = R(θ)ᵀ(m − p)``, ``R = diag(s²/12)`` for footprints of side ``s``.
Sensor params: :class:`jaxnav.models.hf_rfid.HFReaderParams`; observations:
:func:`jaxnav.models.hf_rfid.landmark_observations` of the detections. Its landmark update and
initialisation are in closed form (:func:`jaxnav.models.hf_rfid.footprint_landmark_update`); its landmark covariances do not depend on
the pose, so FastSLAM keeps one per landmark (``FastSLAMConfig.covariance``)."""

OBSERVATION_MODELS = {"range_bearing": RANGE_BEARING, "hf_footprint": HF_FOOTPRINT}
"""The built-in observation models by name (``"range_bearing"``, ``"hf_footprint"``)."""
