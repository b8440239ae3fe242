"""The sensor seam of the particle filters: one protocol for the filters over poses, one for landmarks.

Pose filters (MCL and its variants) take a :class:`ParticleSensor`; the SLAM filters that keep a
particle set per landmark (PF-SLAM, PS-SLAM) take a :class:`LandmarkSensor` (at the end of this
module).

**Overview**

A particle filter over robot poses (MCL, augmented MCL, KLD-MCL) moves its particles with a motion
model (:class:`jaxnav.models.motion.MotionModel`) and weights them with a sensor model, a
:class:`ParticleSensor`. The filter takes both in its static configuration
(``MCLConfig(sensor=…, motion_model=…)``), so a new sensor is one object, never a new filter::

    def beacon_log_likelihood(particles, obs, params):       # particles [N, 3] → [N]
        r = jnp.linalg.norm(particles[:, :2] - params.beacon, axis=-1)
        return jnp.where(obs.seen, -0.5 * ((obs.r - r) / params.sd) ** 2, 0.0)

    BEACON = ParticleSensor("beacon", beacon_log_likelihood)

The docs' interface page runs such a sensor, written by a user, through MCL and KLD-MCL.

**The protocol.** A :class:`ParticleSensor` is a NamedTuple of functions (hashable: it lives in a
filter's static configuration, as :class:`jaxnav.models.observation.ObservationModel` does in
FastSLAM's). Only ``log_likelihood`` is required:

* ``log_likelihood(particles [N, 3], observation, params) -> [N]``: ``log p(z_t | x_t^i)`` (a
  normalised density, so that the filter's log marginal likelihood is one), traceable and
  differentiable in ``params``. ``params`` is the filter's whole parameter pytree; the filter reads
  its ``motion`` field, the sensor reads its own fields (the range-bearing sensor: ``sensor`` and
  ``landmarks``). A particle whose log-likelihood is NaN keeps its previous pose with zero weight
  (:func:`jaxnav.core.particle_filter.keep_finite`);
* ``check_params(params)``: host-side check of the sensor's fields, raising ``ValueError`` that
  names the field (default: none);
* ``check_observations(observation, time_axis, params)``: host-side check of one step's observation
  (``time_axis=False``) or a sequence's (``[T, ...]``) (default: none);
* ``params_in_domain(params) -> bool[]``: the value checks of ``check_params`` as a traceable
  ``jnp`` expression, for steps inside a caller's ``jit`` (``info.invalid_inputs``; default: true);
* ``num_ignored(observation, params) -> int32[]``: observation slots the likelihood dropped
  (``info.num_ignored``; default: 0);
* ``prepare(observation) -> observation``: host-side conversion after the checks (default: the
  observation unchanged).

The functions below apply a configuration's motion model and sensor together: the checks and the
domain test that every particle filter over poses registers in its
:class:`~jaxnav.core.filter.FilterSpec`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.models import motion

__all__ = [
    "ParticleSensor",
    "check_sensor",
    "LandmarkSensor",
    "check_landmark_sensor",
    "check_pose_filter_params",
    "check_pose_filter_inputs",
    "pose_filter_inputs_in_domain",
    "prepare_pose_filter_inputs",
]


def _no_check(*args: Any) -> None:
    del args


def _always_in_domain(params: Any) -> jax.Array:
    del params
    return jnp.asarray(True)


def _none_ignored(observation: Any, params: Any) -> jax.Array:
    del observation, params
    return jnp.zeros((), jnp.int32)


def _unchanged(observation: Any) -> Any:
    return observation


class ParticleSensor(NamedTuple):
    """A sensor model for particle filters over poses (see the module docstring for each function).

    Attributes:
        name: label used in messages.
        log_likelihood: ``(particles [N, 3], observation, params) -> [N]`` log-likelihoods.
        check_params: ``(params) -> None``, host-side, raises ``ValueError``.
        check_observations: ``(observation, time_axis, params) -> None``, host-side, raises ``ValueError``.
        params_in_domain: ``(params) -> bool[]``, traceable.
        num_ignored: ``(observation, params) -> int32[]``, traceable.
        prepare: ``(observation) -> observation``, host-side.
    """

    name: str
    log_likelihood: Callable[[jax.Array, Any, Any], jax.Array]
    check_params: Callable[[Any], None] = _no_check
    check_observations: Callable[[Any, bool, Any], None] = _no_check
    params_in_domain: Callable[[Any], jax.Array] = _always_in_domain
    num_ignored: Callable[[Any, Any], jax.Array] = _none_ignored
    prepare: Callable[[Any], Any] = _unchanged

    def __repr__(self) -> str:
        # the name alone: a config's repr (and its documented signature) stays one readable line
        return f"ParticleSensor({self.name!r})"


def check_sensor(name: str, sensor: object) -> None:
    """Configuration check: ``sensor`` is a :class:`ParticleSensor` with a callable ``log_likelihood``."""
    if not isinstance(sensor, ParticleSensor):
        raise ValueError(f"{name} must be a jaxnav.models.sensor.ParticleSensor, got {type(sensor).__name__}")
    for field in ParticleSensor._fields[1:]:
        if not callable(getattr(sensor, field)):
            raise ValueError(f"{name}.{field} of sensor {sensor.name!r} must be callable")


def check_pose_filter_params(config: Any, params: Any) -> None:
    """Host-side check of a pose filter's ``params``: ``params.motion`` is the noise of
    ``config.motion_model`` (:func:`jaxnav.models.motion.validate_noise`), then the sensor's own fields
    (``config.sensor.check_params``)."""
    if not hasattr(params, "motion"):
        raise ValueError(f"params must have a 'motion' field (the motion model's noise), got {type(params).__name__}")
    motion.validate_noise(config.motion_model, params.motion)
    config.sensor.check_params(params)


def check_pose_filter_inputs(config: Any, params: Any, controls: Any, observations: Any, time_axis: bool) -> None:
    """Host-side check of a pose filter's control(s) and observation(s) (``time_axis``: a sequence's,
    with a leading axis ``T`` on both): the controls of ``config.motion_model``
    (:func:`jaxnav.models.motion.validate_controls`), the observations by ``config.sensor``, and as
    many steps of each."""
    motion.validate_controls("controls" if time_axis else "control", controls, config.motion_model, time_axis)
    config.sensor.check_observations(observations, time_axis, params)
    if time_axis:
        leaves = jax.tree_util.tree_leaves(observations)
        num_obs = np.shape(leaves[0])[0] if leaves and np.ndim(leaves[0]) else None
        if num_obs is not None and num_obs != np.shape(controls)[0]:
            raise ValueError(
                f"controls and observations must have the same number of steps, got "
                f"{np.shape(controls)[0]} and {num_obs}"
            )


def pose_filter_inputs_in_domain(config: Any, params: Any, control: jax.Array, observation: Any) -> jax.Array:
    """``bool[]``, traceable: the control and motion noise are in ``config.motion_model``'s domain
    (:func:`jaxnav.models.motion.controls_in_domain`, :func:`~jaxnav.models.motion.noise_in_domain`)
    and the sensor's parameters in its own (``config.sensor.params_in_domain``). Observations are not
    part of it: a sensor drops and counts an unusable slot instead."""
    del observation
    return (
        motion.controls_in_domain(control, config.motion_model)
        & motion.noise_in_domain(config.motion_model, params.motion)
        & config.sensor.params_in_domain(params)
    )


def prepare_pose_filter_inputs(config: Any, control: Any, observation: Any) -> tuple[Any, Any]:
    """The host-side conversion of a pose filter's inputs (its ``FilterSpec.prepare``): half-precision
    floats promoted to float32 (:func:`jaxnav.core.filter.promote_half_precision`), then the sensor's
    ``prepare`` of the observation."""
    control, observation = filter_api.promote_half_precision(config, control, observation)
    return control, config.sensor.prepare(observation)


# --------------------------------------------------------------------------- landmark sensors


def _all_usable(observation: Any) -> jax.Array:
    return jnp.ones(jnp.shape(observation.mask), bool)


class LandmarkSensor(NamedTuple):
    """A landmark sensor for the SLAM filters that keep a particle set per landmark (PF-SLAM and
    PS-SLAM, :mod:`jaxnav.slam.tag_slam`): the density ``p(z | x, m)`` of one observation ``z`` of a
    landmark ``m`` (``[D]``, world frame) from a robot pose ``x`` (``[3]``), seen from either side,
    and how a landmark first seen is placed.

    One step's observation is a NamedTuple of ``K`` slots with fields ``ids [K]`` (the landmark, an
    index of the filter's table), ``mask [K]`` (the slot holds an observation) and the sensor's own
    fields. ``sensor_params`` below is the filter's ``params.sensor`` (differentiable).

    Attributes:
        name: label used in messages.
        landmark_dim: ``D``, the size of a landmark's state (2 for a point on the floor).
        measurements: ``(observation, sensor_params) -> z`` the slots' measurements, every leaf
            ``[K, ...]`` (HF: the detecting reader's offset; range and bearing: ``(r, φ)``), traceable.
        landmark_log_likelihood: ``(landmarks [J, D], pose [3], z_k, sensor_params) -> [J]``:
            ``log p(z_k | x, m_j)`` for one slot's ``z_k`` (a landmark's particles weighted).
        robot_log_likelihood: ``(poses [I, 3], landmark [D], z_k, sensor_params) -> [I]``: the same
            density with the roles swapped (robot particles weighted against a landmark estimate).
        initialise: ``(key, pose [3], z_k, sensor_params, num) -> [num, D]``: a new landmark's
            particles drawn from ``p(m | x, z_k)`` with a flat prior on ``m`` (a footprint, a ring, a
            range-bearing wedge).
        locate: ``(u [N, 2], heading [N], landmarks [N, D], z [N, ...], sensor_params) -> [N, 2]``:
            the robot position that puts landmark ``n`` at measurement ``z_n`` for a robot of that
            heading, two uniforms ``u`` on ``[0, 1)`` drawing what the measurement leaves free (the
            point of a footprint, the angle on a ring). Used by the kidnapping recovery; ``None``: the
            sensor cannot place the robot, and the filter needs ``recovery=False``.
        check_params: ``(sensor_params, argument) -> None``, host-side, raises ``ValueError`` naming
            ``argument`` (e.g. ``"params.sensor"``).
        check_observations: ``(observation, time_axis, sensor_params, name) -> None``, host-side: one
            step's slots (``time_axis=False``) or a sequence's ``[T, K, ...]``, raises ``ValueError``
            naming ``name``.
        params_in_domain: ``(sensor_params) -> bool[]``, the value checks of ``check_params`` as a
            traceable expression (``info.invalid_inputs`` inside a caller's ``jit``).
        usable: ``(observation) -> bool [K]``, traceable: the slot's measurement can be scored (for
            example finite); a set slot that is not is dropped and counted in ``info.num_ignored``.
    """

    name: str
    landmark_dim: int
    measurements: Callable[[Any, Any], Any]
    landmark_log_likelihood: Callable[[jax.Array, jax.Array, Any, Any], jax.Array]
    robot_log_likelihood: Callable[[jax.Array, jax.Array, Any, Any], jax.Array]
    initialise: Callable[[jax.Array, jax.Array, Any, Any, int], jax.Array]
    locate: Callable[..., jax.Array] | None = None
    check_params: Callable[[Any, str], None] = _no_check
    check_observations: Callable[[Any, bool, Any, str], None] = _no_check
    params_in_domain: Callable[[Any], jax.Array] = _always_in_domain
    usable: Callable[[Any], jax.Array] = _all_usable

    def __repr__(self) -> str:
        return f"LandmarkSensor({self.name!r})"


def check_landmark_sensor(name: str, sensor: object) -> None:
    """Configuration check: ``sensor`` is a :class:`LandmarkSensor` whose functions are callable and
    whose ``landmark_dim`` is a positive integer."""
    if not isinstance(sensor, LandmarkSensor):
        raise ValueError(f"{name} must be a jaxnav.models.sensor.LandmarkSensor, got {type(sensor).__name__}")
    if not isinstance(sensor.landmark_dim, int) or isinstance(sensor.landmark_dim, bool) or sensor.landmark_dim < 1:
        raise ValueError(
            f"{name}.landmark_dim of sensor {sensor.name!r} must be a positive int, got {sensor.landmark_dim!r}"
        )
    for field in LandmarkSensor._fields[2:]:
        value = getattr(sensor, field)
        if not (callable(value) or (field == "locate" and value is None)):
            raise ValueError(f"{name}.{field} of sensor {sensor.name!r} must be callable")
