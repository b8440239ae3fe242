"""Range-only beacons: a range with a bias and Gaussian or Student-t noise.

**Overview**

A robot at ``x = (x, y, θ)`` measures its distance to a beacon (a UWB anchor, a radio tag) at
``m = (m_x, m_y)`` as

    z = ‖m − (x, y)‖ + b + σ·ε,

with a bias ``b`` (m; UWB ranges read long, by about 0.1 m in the TU Chemnitz data) and noise
``ε`` either standard normal or Student-t with ``ν`` degrees of freedom, whose heavy tails make
the occasional non-line-of-sight range (half a metre too long) an outlier instead of a
catastrophe. ``σ``, ``b`` and ``ν`` are fields of :class:`RangeNoise`, a differentiable pytree:
all three can be learned from data.

One range does not pin a beacon down: seen once it lies anywhere on a ring around the robot.
No single Gaussian (EKF-SLAM, FastSLAM) represents a ring; a particle set per beacon (PF-SLAM,
PS-SLAM) does, and :data:`RANGE_ONLY_LANDMARK_SENSOR` starts a new beacon's particles along it.

Observations are :class:`RangeObs` slots (``z [K, 1]``, the same layout as range-bearing slots,
so :func:`jaxnav.models.landmarks.lookup` and the slot checks serve both).

Instances:

* :data:`RANGE_ONLY_SENSOR`, :data:`RANGE_ONLY_T_SENSOR` — beacons at known positions as
  :class:`~jaxnav.models.sensor.ParticleSensor`\\ s (MCL, augmented and KLD-MCL): parameters with the
  fields ``sensor`` (:class:`RangeNoise`) and ``landmarks`` (``[M, 2]``, m).
* :data:`RANGE_ONLY_LANDMARK_SENSOR`, :data:`RANGE_ONLY_T_LANDMARK_SENSOR` — unknown beacons as
  :class:`~jaxnav.models.sensor.LandmarkSensor`\\ s (PF-SLAM, PS-SLAM): ``params.sensor`` a
  :class:`RangeNoise`.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.validation import all_positive, check_finite, check_positive, check_shape, check_type
from jaxnav.models import landmarks as lm
from jaxnav.models.sensor import LandmarkSensor, ParticleSensor

__all__ = [
    "RangeNoise",
    "RangeObs",
    "range_noise",
    "expected_range",
    "log_density",
    "validate_noise",
    "noise_in_domain",
    "RANGE_ONLY_SENSOR",
    "RANGE_ONLY_T_SENSOR",
    "RANGE_ONLY_LANDMARK_SENSOR",
    "RANGE_ONLY_T_LANDMARK_SENSOR",
]


class RangeNoise(NamedTuple):
    """Range measurement model (a differentiable pytree of scalars).

    Attributes:
        sd: ``σ`` (m), the noise scale (the standard deviation for Gaussian noise).
        bias: ``b`` (m), added to the true distance.
        dof: ``ν`` of the Student-t noise (> 0); read only by the Student-t sensors.
    """

    sd: jax.Array
    bias: jax.Array
    dof: jax.Array


class RangeObs(NamedTuple):
    """One step's range measurements in ``K`` fixed slots (a leading time axis for a sequence).

    Attributes:
        ids: ``[K]`` int32 beacon index (into the known map, or the SLAM filter's table).
        z: ``[K, 1]`` measured range (m).
        mask: ``[K]`` bool, True where the slot holds a measurement.
    """

    ids: jax.Array
    z: jax.Array
    mask: jax.Array


def range_noise(sd: float, bias: float = 0.0, dof: float = 4.0, dtype: Any = jnp.float32) -> RangeNoise:
    """A checked :class:`RangeNoise`: ``sd > 0`` m, a finite ``bias`` (m), ``dof > 0``."""
    noise = RangeNoise(*(jnp.asarray(v, dtype) for v in (sd, bias, dof)))
    validate_noise(noise, "range_noise")
    return noise


def validate_noise(params: RangeNoise, argument: str = "params.sensor") -> None:
    """Host-side check: a :class:`RangeNoise` of scalars, ``sd`` and ``dof`` positive, ``bias`` finite."""
    check_type(argument, params, RangeNoise)
    for field in RangeNoise._fields:
        check_shape(f"{argument}.{field}", getattr(params, field), ())
    check_positive(f"{argument}.sd", params.sd)
    check_finite(f"{argument}.bias", params.bias)
    check_positive(f"{argument}.dof", params.dof)


def noise_in_domain(params: RangeNoise) -> jax.Array:
    """``bool[]``, traceable: the value checks of :func:`validate_noise` (``sd`` and ``dof`` in
    ``(0, MAX_MAGNITUDE]``, ``bias`` finite)."""
    return all_positive(params.sd) & all_positive(params.dof) & jnp.isfinite(params.bias)


def expected_range(positions: jax.Array, beacons: jax.Array, bias: jax.Array) -> jax.Array:
    """``‖m − p‖ + b`` for positions ``[..., 2]`` and beacons ``[..., 2]`` (broadcasting; m)."""
    dx = beacons[..., 0] - positions[..., 0]
    dy = beacons[..., 1] - positions[..., 1]
    return jnp.sqrt(dx * dx + dy * dy) + bias


def log_density(residual: jax.Array, params: RangeNoise, heavy_tailed: bool) -> jax.Array:
    """Log-density of a range residual ``e = z − (‖m − p‖ + b)`` (m⁻¹, normalised):

    * Gaussian: ``−½(e/σ)² − log σ − ½ log 2π``;
    * Student-t (``heavy_tailed``): ``log Γ((ν+1)/2) − log Γ(ν/2) − ½ log(νπ) − log σ
      − (ν+1)/2 · log(1 + (e/σ)²/ν)``.
    """
    u = residual / params.sd
    if not heavy_tailed:
        return -0.5 * u * u - jnp.log(params.sd) - 0.5 * math.log(2.0 * math.pi)
    nu = params.dof
    # log Γ((ν+1)/2) − log Γ(ν/2) = log Γ(½) − log B(ν/2, ½): the difference of two log Γ of
    # about ν log ν loses every digit in float32 for large ν (0.06 off at ν = 10⁶); betaln does not.
    half = jnp.asarray(0.5, u.dtype)
    log_norm = (
        jax.scipy.special.gammaln(half)
        - jax.scipy.special.betaln(0.5 * nu, half)
        - 0.5 * jnp.log(nu * math.pi)
        - jnp.log(params.sd)
    )
    return log_norm - 0.5 * (nu + 1.0) * jnp.log1p(u * u / nu)


def _check_observations(obs: Any, time_axis: bool, num_beacons: int | None, name: str) -> None:
    if not isinstance(obs, RangeObs):
        raise ValueError(f"{name} must be a RangeObs (z [K, 1] ranges in m), got {type(obs).__name__}")
    lm.validate_observations(obs, time_axis, num_beacons, obs_dim=1)


# --------------------------------------------------------------------------- beacons at known positions


@functools.cache
def _map_sensor(heavy_tailed: bool) -> ParticleSensor:
    def log_likelihood(particles: jax.Array, obs: RangeObs, params: Any) -> jax.Array:
        positions, valid, _ = lm.lookup(params.landmarks, obs)
        z = jnp.where(valid, obs.z[:, 0], 0.0)
        resid = z - expected_range(particles[:, None, :2], positions, params.sensor.bias)  # [N, K]
        return jnp.sum(jnp.where(valid, log_density(resid, params.sensor, heavy_tailed), 0.0), axis=-1)

    def check_params(params: Any) -> None:
        validate_noise(params.sensor)
        lm.check_landmark_map(params.landmarks)

    return ParticleSensor(
        "range_only_t" if heavy_tailed else "range_only",
        log_likelihood,
        check_params=check_params,
        check_observations=lambda obs, time_axis, params: _check_observations(
            obs, time_axis, np.shape(params.landmarks)[0], "observations"
        ),
        params_in_domain=lambda params: noise_in_domain(params.sensor),
        num_ignored=lambda obs, params: lm.lookup(params.landmarks, obs)[2],
    )


RANGE_ONLY_SENSOR = _map_sensor(False)
"""Ranges to beacons at known positions with Gaussian noise, as a pose sensor, ``log p(z | x) = Σ_k
log N(z_k; ‖m_k − p‖ + b, σ²)`` over the valid slots. Parameters with the fields ``sensor``
(:class:`RangeNoise`) and ``landmarks`` (``[M, 2]``, m); observations :class:`RangeObs`."""

RANGE_ONLY_T_SENSOR = _map_sensor(True)
"""As :data:`RANGE_ONLY_SENSOR` with Student-t noise of ``ν = params.sensor.dof`` degrees of freedom."""


# --------------------------------------------------------------------------- unknown beacons


def _ring(angle: jax.Array, radius: jax.Array) -> jax.Array:
    return radius[..., None] * jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)


@functools.cache
def _landmark_sensor(heavy_tailed: bool) -> LandmarkSensor:
    def beacon_log_likelihood(beacons: jax.Array, pose: jax.Array, z: jax.Array, params: RangeNoise) -> jax.Array:
        return log_density(z[0] - expected_range(pose[:2], beacons, params.bias), params, heavy_tailed)

    def robot_log_likelihood(poses: jax.Array, beacon: jax.Array, z: jax.Array, params: RangeNoise) -> jax.Array:
        return log_density(z[0] - expected_range(poses[:, :2], beacon, params.bias), params, heavy_tailed)

    def initialise(key: jax.Array, pose: jax.Array, z: jax.Array, params: RangeNoise, num: int) -> jax.Array:
        """A ring around the robot: angle uniform, radius ``z − b + σ·ε`` (``ε`` standard normal, the
        radius kept ≥ 0)."""
        k_angle, k_radius = jax.random.split(key)
        angle = rng.uniform(k_angle, (num,), pose.dtype, 0.0, 2.0 * math.pi)
        radius = jnp.maximum(z[0] - params.bias + params.sd * rng.normal(k_radius, (num,), pose.dtype), 0.0)
        return pose[:2] + _ring(angle, radius)

    def locate(u: jax.Array, heading: jax.Array, beacons: jax.Array, z: jax.Array, params: RangeNoise) -> jax.Array:
        """The robot anywhere on the ring of radius ``z − b`` (± a uniform error of σ) around the beacon."""
        del heading  # a range says nothing about the heading
        radius = jnp.maximum(z[:, 0] - params.bias + (2.0 * u[:, 1] - 1.0) * math.sqrt(3.0) * params.sd, 0.0)
        return beacons - _ring(2.0 * math.pi * u[:, 0], radius)

    return LandmarkSensor(
        "range_only_t" if heavy_tailed else "range_only",
        2,
        lambda obs, params: obs.z,
        beacon_log_likelihood,
        robot_log_likelihood,
        initialise,
        locate=locate,
        check_params=validate_noise,
        check_observations=lambda obs, time_axis, params, name: _check_observations(obs, time_axis, None, name),
        params_in_domain=noise_in_domain,
        usable=lambda obs: lm.usable_measurements(obs.z),
    )


RANGE_ONLY_LANDMARK_SENSOR = _landmark_sensor(False)
"""Ranges to unknown beacons with Gaussian noise, as a landmark sensor for PF-SLAM and PS-SLAM. Observations
:class:`RangeObs` (``ids`` index the filter's table), ``params.sensor`` a :class:`RangeNoise`. A new
beacon's particles lie along the ring of its first range."""

RANGE_ONLY_T_LANDMARK_SENSOR = _landmark_sensor(True)
"""As :data:`RANGE_ONLY_LANDMARK_SENSOR` with Student-t noise of ``ν = params.sensor.dof`` degrees of freedom."""
