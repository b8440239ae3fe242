"""HF-RFID reader arrays and the detection model of [W] eq. 3.7.

**Overview**

``B`` HF readers sit under the robot ([W] §3.1, Fig. 3.2c), reader ``b`` at
``offsets[b]`` in the robot frame (x forward, y left, metres). A reader
detects a floor tag when the tag lies in its square footprint of side
``s = 2σ`` (60 mm in [W] ch. 3, 100–500 mm in [W] §4.4.3); the footprint
turns with the robot. The default layout (:func:`default_reader_offsets`)
is two rows of four readers at 60 mm pitch centred on the robot.

Detection likelihood, [W] eq. 3.7, in log form. With ``e = ʳm − ʳb`` the
tag's position minus the detecting reader's position, both in the robot
frame::

    log w(e) = 0                          if |e_x| < σ and |e_y| < σ
    log w(e) = log β − eᵀe / (2σ²)        otherwise

[W] leaves β "a constant"; the default β = 0.1 makes the likelihood a near
indicator of the footprint (at most ``0.1·e^{-1/2} ≈ 0.06`` outside) with
Gaussian tails, so a particle set that has drifted wholly outside still has
an ordering instead of a tie. The same function scores tag particles (a
tag's particles against one robot pose, :func:`tag_log_likelihood`) and
robot particles (many poses against one tag estimate,
:func:`robot_log_likelihood`).

FastSLAM cannot use a step likelihood; its per-particle EKF sees the
detection as a measurement ``z = ʳb`` (the detecting reader's position in
the robot frame) of the tag's robot-frame position ``h(x, m) = R(θ)ᵀ(m − p)``
with the footprint replaced by the Gaussian of the same variance: a uniform
square of side ``s`` has variance ``s²/12 = σ²/3`` per axis.
:func:`robot_frame`, :func:`world_frame` and :func:`footprint_cov` are that
model's pieces (``jaxnav.models.observation.HF_FOOTPRINT``), with its landmark update
and initialisation in closed form (:func:`footprint_landmark_update`,
:func:`footprint_landmark_initialise`); :func:`landmark_observations` turns detections
into its observation slots.

Detections of one step are fixed slots (:class:`TagDetections`): tag ID,
reader index and a validity mask, so the number of tags seen never changes
an array shape.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import fastmath, rng
from jaxnav.core.kalman import UpdateResult, ensure_pd, symmetrize
from jaxnav.core.validation import (
    all_positive,
    check_finite,
    check_positive,
    check_positive_int,
    check_shape,
    check_slots,
    first_index,
    is_concrete,
)
from jaxnav.models.sensor import LandmarkSensor

__all__ = [
    "HF_TAG_SENSOR",
    "HFReaderParams",
    "TagDetections",
    "ReaderObservations",
    "DEFAULT_BETA",
    "default_reader_offsets",
    "reader_params",
    "validate_params",
    "reader_params_in_domain",
    "validate_detections",
    "robot_frame",
    "world_frame",
    "log_detection_likelihood",
    "tag_log_likelihood",
    "robot_log_likelihood",
    "sample_in_footprint",
    "footprint_cov",
    "footprint_landmark_update",
    "footprint_landmark_initialise",
    "landmark_observations",
    "log_soft_inside",
    "soft_inside",
    "TagMap",
    "soft_detection_log_likelihood",
]

DEFAULT_BETA = 0.1
"""β of [W] eq. 3.7 (the thesis gives no value; see the module docstring)."""


class HFReaderParams(NamedTuple):
    """Reader array and detection model (a differentiable pytree).

    Attributes:
        offsets: ``[B, 2]`` reader centres in the robot frame (m).
        half_width: σ of [W] eq. 3.7, half the footprint side (m); 0.03 for 60 mm readers.
        log_beta: ``log β`` of [W] eq. 3.7 (β ≤ 1).
    """

    offsets: jax.Array
    half_width: jax.Array
    log_beta: jax.Array

    @property
    def num_readers(self) -> int:
        return int(np.shape(self.offsets)[0])


class TagDetections(NamedTuple):
    """One step's detections in ``K`` fixed slots (a leading time axis for a sequence).

    Attributes:
        ids: ``[K]`` int32 tag ID (the filters' tag-table slot).
        readers: ``[K]`` int32 index of the detecting reader into ``offsets``.
        mask: ``[K]`` bool, True where the slot holds a detection.
    """

    ids: jax.Array
    readers: jax.Array
    mask: jax.Array


class ReaderObservations(NamedTuple):
    """Detections as landmark observations for FastSLAM: ``z`` = detecting reader's offset.

    Attributes:
        ids: ``[K]`` tag ID.
        z: ``[K, 2]`` the detecting reader's position in the robot frame (m).
        mask: ``[K]`` bool.
    """

    ids: jax.Array
    z: jax.Array
    mask: jax.Array


def default_reader_offsets(rows: int = 2, cols: int = 4, pitch: float = 0.06) -> jax.Array:
    """``[rows·cols, 2]`` reader centres on a grid of ``pitch`` (m) centred on the robot.

    Rows run along the robot's y axis, columns along x; the default is two
    rows of four at 60 mm, reader ``b = r·cols + c``.
    """
    rows, cols = check_positive_int("rows", rows), check_positive_int("cols", cols)
    if not pitch > 0:
        raise ValueError(f"pitch must be > 0 m, got {pitch!r}")
    xs = (np.arange(cols) - (cols - 1) / 2.0) * pitch
    ys = (np.arange(rows) - (rows - 1) / 2.0) * pitch
    grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1).reshape(-1, 2)
    return jnp.asarray(grid, jnp.float32)


def reader_params(side: float = 0.06, offsets: Any = None, beta: float = DEFAULT_BETA) -> HFReaderParams:
    """:class:`HFReaderParams` for square footprints of ``side`` metres (σ = side/2).

    Args:
        side: footprint side (m): 0.06 in [W] ch. 3, 0.1–0.5 in [W] §4.4.3.
        offsets: ``[B, 2]`` reader centres (m); default :func:`default_reader_offsets`.
        beta: β of [W] eq. 3.7, in (0, 1].
    """
    if not side > 0:
        raise ValueError(f"side (the reader footprint) must be > 0 m, got {side!r}; [W] uses 0.06 to 0.5")
    if not 0 < beta <= 1:
        raise ValueError(f"beta must be in (0, 1], got {beta!r}")
    off = default_reader_offsets() if offsets is None else jnp.asarray(offsets, jnp.float32)
    params = HFReaderParams(off, jnp.asarray(side / 2.0, jnp.float32), jnp.asarray(math.log(beta), jnp.float32))
    validate_params(params)
    return params


def validate_params(params: HFReaderParams, argument: str = "params.sensor") -> None:
    """Host-side check: ``offsets [B, 2]`` finite, ``half_width > 0``, ``log_beta ≤ 0``."""
    if not isinstance(params, HFReaderParams):
        raise ValueError(
            f"{argument} must be an HFReaderParams (see hf_rfid.reader_params), got {type(params).__name__}"
        )
    check_shape(f"{argument}.offsets", params.offsets, (None, 2))
    if np.shape(params.offsets)[0] < 1:
        raise ValueError(f"{argument}.offsets must hold at least one reader")
    check_finite(f"{argument}.offsets", params.offsets)
    check_shape(f"{argument}.half_width", params.half_width, ())
    check_positive(f"{argument}.half_width", params.half_width)
    check_shape(f"{argument}.log_beta", params.log_beta, ())
    check_finite(f"{argument}.log_beta", params.log_beta)
    lb = np.asarray(params.log_beta) if not isinstance(params.log_beta, jax.core.Tracer) else None
    if lb is not None and lb > 0:
        raise ValueError(f"{argument}.log_beta must be ≤ 0 (β ≤ 1), got {float(lb)}")


def reader_params_in_domain(params: HFReaderParams) -> jax.Array:
    """``bool[]``, traceable: ``half_width`` in ``(0, MAX_MAGNITUDE]`` and ``log β ≤ 0``, the value
    checks of :func:`validate_params` as a ``jnp`` expression for use inside a ``jit`` (a zero or
    negative σ divides [W] eq. 3.7's residual by zero or flips the footprint)."""
    return all_positive(params.half_width) & jnp.all(jnp.asarray(params.log_beta) <= 0)


def validate_detections(
    det: TagDetections, time_axis: bool, num_readers: int | None = None, name: str = "observations"
) -> None:
    """Host-side check of a :class:`TagDetections` (shapes; reader indices when concrete)."""
    for field in ("ids", "readers", "mask"):
        if not hasattr(det, field):
            raise ValueError(f"{name} must be a TagDetections with fields ids, readers and mask; missing {field!r}")
    lead = (None, None) if time_axis else (None,)
    for field in ("ids", "readers", "mask"):
        check_shape(f"{name}.{field}", getattr(det, field), lead)
    if not (np.shape(det.ids) == np.shape(det.readers) == np.shape(det.mask)):
        raise ValueError(
            f"{name}.ids, .readers and .mask must have the same shape, got "
            f"{np.shape(det.ids)}, {np.shape(det.readers)}, {np.shape(det.mask)}"
        )
    check_slots(name, det.ids, det.mask)
    check_slots(name, det.readers, det.mask, ids_field="readers")
    if num_readers is not None and not isinstance(det.readers, jax.core.Tracer):
        r = np.asarray(det.readers)[np.asarray(det.mask, bool)]
        if r.size and (r.min() < 0 or r.max() >= num_readers):
            raise ValueError(
                f"{name}.readers must index the {num_readers} readers, got values in [{r.min()}, {r.max()}]"
            )


# ---------------------------------------------------------------------------
# frames


def robot_frame(pose: jax.Array, point: jax.Array) -> jax.Array:
    """``R(θ)ᵀ (point − p)``: a world point ``[..., 2]`` in the frame of ``pose [..., 3]`` (broadcasting)."""
    s, c = fastmath.sincos(pose[..., 2])
    dx = point[..., 0] - pose[..., 0]
    dy = point[..., 1] - pose[..., 1]
    return jnp.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def world_frame(pose: jax.Array, point: jax.Array) -> jax.Array:
    """``p + R(θ) point``: a robot-frame point ``[..., 2]`` in the world frame (inverse of :func:`robot_frame`)."""
    s, c = fastmath.sincos(pose[..., 2])
    x, y = point[..., 0], point[..., 1]
    return jnp.stack([pose[..., 0] + c * x - s * y, pose[..., 1] + s * x + c * y], axis=-1)


# ---------------------------------------------------------------------------
# [W] eq. 3.7


def _eq37(ex: jax.Array, ey: jax.Array, half_width: jax.Array, log_beta: jax.Array) -> jax.Array:
    # Componentwise: stacking (e_x, e_y) and reducing over the pair costs XLA:CPU a
    # materialised [..., 2] array and a reduction per call, several times the arithmetic.
    inside = (jnp.abs(ex) < half_width) & (jnp.abs(ey) < half_width)
    outside = log_beta - (ex * ex + ey * ey) / (2.0 * half_width * half_width)
    return jnp.where(inside, jnp.zeros_like(outside), outside)


def _residual(pose: jax.Array, point: jax.Array, reader_offset: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``e = R(θ)ᵀ(point − p) − offset`` as two arrays (broadcasting pose ``[..., 3]`` and point ``[..., 2]``)."""
    s, c = fastmath.sincos(pose[..., 2])
    dx = point[..., 0] - pose[..., 0]
    dy = point[..., 1] - pose[..., 1]
    return c * dx + s * dy - reader_offset[..., 0], -s * dx + c * dy - reader_offset[..., 1]


def log_detection_likelihood(e: jax.Array, half_width: jax.Array, log_beta: jax.Array) -> jax.Array:
    """[W] eq. 3.7 in log form for residuals ``e [..., 2]`` (tag minus reader, robot frame, m)."""
    return _eq37(e[..., 0], e[..., 1], half_width, log_beta)


def tag_log_likelihood(
    tag_particles: jax.Array, pose: jax.Array, reader_offset: jax.Array, params: HFReaderParams
) -> jax.Array:
    """``[J]`` log-likelihood of tag particles ``[J, 2]`` (world, m) detected by the reader at
    ``reader_offset [2]`` of a robot at ``pose [3]`` ([W] Alg. 1 line 10)."""
    ex, ey = _residual(pose, tag_particles, reader_offset)
    return _eq37(ex, ey, params.half_width, params.log_beta)


def robot_log_likelihood(
    poses: jax.Array, tag: jax.Array, reader_offset: jax.Array, params: HFReaderParams
) -> jax.Array:
    """``[I]`` log-likelihood of robot particles ``[I, 3]`` for a detection of the tag estimated
    at ``tag [2]`` (world, m) by the reader at ``reader_offset [2]`` ([W] Alg. 1 line 18)."""
    ex, ey = _residual(poses, tag, reader_offset)
    return _eq37(ex, ey, params.half_width, params.log_beta)


def sample_in_footprint(
    key: jax.Array, pose: jax.Array, reader_offset: jax.Array, half_width: jax.Array, num: int
) -> jax.Array:
    """``[num, 2]`` world points uniform over the footprint of the reader at ``reader_offset``
    of a robot at ``pose`` ([W] Alg. 1 line 7: a new tag's particles)."""
    u = rng.uniform(key, (num, 2), pose.dtype, -1.0, 1.0) * half_width
    return world_frame(pose, reader_offset + u)


def slot_offsets(detections: TagDetections, params: HFReaderParams) -> jax.Array:
    """``[K, 2]`` the detecting reader's offset per slot (m, robot frame); a reader index out of range
    (refused on the host) is clipped."""
    return params.offsets[jnp.clip(detections.readers, 0, params.offsets.shape[0] - 1)]


def _sample_tag(
    key: jax.Array, pose: jax.Array, reader_offset: jax.Array, params: HFReaderParams, num: int
) -> jax.Array:
    return sample_in_footprint(key, pose, reader_offset, params.half_width, num)


def locate_robot(
    u: jax.Array, heading: jax.Array, tags: jax.Array, reader_offsets: jax.Array, params: HFReaderParams
) -> jax.Array:
    """``[N, 2]`` robot positions that put tag ``tags[n]`` under the reader at ``reader_offsets[n]`` of a
    robot of ``heading [N]``, at the point ``(2u − 1)·σ`` of its footprint (``u [N, 2]`` uniform):
    ``tag = p + R(θ)(offset + point)``, so ``p = tag − R(θ)(offset + point)``."""
    n = heading.shape[0]
    body = reader_offsets + (2.0 * u - 1.0) * params.half_width
    rotation_only = jnp.concatenate([jnp.zeros((n, 2), heading.dtype), heading[:, None]], axis=1)
    return tags - world_frame(rotation_only, body)


def _check_detections(det: TagDetections, time_axis: bool, params: HFReaderParams, name: str) -> None:
    validate_detections(det, time_axis, params.num_readers, name)


HF_TAG_SENSOR = LandmarkSensor(
    "hf_tag",
    2,
    slot_offsets,
    tag_log_likelihood,
    robot_log_likelihood,
    _sample_tag,
    locate=locate_robot,
    check_params=validate_params,
    check_observations=_check_detections,
    params_in_domain=reader_params_in_domain,
)
"""HF-RFID tag detections as a landmark sensor ([W] eq. 3.7; PF-SLAM's and PS-SLAM's default):
observations :class:`TagDetections`, sensor parameters :class:`HFReaderParams`. A new tag's particles
are uniform over the first detecting reader's footprint ([W] Alg. 1 line 7)."""


# ---------------------------------------------------------------------------
# Gaussian footprint model for FastSLAM


def footprint_cov(params: HFReaderParams) -> jax.Array:
    """``[2, 2]`` covariance ``diag(s²/12)`` of a uniform square footprint of side ``s = 2σ``."""
    var = params.half_width * params.half_width / 3.0
    return jnp.eye(2, dtype=jnp.result_type(var)) * var


def landmark_observations(detections: TagDetections, params: HFReaderParams) -> ReaderObservations:
    """FastSLAM observation slots: ``z[k] = offsets[readers[k]]`` (m, robot frame; works with a
    leading time axis).

    On the host a detection (mask set) whose reader index is outside ``[0, B)`` for the ``B`` rows
    of ``params.offsets`` raises ``ValueError`` naming ``detections.readers``, the first such index
    and its slot. Inside a caller's ``jit`` the values are unknown: the index is clipped into range.
    """
    num_readers = np.shape(params.offsets)[0]
    if is_concrete((detections.readers, detections.mask)):
        r = np.asarray(detections.readers)
        bad = np.asarray(detections.mask, bool) & ((r < 0) | (r >= num_readers))
        if bad.any():
            where = first_index(bad)
            raise ValueError(
                f"detections.readers must index the {num_readers} readers of params.offsets (0 to "
                f"{num_readers - 1}) where a detection is set, got {int(r[where])} at index {where} "
                f"({int(bad.sum())} such slot(s))"
            )
    return ReaderObservations(detections.ids, slot_offsets(detections, params), detections.mask)


def footprint_landmark_update(
    pose: jax.Array, mean: jax.Array, cov: jax.Array, z: jax.Array, r: jax.Array
) -> UpdateResult:
    """The HF footprint's landmark update in closed form (exactly the EKF's: ``h`` is linear in the landmark).

    ``h(x, m) = R(θ)ᵀ(m − p)``, so the detection is the world point ``m_z = p + R(θ) z`` with noise
    ``N = R(θ) R_z R(θ)ᵀ`` and ``H = I``. The footprint's ``R_z = (σ²/3) I`` is isotropic
    (:func:`footprint_cov`), so ``N = R_z`` for every heading: the
    covariance update below does not depend on the pose, and every particle keeps the same
    landmark covariance (``pose_free_covariance``). ``S = Σ + N``, ``K = Σ S⁻¹``,
    ``μ' = μ + K (m_z − μ)``, ``Σ' = (I − K) Σ (I − K)ᵀ + K N Kᵀ`` (Joseph form, as
    :func:`jaxnav.core.kalman.ekf_update`), weight ``log N(m_z − μ; 0, S)``, equal to the
    robot-frame ``log N(z; h(x, μ), H_m Σ H_mᵀ + R_z)`` because a rotation keeps the Mahalanobis
    distance and the determinant. 2 × 2 algebra written out: under ``vmap`` the generic EKF's
    Jacobian and factorisations cost several times more.
    """
    noise = r
    cov = symmetrize(cov)
    s = cov + noise
    det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
    s_inv = jnp.stack([jnp.stack([s[1, 1], -s[0, 1]]), jnp.stack([-s[1, 0], s[0, 0]])]) / det
    e = world_frame(pose, z) - mean
    maha = fastmath.small_sum(e * fastmath.matmul(s_inv, e))
    log_lik = -0.5 * (maha + jnp.log(det) + 2.0 * np.log(2.0 * np.pi))
    gain = fastmath.matmul(cov, s_inv)
    m_ = cov - fastmath.matmul(gain, cov)
    new_cov = ensure_pd(m_ - fastmath.matmul(m_, gain.T) + fastmath.matmul(fastmath.matmul(gain, noise), gain.T))
    return UpdateResult(
        mean + fastmath.matmul(gain, e), new_cov, maha, log_lik, jnp.ones((), bool), jnp.zeros((), bool)
    )


def footprint_landmark_initialise(pose: jax.Array, z: jax.Array, r: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``μ = p + R(θ) z``, ``Σ = R(θ) R_z R(θ)ᵀ = R_z`` (the generic ``J R Jᵀ`` with ``J = R(θ)``;
    ``R_z`` is isotropic, :func:`footprint_landmark_update`)."""
    return world_frame(pose, z), ensure_pd(r)


# ---------------------------------------------------------------------------
# smooth relaxation: a differentiable detection likelihood


def log_soft_inside(e: jax.Array, half_width: jax.Array, temperature: jax.Array) -> jax.Array:
    """``log Π_{a∈{x,y}} s((σ − e_a)/τ)·s((σ + e_a)/τ)`` for ``e [..., 2]`` (m); ``s`` the logistic."""
    hw = jnp.asarray(half_width)
    tau = jnp.asarray(temperature)
    z = jax.nn.log_sigmoid((hw - e) / tau) + jax.nn.log_sigmoid((hw + e) / tau)
    return jnp.sum(z, axis=-1)


def soft_inside(e: jax.Array, half_width: jax.Array, temperature: jax.Array) -> jax.Array:
    """Smooth footprint indicator in (0, 1): → ``1{|e_x| < σ, |e_y| < σ}`` as ``τ → 0``.

    Far outside the footprint the value underflows to 0 in floating point; use
    :func:`log_soft_inside` for log-probabilities.

    Args:
        e: ``[..., 2]`` tag minus reader, robot frame (m).
        half_width: σ (m).
        temperature: τ (m), the width of the soft edge.
    """
    return jnp.exp(log_soft_inside(e, half_width, temperature))


def _log1mexp(x: jax.Array) -> jax.Array:
    """``log(1 − eˣ)`` for ``x ≤ 0`` (Mächler 2012), finite with finite gradients; ``x`` clamped below 0."""
    x = jnp.minimum(x, -(jnp.finfo(jnp.result_type(x)).tiny ** 0.5))
    near = x > -math.log(2.0)
    a = jnp.where(near, x, -1.0)
    b = jnp.where(near, -1.0, x)
    return jnp.where(near, jnp.log(-jnp.expm1(a)), jnp.log1p(-jnp.exp(b)))


class TagMap(NamedTuple):
    """A map of tags as :func:`soft_detection_log_likelihood` reads it (e.g.
    :func:`jaxnav.sim.tag_carpet.tag_map` of a carpet).

    Attributes:
        positions: ``(ids [...], dtype) -> [..., 2]`` world positions (m) of tags by ID.
        near: ``(pose [3], offsets [B, 2]) -> (ids [B, C], positions [B, C, 2], on [B, C])``: every
            tag that may lie within the likelihood's window of each reader (``C`` static), ``on``
            marking real tags.
        dtype: the dtype of the map's positions (computations run in the wider of it and the poses').
    """

    positions: Any
    near: Any
    dtype: Any


def _soft_step(tag_map, pose, dets, offsets, half_width, temperature, log_eps, log_keep, log_base, window):
    """Bernoulli log-likelihood of one step's detections and non-detections."""
    dtype = jnp.result_type(pose.dtype, tag_map.dtype)
    offsets = offsets.astype(dtype)
    # detections
    tag = tag_map.positions(dets.ids, dtype)
    rdr = jnp.clip(dets.readers, 0, offsets.shape[0] - 1)
    e = robot_frame(pose, tag) - offsets[rdr]
    lp = log_soft_inside(e, half_width, temperature)
    hit = jnp.logaddexp(log_eps, log_keep + lp) - log_base
    ll_det = jnp.sum(jnp.where(dets.mask, hit, 0.0))
    # non-detections among the tags within ``window`` of each reader
    ids, pos, on = tag_map.near(pose, offsets)
    e = robot_frame(pose, pos) - offsets[:, None, :]
    near = on & jnp.all(jnp.abs(e) < window, axis=-1)
    readers = jnp.arange(offsets.shape[0], dtype=jnp.int32)
    seen = jnp.any(
        dets.mask[None, None, :]
        & (ids[:, :, None] == dets.ids[None, None, :])
        & (readers[:, None, None] == dets.readers[None, None, :]),
        axis=-1,
    )
    lp = log_soft_inside(e, half_width, temperature)
    miss = jnp.logaddexp(log_eps, log_keep + _log1mexp(lp)) - log_base  # → 0 far from the reader
    ll_miss = jnp.sum(jnp.where(near & ~seen, miss, 0.0))
    return ll_det + ll_miss


def soft_detection_log_likelihood(
    tag_map: TagMap,
    poses: jax.Array,
    detections: TagDetections,
    offsets: jax.Array,
    half_width: jax.Array,
    temperature: jax.Array,
    window: float,
    false_rate: float = 1e-6,
) -> jax.Array:
    """Differentiable log-likelihood of a run's detections given the path (smooth [W] eq. 3.7 "inside").

    Each (tag, reader) pair within ``window`` of the reader at step ``t`` is a
    Bernoulli outcome with ``P(detect) = ε + (1 − 2ε)·soft_inside(e, σ, τ)``
    (``ε = false_rate`` keeps every term finite): detected pairs (the valid
    slots of ``detections``) add ``log P``, the others ``log(1 − P)``. The
    result is taken relative to the baseline "no tag detected", i.e. each term
    is ``log P − log(1 − ε)`` or ``log(1 − P) − log(1 − ε)``: this subtracts
    the constant ``N·B·log(1 − ε)`` from the full log-likelihood and makes the
    term of a pair far from the reader vanish. Pairs farther than ``window``
    (L∞ in the reader frame) are therefore left out with an error of at most
    about ``e^{−(window − σ)/τ}`` each (and the sum stays continuous as tags
    cross the window), so take ``window ≥ σ + 20τ``. Smooth in ``half_width``, ``temperature``, ``poses``
    and the map's tag positions (gradients by ``jax.grad``; the choice of candidate
    tags is piecewise constant and carries no gradient).

    Args:
        tag_map: the true map, a :class:`TagMap` whose ``near`` covers ``window``
            (:func:`jaxnav.sim.tag_carpet.tag_map` of a carpet).
        poses: ``[T, 3]`` poses at which the detections were made.
        detections: :class:`TagDetections` with leading axis ``T``.
        offsets: ``[B, 2]`` reader offsets (m).
        half_width: σ (m).
        temperature: τ (m).
        window: static half-width (m) of the square scored around each reader.
        false_rate: ε, probability floor of each outcome.

    Returns:
        Scalar log-likelihood (nats).
    """
    if not isinstance(tag_map, TagMap):
        raise ValueError(f"tag_map must be a TagMap (e.g. jaxnav.sim.tag_carpet.tag_map), got {type(tag_map).__name__}")
    check_shape("poses", poses, (None, 3))
    check_shape("offsets", offsets, (None, 2))
    validate_detections(detections, True, np.shape(offsets)[0], "detections")
    if np.shape(detections.ids)[0] != np.shape(poses)[0]:
        raise ValueError(f"detections has {np.shape(detections.ids)[0]} steps but poses has {np.shape(poses)[0]}")
    check_positive("half_width", half_width)
    check_positive("temperature", temperature)
    w = float(window)
    if not (math.isfinite(w) and w > 0):
        raise ValueError(f"window must be a finite number > 0 m, got {window!r}")
    if is_concrete((half_width, temperature)):
        need = float(np.asarray(half_width)) + 20.0 * float(np.asarray(temperature))
        if w < need * (1 - 1e-9):
            raise ValueError(f"window={w} m is too small: take window ≥ half_width + 20·temperature = {need:g} m")
    eps = float(false_rate)
    if not 0 < eps < 0.5:
        raise ValueError(f"false_rate must be in (0, 0.5), got {false_rate!r}")
    log_eps, log_keep, log_base = math.log(eps), math.log1p(-2 * eps), math.log1p(-eps)

    def step(pose: jax.Array, det: TagDetections) -> jax.Array:
        return _soft_step(tag_map, pose, det, offsets, half_width, temperature, log_eps, log_keep, log_base, w)

    return jnp.sum(jax.vmap(step)(poses, detections))
