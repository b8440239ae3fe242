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
* :data:`RANGE_ONLY` — a range to a beacon, with a bias (:mod:`jaxnav.models.range_only`); EKF
  and UKF localization take it, FastSLAM too, though one Gaussian cannot hold the ring a first
  range leaves (its initialisation is a guess, see the instance).
* :data:`RANGE_ONLY_RING` — the same range, for FastSLAM: a new beacon is spread around its ring
  over the particles, each particle holding one point of the ring.

EKF and UKF localization (``EKFConfig.observation_model``) and FastSLAM take any of them.

On a known map the same models weigh robot poses: :func:`known_map_sensor` turns any of them into
a :class:`~jaxnav.models.sensor.ParticleSensor` for MCL and its variants, and
:data:`HF_FOOTPRINT_MAP_SENSOR` is the HF footprint's (localization on a tag carpet of surveyed tags).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import kalman
from jaxnav.core.validation import check_choice
from jaxnav.core.weights import wrap_angle
from jaxnav.models import hf_rfid
from jaxnav.models import landmarks as lm
from jaxnav.models import range_only as ro
from jaxnav.models.sensor import ParticleSensor

__all__ = [
    "ObservationModel",
    "RANGE_BEARING",
    "HF_FOOTPRINT",
    "RANGE_ONLY",
    "RANGE_ONLY_RING",
    "OBSERVATION_MODELS",
    "spread_quantiles",
    "get_observation_model",
    "check_observation_model",
    "unbiased_measurements",
    "noise_in_domain",
    "known_map_sensor",
    "HF_FOOTPRINT_MAP_SENSOR",
]


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
        bias: optional ``sensor_params -> b [dz]``, an additive offset of the measurement,
            ``z = h(x, m) + b + noise``, differentiable in the parameters: the filters subtract it
            from ``z`` (:func:`unbiased_measurements`) before anything else.
        params_in_domain: optional ``sensor_params -> bool[]``, the value checks of ``validate``
            as a traceable expression (steps inside a caller's ``jit``); default: every noise
            variance positive (:func:`noise_in_domain`).
        initialise_spread: optional ``(pose, z, R, u, du) -> (mean, cov)``, used by FastSLAM instead
            of ``initialise`` when one measurement leaves a landmark on a curve rather than near a
            point: particle ``n`` gets its own point of the curve at quantile ``u ∈ (0, 1)``
            (:func:`spread_quantiles`, one per stratum of width ``du = 1/N``), so that together the particles
            hold the curve that no single Gaussian does.
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
    bias: Callable[[Any], jax.Array] | None = None
    params_in_domain: Callable[[Any], jax.Array] | None = None
    initialise_spread: Callable[..., tuple[jax.Array, jax.Array]] | None = None


def _mix32(h: jax.Array) -> jax.Array:
    """MurmurHash3's 32-bit finaliser: a bijection of ``uint32`` that scatters nearby inputs."""
    h = h ^ (h >> 16)
    h = h * jnp.uint32(0x85EBCA6B)
    h = h ^ (h >> 13)
    h = h * jnp.uint32(0xC2B2AE35)
    return h ^ (h >> 16)


def spread_quantiles(num_particles: int, landmark: jax.Array) -> jax.Array:
    """``[num_particles]`` quantiles in ``(0, 1)`` at which FastSLAM's particles place a new landmark
    (``ObservationModel.initialise_spread``): a Latin hypercube, ``u_n = (π_j(n) + ½) / N``.

    ``π_j`` is a permutation of ``0 … N − 1`` that depends on the landmark ``j`` (the ranks of a hash
    of ``(n, j)``), so each landmark's quantiles are exactly one per stratum ``[k/N, (k + 1)/N)`` — the
    ring is covered evenly, with no gap a random draw would leave — while the pairing of two
    landmarks' quantiles across the particles looks random: the ``N`` joint hypotheses of a particle
    set spread over the combinations instead of repeating one. Deterministic (no key, the same for
    every run) and exact in float32 and float64.
    """
    n = jnp.arange(num_particles, dtype=jnp.uint32)
    salt = _mix32(jnp.asarray(landmark).astype(jnp.uint32) + jnp.uint32(0x9E3779B9))
    rank = jnp.argsort(_mix32(n ^ salt))  # distinct hashes (a bijection of n): a permutation
    return (rank.astype(jnp.float32) + 0.5) / num_particles


def _range_bearing_cov(sensor: lm.RangeBearingNoise) -> jax.Array:
    return jnp.diag(sensor.sd**2)


RANGE_BEARING = ObservationModel(
    "range_bearing",
    2,
    2,
    lm.predict,
    lm.inverse,
    _range_bearing_cov,
    (1,),
    lm.validate_noise,
    params_in_domain=lm.noise_in_domain,
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
    params_in_domain=hf_rfid.reader_params_in_domain,
)
"""The HF-RFID detection as a Gaussian measurement ([W] §3.2), ``z`` = the detecting reader's
position in the robot frame, ``h(x, m) = R(θ)ᵀ(m − p)``, ``R = diag(s²/12)`` for footprints of side ``s``.
Sensor params: :class:`jaxnav.models.hf_rfid.HFReaderParams`; observations:
:func:`jaxnav.models.hf_rfid.landmark_observations` of the detections. Its landmark update and
initialisation are in closed form (:func:`jaxnav.models.hf_rfid.footprint_landmark_update`); its landmark covariances do not depend on
the pose, so FastSLAM keeps one per landmark (``FastSLAMConfig.covariance``)."""


def _range(pose: jax.Array, beacon: jax.Array) -> jax.Array:
    return ro.expected_range(pose[..., :2], beacon, 0.0)[..., None]


def _ahead(pose: jax.Array, z: jax.Array) -> jax.Array:
    """The point at range ``z`` straight ahead of the robot: a range alone does not say where."""
    s, c = jnp.sin(pose[..., 2]), jnp.cos(pose[..., 2])
    return pose[..., :2] + z[..., 0:1] * jnp.stack([c, s], axis=-1)


def _ring_gaussian(pose: jax.Array, z: jax.Array, r: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The Gaussian of a beacon seen once by its range ``ρ``: on the ring, straight ahead of the robot,
    with the ring's spread, ``cov = (ρ² / 2 + σ²) I`` (the second moment of a uniform ring about its
    centre; a guess that the next ranges must correct)."""
    var = 0.5 * z[0] * z[0] + r[0, 0]
    return _ahead(pose, z), jnp.eye(2, dtype=var.dtype) * var


def _range_cov(noise: ro.RangeNoise) -> jax.Array:
    return jnp.reshape(noise.sd * noise.sd, (1, 1))


RANGE_ONLY = ObservationModel(
    "range_only",
    1,
    2,
    _range,
    _ahead,
    _range_cov,
    (),
    ro.validate_noise,
    initialise=_ring_gaussian,
    bias=lambda noise: jnp.reshape(noise.bias, (1,)),
    params_in_domain=ro.noise_in_domain,
)
"""A range to a beacon with Gaussian noise and a bias, ``z = ‖m − p‖ + b + σε`` ``[1]`` (m); sensor params
:class:`jaxnav.models.range_only.RangeNoise` (its ``dof`` unused), observations
:class:`jaxnav.models.range_only.RangeObs`. EKF and UKF localization with known beacons use it as it
is. In FastSLAM a beacon seen for the first time becomes a Gaussian straight ahead of the robot at the
measured range, with the ring's spread (``(ρ²/2 + σ²) I``): one Gaussian cannot hold the ring, which is
why PF-SLAM and PS-SLAM's :data:`~jaxnav.models.range_only.RANGE_ONLY_LANDMARK_SENSOR` starts a particle
set along it."""


def _ring_point(pose: jax.Array, z: jax.Array, r: jax.Array, u: jax.Array, du: float) -> tuple[jax.Array, jax.Array]:
    """A beacon seen once by its range ``ρ``, as one particle's hypothesis: the point of the ring at the
    angle ``2πu`` (world frame), with the range's variance ``σ²`` across the ring and
    ``σ² + (2πρ·du)²`` along it (the particles' points are ``2πρ·du`` apart on the ring)."""
    angle = 2.0 * jnp.pi * u.astype(z.dtype)
    c, s = jnp.cos(angle), jnp.sin(angle)
    mean = pose[:2] + z[0] * jnp.stack([c, s])
    var_along = r[0, 0] + (2.0 * jnp.pi * z[0] * du) ** 2
    radial = jnp.stack([c, s])
    along = jnp.stack([-s, c])
    cov = r[0, 0] * jnp.outer(radial, radial) + var_along * jnp.outer(along, along)
    return mean, cov


RANGE_ONLY_RING = RANGE_ONLY._replace(name="range_only_ring", initialise_spread=_ring_point)
""":data:`RANGE_ONLY` with FastSLAM's new beacons spread around the ring of their first range: particle
``n`` places the beacon at the angle ``2πu_n`` (:func:`spread_quantiles`) with the range's variance across
the ring and its share of the ring along it, so the particle set together holds the ring and the ranges
that follow select the particles whose guess was right. The measurement model, and EKF and UKF with
known beacons, are :data:`RANGE_ONLY`'s."""

OBSERVATION_MODELS = {
    "range_bearing": RANGE_BEARING,
    "hf_footprint": HF_FOOTPRINT,
    "range_only": RANGE_ONLY,
    "range_only_ring": RANGE_ONLY_RING,
}
"""The built-in observation models by name (``"range_bearing"``, ``"hf_footprint"``, ``"range_only"``,
``"range_only_ring"``)."""


def get_observation_model(model: str | ObservationModel) -> ObservationModel:
    """``model`` itself, or the built-in model of that name (:data:`OBSERVATION_MODELS`)."""
    return model if isinstance(model, ObservationModel) else OBSERVATION_MODELS[model]


def check_observation_model(name: str, model: object) -> None:
    """Configuration check: a name in :data:`OBSERVATION_MODELS` or an :class:`ObservationModel`."""
    if not isinstance(model, ObservationModel):
        check_choice(name, model, OBSERVATION_MODELS)


def unbiased_measurements(model: ObservationModel, z: jax.Array, sensor_params: Any) -> jax.Array:
    """``z − b`` for a model with a ``bias`` (every leading axis of ``z [..., dz]``), else ``z`` itself."""
    if model.bias is None:
        return z
    return z - model.bias(sensor_params).astype(z.dtype)


def noise_in_domain(model: ObservationModel, sensor_params: Any) -> jax.Array:
    """``bool[]``, traceable: the model's own ``params_in_domain``, else every variance of its noise
    covariance positive and finite."""
    if model.params_in_domain is not None:
        return jnp.asarray(model.params_in_domain(sensor_params))
    diag = jnp.diag(model.noise_cov(sensor_params))
    return jnp.all((diag > 0) & jnp.isfinite(diag))


# --------------------------------------------------------------------------- a known map: pose sensors


@functools.cache
def known_map_sensor(model: ObservationModel) -> ParticleSensor:
    """Observations of landmarks at known positions through ``model``, as a
    :class:`~jaxnav.models.sensor.ParticleSensor` over poses ``[N, 3]``:

        log p(z_t | x) = Σ_k log N(z_k; h(x, m_{id_k}), R),   R = model.noise_cov(params.sensor),

    over the valid slots, the components of ``model.angle_dims`` of each residual wrapped to
    ``[-π, π)``. Parameters: any pytree with the fields ``sensor`` (the model's sensor parameters)
    and ``landmarks [M, D]`` (the map, m; and ``motion`` for the filter). Observations: ``ids [K]``,
    ``z [K, dz]`` and ``mask [K]``, e.g. :class:`jaxnav.models.landmarks.RangeBearingObs` or
    :class:`jaxnav.models.hf_rfid.ReaderObservations`; a slot whose id is not in the map, or whose
    ``z`` is unusable, is dropped and counted. Cached: one model gives one (hashable) sensor.

    For range and bearing, :data:`jaxnav.models.landmarks.RANGE_BEARING_SENSOR` computes the same
    density with one ``atan2`` per particle and landmark; this generic form evaluates ``h`` and
    factorises ``R``, for any model.
    """

    def residuals(particles: jax.Array, obs: Any, positions: jax.Array) -> jax.Array:
        pred = jax.vmap(jax.vmap(model.mean, (None, 0)), (0, None))(particles, positions)  # [N, K, dz]
        r = obs.z[None] - pred
        for d in model.angle_dims:
            r = r.at[..., d].set(wrap_angle(r[..., d]))
        return r

    def log_likelihood(particles: jax.Array, obs: Any, params: Any) -> jax.Array:
        positions, valid, _ = lm.lookup(params.landmarks, obs)
        obs = obs._replace(z=jnp.where(valid[:, None], obs.z, 0.0))
        r = residuals(particles, obs, positions)
        chol = jnp.linalg.cholesky(model.noise_cov(params.sensor).astype(r.dtype))
        white = jax.scipy.linalg.solve_triangular(chol, jnp.moveaxis(r, -1, 0).reshape(model.obs_dim, -1), lower=True)
        maha = jnp.sum(white * white, axis=0).reshape(r.shape[:-1])  # [N, K]
        log_norm = jnp.sum(jnp.log(jnp.diag(chol))) + 0.5 * model.obs_dim * math.log(2.0 * math.pi)
        return jnp.sum(jnp.where(valid, -0.5 * maha - log_norm, 0.0), axis=-1)

    def check_params(params: Any) -> None:
        model.validate(params.sensor)
        lm.check_landmark_map(params.landmarks, model.landmark_dim)

    def check_observations(obs: Any, time_axis: bool, params: Any) -> None:
        if not all(hasattr(obs, field) for field in ("ids", "z", "mask")):
            raise ValueError(f"observations must have the fields ids, z and mask, got {type(obs).__name__}")
        lm.validate_observations(obs, time_axis, np.shape(params.landmarks)[0], model.obs_dim)

    def params_in_domain(params: Any) -> jax.Array:
        return jnp.all(jnp.diag(model.noise_cov(params.sensor)) > 0)

    return ParticleSensor(
        f"{model.name}_on_a_known_map",
        log_likelihood,
        check_params=check_params,
        check_observations=check_observations,
        params_in_domain=params_in_domain,
        num_ignored=lambda obs, params: lm.lookup(params.landmarks, obs)[2],
    )


HF_FOOTPRINT_MAP_SENSOR = known_map_sensor(HF_FOOTPRINT)
"""HF-RFID detections of surveyed tags as a pose sensor (:func:`known_map_sensor` of :data:`HF_FOOTPRINT`):
parameters with ``sensor`` (:class:`jaxnav.models.hf_rfid.HFReaderParams`) and ``landmarks`` (the tag
positions, e.g. :func:`jaxnav.sim.tag_carpet.tag_positions`), observations
:func:`jaxnav.models.hf_rfid.landmark_observations` of the detections."""
