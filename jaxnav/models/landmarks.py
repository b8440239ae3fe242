"""Range-bearing observations of point landmarks.

**Overview**

A robot at pose ``x = (x, y, θ)`` observes landmark ``m = (m_x, m_y)`` as

    r = √((m_x − x)² + (m_y − y)²),   φ = atan2(m_y − y, m_x − x) − θ

(Thrun et al. eq. 6.40; [A] §2.1, the sensor of Algs. 1, 3, 4, 5), with
independent Gaussian noise of standard deviations ``(σ_r, σ_φ)`` in metres and
radians. The bearing residual is wrapped to ``[-π, π)`` before it is scored.

Observations of one step are a fixed-size :class:`RangeBearingObs` of ``K``
slots — landmark id, measurement, validity mask — so the number of landmarks
seen never changes an array shape. A slot whose mask is False, or whose id
is outside the map, contributes nothing (log-likelihood 0) and is counted by
:func:`lookup`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import fastmath, rng
from jaxnav.core.validation import (
    MAX_MAGNITUDE,
    all_positive,
    check_magnitude,
    check_positive,
    check_shape,
    check_slots,
    check_type,
    finite_within,
)
from jaxnav.core.weights import wrap_angle
from jaxnav.models import motion
from jaxnav.models.sensor import LandmarkSensor, ParticleSensor

__all__ = [
    "check_filter_inputs",
    "RangeBearingNoise",
    "RangeBearingObs",
    "predict",
    "inverse",
    "lookup",
    "log_likelihood",
    "validate_noise",
    "validate_observations",
    "LandmarkMapParams",
    "validate_map_params",
    "check_landmark_map",
    "validate_steps",
    "usable_measurements",
    "noise_in_domain",
    "filter_inputs_in_domain",
    "RANGE_BEARING_SENSOR",
    "log_density",
    "RANGE_BEARING_LANDMARK_SENSOR",
]


class RangeBearingNoise(NamedTuple):
    """Measurement noise.

    Attributes:
        sd: ``[2]`` standard deviations ``(σ_r [m], σ_φ [rad])``.
    """

    sd: jax.Array


class RangeBearingObs(NamedTuple):
    """One step's observations in ``K`` fixed slots (add a leading time axis for a sequence).

    Attributes:
        ids: ``[K]`` int32 landmark index into the map.
        z: ``[K, 2]`` measured ``(range [m], bearing [rad])``.
        mask: ``[K]`` bool, True where the slot holds a real observation.
    """

    ids: jax.Array
    z: jax.Array
    mask: jax.Array


def predict(pose: jax.Array, landmark: jax.Array) -> jax.Array:
    """Expected ``(range, bearing)`` of ``landmark [..., 2]`` from ``pose [..., 3]`` (broadcasting)."""
    dx = landmark[..., 0] - pose[..., 0]
    dy = landmark[..., 1] - pose[..., 1]
    r = jnp.sqrt(dx * dx + dy * dy)
    b = wrap_angle(fastmath.atan2(dy, dx) - pose[..., 2])
    return jnp.stack([r, b], axis=-1)


def inverse(pose: jax.Array, z: jax.Array) -> jax.Array:
    """Landmark position ``[..., 2]`` that would produce measurement ``z`` from ``pose``."""
    h = pose[..., 2] + z[..., 1]
    return jnp.stack([pose[..., 0] + z[..., 0] * jnp.cos(h), pose[..., 1] + z[..., 0] * jnp.sin(h)], axis=-1)


def lookup(landmark_map: jax.Array, obs: RangeBearingObs) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Landmark positions of the observed ids.

    Returns:
        ``(positions [K, 2], valid [K], num_ignored)`` — ``valid`` is the mask
        (nonzero = set) restricted to ids inside ``[0, M)`` and usable ``z``
        (:func:`usable_measurements`); ``num_ignored`` counts masked-in slots dropped
        for either reason (an id outside the map is never read out of bounds; a ``z``
        the host checks refuse for concrete inputs never reaches a filter).
    """
    mask, usable = _set_and_usable(landmark_map.shape[0], obs)
    valid = mask & usable
    # mode="clip" clamps an id outside the map (such a slot is invalid, its position unused); the
    # default "fill" adds a bounds select that XLA:CPU fuses into every [N, K] consumer, where it
    # would cost more than the rest of the likelihood.
    positions = jnp.take(landmark_map, obs.ids, axis=0, mode="clip")
    return positions, valid, jnp.sum(mask & ~usable).astype(jnp.int32)


def _set_and_usable(num_landmarks: int, obs: Any) -> tuple[jax.Array, jax.Array]:
    """``(mask, usable)`` ``[K]`` bool: the slot is set, and its id is a landmark of the map and its ``z`` usable."""
    mask = obs.mask.astype(bool)
    return mask, (obs.ids >= 0) & (obs.ids < num_landmarks) & usable_measurements(obs.z)


def usable_measurements(z: jax.Array) -> jax.Array:
    """``[K]`` bool: the slot's measurement ``z [K, D]`` is finite and at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE` in magnitude. The host checks refuse other
    values; inside a caller's ``jit`` the filters drop (and count) such slots instead."""
    return jnp.all(finite_within(z, MAX_MAGNITUDE), axis=-1)


def log_likelihood(
    poses: jax.Array,
    landmark_positions: jax.Array,
    z: jax.Array,
    valid: jax.Array,
    params: RangeBearingNoise,
) -> jax.Array:
    """``Σ_k log N(z_k; h(x, m_k), diag(σ²))`` over valid slots, for ``poses [..., 3]``.

    Args:
        poses: ``[..., 3]`` (e.g. ``[N, 3]`` particles).
        landmark_positions: ``[K, 2]``.
        z: ``[K, 2]`` measurements; entries of invalid slots are never read
            (NaN there is harmless, gradients included).
        valid: ``[K]`` bool.
        params: noise standard deviations.

    Returns:
        ``[...]`` log-likelihoods (normalised densities, so that a particle
        filter's marginal likelihood is a proper density).
    """
    z_safe = jnp.where(valid[:, None], z, 0.0)
    resid_r, resid_b = _residuals(poses, landmark_positions, z_safe)
    sd = params.sd
    # An invalid slot is switched off by per-slot constants (sd = ∞, log-normaliser 0: its term is
    # exactly 0), not by a select on each particle–slot term: XLA:CPU fuses the [K] constants
    # into the [N, K] loop, where a select on the [N, K] terms would cost about as much as the rest
    # of the likelihood. Valid slots compute the same expression.
    inf = jnp.asarray(jnp.inf, resid_r.dtype)
    sd_r, sd_b = jnp.where(valid, sd[0], inf), jnp.where(valid, sd[1], inf)
    log_norm = jnp.where(valid, -jnp.log(sd[0]) - jnp.log(sd[1]) - math.log(2.0 * math.pi), 0.0)
    return jnp.sum(log_norm - 0.5 * ((resid_r / sd_r) ** 2 + (resid_b / sd_b) ** 2), axis=-1)


def _residuals(poses: jax.Array, landmark_positions: jax.Array, z: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Range residual and wrapped bearing residual ``[..., K]`` with one ``atan2`` each.

    The bearing residual ``wrap(φ_z − φ̂)`` is the angle from the predicted
    direction to the measured one. With the landmark offset rotated into the
    robot frame, ``(p_x, p_y) = R(−θ)(m − x)``, and the measured direction
    ``(cos φ_z, sin φ_z)`` (computed once per landmark, not per particle),
    it is ``atan2(p_x sin φ_z − p_y cos φ_z, p_x cos φ_z + p_y sin φ_z)``: no
    wrapping, and one trigonometric call per particle–landmark pair (the cost
    that dominates an MCL step).
    """
    s, c = fastmath.sincos(poses[..., 2:3])  # [..., 1]
    dx = landmark_positions[:, 0] - poses[..., 0:1]  # [..., K]
    dy = landmark_positions[:, 1] - poses[..., 1:2]
    px = c * dx + s * dy
    py = c * dy - s * dx
    sz, cz = fastmath.sincos(z[:, 1])
    resid_r = z[:, 0] - jnp.sqrt(dx * dx + dy * dy)
    resid_b = fastmath.atan2(px * sz - py * cz, px * cz + py * sz)
    return resid_r, resid_b


def validate_noise(params: RangeBearingNoise, argument: str = "params.sensor") -> None:
    """Host-side check: a :class:`RangeBearingNoise` whose ``sd`` has shape ``[2]``, strictly positive and
    at most :data:`~jaxnav.core.validation.MAX_MAGNITUDE`."""
    check_type(argument, params, RangeBearingNoise)
    check_shape(f"{argument}.sd", params.sd, (2,))
    check_positive(f"{argument}.sd", params.sd)
    check_magnitude(f"{argument}.sd", params.sd)


def validate_observations(
    obs: RangeBearingObs, time_axis: bool, num_landmarks: int | None = None, obs_dim: int = 2
) -> None:
    """Host-side check of the observation slots (``[T, K]`` if ``time_axis``): shapes (``z [..., obs_dim]``),
    integer ids, a boolean (or integer) mask, and finite ``z`` in every valid slot whose id is a landmark
    of the map (``num_landmarks``; all valid slots when ``None``)."""
    lead = (None, None) if time_axis else (None,)
    check_shape("observations.ids", obs.ids, lead)
    check_shape("observations.mask", obs.mask, lead)
    check_shape("observations.z", obs.z, lead + (obs_dim,))
    if jnp.shape(obs.ids) != jnp.shape(obs.mask) or jnp.shape(obs.z)[:-1] != jnp.shape(obs.ids):
        raise ValueError(
            "observations.ids, .mask and .z must agree in their leading shape, got "
            f"{jnp.shape(obs.ids)}, {jnp.shape(obs.mask)}, {jnp.shape(obs.z)}"
        )
    check_slots("observations", obs.ids, obs.mask, obs.z, num_ids=num_landmarks)


# --------------------------------------------------------------------------- a filter on a known map


class LandmarkMapParams(NamedTuple):
    """Differentiable parameters of a filter on a known landmark map (MCL and its variants, grid, EKF, UKF).

    Attributes:
        motion: noise of the configured motion model (e.g. ``VelocityNoise``).
        sensor: range-bearing noise ``(σ_r [m], σ_φ [rad])``.
        landmarks: ``[M, 2]`` known landmark positions (m).
    """

    motion: Any
    sensor: RangeBearingNoise
    landmarks: jax.Array


def validate_map_params(motion_model: str | motion.MotionModel, params: Any) -> None:
    """Host-side check of the fields ``motion``, ``sensor`` and ``landmarks`` of ``params``: noise of
    ``motion_model``, a range-bearing noise, and at least one finite landmark ``[M, 2]`` (m)."""
    motion.validate_noise(motion_model, params.motion)
    _check_sensor_params(params)


def check_landmark_map(landmarks: Any, landmark_dim: int = 2) -> None:
    """Host-side check of a known map ``params.landmarks``: ``[M, landmark_dim]`` with ``M ≥ 1``, finite
    and at most :data:`~jaxnav.core.validation.MAX_MAGNITUDE` (m); raises ``ValueError`` naming it."""
    check_shape("params.landmarks", landmarks, (None, landmark_dim))
    if np.shape(landmarks)[0] < 1:
        raise ValueError("params.landmarks must hold at least one landmark")
    check_magnitude("params.landmarks", landmarks)


def _check_sensor_params(params: Any) -> None:
    """The fields ``sensor`` (a range-bearing noise) and ``landmarks`` (at least one finite ``[M, 2]``, m)."""
    validate_noise(params.sensor)
    check_landmark_map(params.landmarks)


def noise_in_domain(params: RangeBearingNoise) -> jax.Array:
    """``bool[]``, traceable: ``σ_r, σ_φ`` in ``(0, MAX_MAGNITUDE]``, the value check of :func:`validate_noise`
    as a ``jnp`` expression (a zero or negative σ divides the residual by zero or flips its sign)."""
    return all_positive(params.sd)


def filter_inputs_in_domain(config: Any, params: Any, control: jax.Array, obs: RangeBearingObs) -> jax.Array:
    """``bool[]``, traceable: a landmark-map filter's step inputs are in the models' domain (the
    ``valid_inputs`` of its :class:`~jaxnav.core.filter.FilterSpec`): the control
    (:func:`jaxnav.models.motion.controls_in_domain`), the motion noise
    (:func:`jaxnav.models.motion.noise_in_domain`) and the range-bearing noise (:func:`noise_in_domain`).
    The observations are not part of it: an unusable slot is dropped and counted (:func:`lookup`)."""
    del obs
    return (
        motion.controls_in_domain(control, config.motion_model)
        & motion.noise_in_domain(config.motion_model, params.motion)
        & noise_in_domain(params.sensor)
    )


def check_filter_inputs(config: Any, params: Any, controls: jax.Array, obs: RangeBearingObs, time_axis: bool) -> None:
    """The input check of every landmark-map filter (:class:`jaxnav.core.filter.FilterSpec`'s ``check_inputs``):
    :func:`validate_steps` with ``config.motion_model``."""
    landmarks = getattr(params, "landmarks", None)
    num_landmarks = np.shape(landmarks)[0] if landmarks is not None else getattr(config, "num_landmarks", None)
    validate_steps(config.motion_model, controls, obs, time_axis, num_landmarks)


def validate_steps(
    motion_model: str, controls: jax.Array, obs: RangeBearingObs, time_axis: bool, num_landmarks: int | None = None
) -> None:
    """Host-side check of one step's control and observations (``time_axis``: a sequence's, ``[T, ...]``):
    controls of ``motion_model``'s dimension, finite, and range-bearing observation slots of as many steps."""
    motion.validate_controls("controls" if time_axis else "control", controls, motion_model, time_axis)
    if not isinstance(obs, RangeBearingObs):
        raise ValueError(f"observations must be a RangeBearingObs, got {type(obs).__name__}")
    validate_observations(obs, time_axis, num_landmarks)
    if time_axis and np.shape(obs.ids)[0] != np.shape(controls)[0]:
        raise ValueError(
            f"controls and observations must have the same number of steps, got "
            f"{np.shape(controls)[0]} and {np.shape(obs.ids)[0]}"
        )


# --------------------------------------------------------------------------- the particle-sensor instance


def _map_log_likelihood(poses: jax.Array, obs: RangeBearingObs, params: Any) -> jax.Array:
    """``log p(z_t | x)`` for ``poses [N, 3]`` from the map ``params.landmarks`` and noise ``params.sensor``
    (:func:`lookup`, then :func:`log_likelihood`)."""
    positions, valid, _ = lookup(params.landmarks, obs)
    return log_likelihood(poses, positions, obs.z, valid, params.sensor)


def _map_num_ignored(obs: RangeBearingObs, params: Any) -> jax.Array:
    """The third output of :func:`lookup` without its gather of the positions."""
    mask, usable = _set_and_usable(params.landmarks.shape[0], obs)
    return jnp.sum(mask & ~usable).astype(jnp.int32)


def _map_check_observations(obs: RangeBearingObs, time_axis: bool, params: Any) -> None:
    if not isinstance(obs, RangeBearingObs):
        raise ValueError(f"observations must be a RangeBearingObs, got {type(obs).__name__}")
    validate_observations(obs, time_axis, np.shape(params.landmarks)[0])


def _map_params_in_domain(params: Any) -> jax.Array:
    return noise_in_domain(params.sensor)


RANGE_BEARING_SENSOR = ParticleSensor(
    "range_bearing",
    _map_log_likelihood,
    check_params=_check_sensor_params,
    check_observations=_map_check_observations,
    params_in_domain=_map_params_in_domain,
    num_ignored=_map_num_ignored,
)
"""Range-bearing observations of a known landmark map as a :class:`~jaxnav.models.sensor.ParticleSensor`,
the default sensor of MCL and its variants: observations :class:`RangeBearingObs`, parameters with the
fields ``sensor`` (:class:`RangeBearingNoise`) and ``landmarks`` (``[M, 2]``, m), as in
:class:`LandmarkMapParams`. A slot whose id is outside the map, or whose ``z`` is unusable, is dropped
and counted (:func:`lookup`)."""


# --------------------------------------------------------------------------- the landmark-sensor instance


def log_density(poses: jax.Array, landmarks: jax.Array, z: jax.Array, params: RangeBearingNoise) -> jax.Array:
    """``log N(z; h(x, m), diag(σ_r², σ_φ²))`` of one measurement ``z [2]`` for poses ``[..., 3]`` and
    landmarks ``[..., 2]`` (broadcasting: many poses and one landmark, or one pose and many landmarks),
    the bearing residual wrapped to ``[-π, π)``."""
    pred = predict(poses, landmarks)
    resid_r = z[0] - pred[..., 0]
    resid_b = wrap_angle(z[1] - pred[..., 1])
    sd = params.sd
    log_norm = -jnp.log(sd[0]) - jnp.log(sd[1]) - math.log(2.0 * math.pi)
    return log_norm - 0.5 * ((resid_r / sd[0]) ** 2 + (resid_b / sd[1]) ** 2)


def _landmark_log_likelihood(
    landmarks: jax.Array, pose: jax.Array, z: jax.Array, params: RangeBearingNoise
) -> jax.Array:
    return log_density(pose, landmarks, z, params)


def _initialise(key: jax.Array, pose: jax.Array, z: jax.Array, params: RangeBearingNoise, num: int) -> jax.Array:
    """``[num, 2]`` landmark particles ``h⁻¹(x, z + ε)``, ``ε ~ N(0, diag(σ²))``: the measurement's
    noise carried to the floor, a wedge around the measured point (the posterior of a landmark
    seen once, up to the Jacobian ``r`` of the polar map)."""
    noisy = z + rng.normal(key, (num, 2), pose.dtype) * params.sd
    return inverse(pose, noisy)


def _locate(
    u: jax.Array, heading: jax.Array, landmarks: jax.Array, z: jax.Array, params: RangeBearingNoise
) -> jax.Array:
    """``[N, 2]`` robot positions that see ``landmarks [N, 2]`` at ``z [N, 2]`` with ``heading [N]``,
    the range and bearing moved by a uniform error of their noise's standard deviation (``u [N, 2]``)."""
    spread = (2.0 * u - 1.0) * math.sqrt(3.0) * params.sd  # uniform of standard deviation σ
    r = z[:, 0] + spread[:, 0]
    direction = heading + z[:, 1] + spread[:, 1]
    return landmarks - r[:, None] * jnp.stack([jnp.cos(direction), jnp.sin(direction)], axis=-1)


def _slam_check_observations(obs: RangeBearingObs, time_axis: bool, params: RangeBearingNoise, name: str) -> None:
    if not isinstance(obs, RangeBearingObs):
        raise ValueError(f"{name} must be a RangeBearingObs, got {type(obs).__name__}")
    validate_observations(obs, time_axis)


RANGE_BEARING_LANDMARK_SENSOR = LandmarkSensor(
    "range_bearing",
    2,
    lambda obs, params: obs.z,
    _landmark_log_likelihood,
    log_density,
    _initialise,
    locate=_locate,
    check_params=validate_noise,
    check_observations=_slam_check_observations,
    params_in_domain=noise_in_domain,
    usable=lambda obs: usable_measurements(obs.z),
)
"""Range-bearing observations of unknown point landmarks as a :class:`~jaxnav.models.sensor.LandmarkSensor`
for PF-SLAM and PS-SLAM: observations :class:`RangeBearingObs` (``ids`` index the filter's table),
sensor parameters :class:`RangeBearingNoise`. A new landmark's particles are spread over the range
and bearing noise of its first measurement (:func:`log_density` is the density)."""
