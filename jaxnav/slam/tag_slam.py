"""The step shared by PF-SLAM and PS-SLAM: one robot particle filter, an independent estimator per tag.

[W] Algs. 1 and 2 differ only in how a detected tag's particle set is
updated (a particle filter, or a fixed-lag particle smoother); everything
else — motion, gathering the detected tags, initialising new ones, weighting
and resampling the robot — is this module. A tag estimator is a
row type (a NamedTuple of one tag's arrays, with fields ``estimates`` and
``counts``) and a :class:`TagModel` (``propose`` the particles to weight,
``finish`` the update); the tag table is the same row type with a leading
``max_tags`` axis, indexed by tag ID.

The sensor is ``config.sensor``, a :class:`~jaxnav.models.sensor.LandmarkSensor`: [W]'s HF readers
by default (:data:`~jaxnav.models.hf_rfid.HF_TAG_SENSOR`), or range and bearing
(:data:`~jaxnav.models.landmarks.RANGE_BEARING_LANDMARK_SENSOR`), range-only beacons
(:mod:`jaxnav.models.range_only`) or a user's own. Below, "tag" is any landmark, a "reader" the
slot's measurement, "eq. 3.7" the sensor's density and "the footprint" where its ``initialise``
places a new landmark's particles.

One step, for ``K`` detection slots (ids, readers, mask):

1. Robot particles move by the motion model ([W] Alg. 1 lines 2–4); the
   robot estimate ``x̂`` is their weighted mean (circular θ).
2. The ``K`` detected rows are *gathered* from the table (``O(K·J)``).
3. Each slot is updated by the tag model, ``vmap``-ed over slots. Slots that
   detected the same tag in this step (two readers, one tag) are grouped:
   every slot of a group proposes the same particles (same row, same key
   ``fold_in(key, tag ID)``), scores them against its own reader only, and a
   ``[K, K]`` group matrix sums the scores of the group (``K·J`` likelihoods,
   not ``K·K·J``); every slot of the group then finishes the same update and
   only the group's first slot writes it back, so a tag is updated exactly
   once per step with every reader's evidence. A new tag is initialised uniformly over the
   footprint of its first detecting reader (world frame, from ``x̂``); the
   group's other readers then weight it.
4. The rows are *scattered* back (out-of-table writes dropped), in place in
   a ``lax.scan`` carry or in a donated ``step``: no operation in a step
   touches the whole table, so a step costs ``O(I + K·J)`` whatever the map
   holds ([W] §3.3.1).
5. Robot particles are weighted by [W] eq. 3.7 against the *updated*
   estimates of the re-detected tags (Alg. 1 lines 17–19), then resampled
   (lines 21–24, conditional on the ESS; every step by default). With
   ``config.robot_likelihood = "mixture"`` they are weighted against each
   re-detected tag's particle set *before* its update instead,
   ``log Σ_j w_j Π_k p(z_k | x, m_j)`` over the group's slots ``k``: the
   predictive density of the step's observations, right when a tag's set is
   far from one point (a range-only ring), at ``K·I·J`` evaluations. A tag model may instead
   name mixture points of the *updated* row (``TagModel.robot_target``: PS-SLAM's smoothed or
   current particles, :mod:`jaxnav.slam.ps_slam`, "Readings").

The robot particles can be spread over devices (:func:`run_sharded`, the filters' ``run_sharded``):
each device moves and weights its block, the robot's sums, maxima and resampling are over every
device (:mod:`jaxnav.core.sharded`), and every device holds the whole tag table and makes the same
update of the detected tags from the same robot estimate.

Choices where [W] is silent (stated here, tested):

* A tag seen for the first time does not weight the robot: its estimate was
  made from ``x̂`` itself, so scoring the robot against it would only pull
  the particles toward their own mean.
* Kidnapping ([W] §3.4.3 says the robot "recognizes the kidnapping" without
  giving a mechanism). With ``config.recovery`` the step first scores the
  robot particles against the re-detected tags' *previous* estimates; if the
  best particle averages below ``recovery_log_likelihood`` per detection
  (with the default −8 and β = 0.1 that is about 3.4 σ from every detected
  tag), the robot is lost: its particles are redrawn around the detected
  tags (for each particle a re-detected slot is picked at random, a point
  uniform over that reader's footprint, and the position that puts the
  reader over the tag estimate; heading uniform, since the robot may have
  been turned, or with ``recovery_heading_sd`` the particle's own plus a
  uniform error of that standard deviation), and no tag is updated in that
  step so a lost robot does not corrupt the map. ``info.lost`` flags such steps.
* In place: every field written back must be computed *from* its gathered
  row. A row field that does not depend on its gather (say, a constant) lets
  XLA schedule the scatter before the read and copy the whole table to keep
  the read valid, an ``O(max_tags)`` copy per step. The step therefore writes
  ``where(write, updated, gathered)`` for every field (the slots that do not
  write are dropped by the scatter anyway). PF-SLAM's estimate, the mean of the
  new particles, is tied to its gathered row by nothing else once
  ``recovery=False`` removes the kidnapping check (which reads the gathered
  estimates), and XLA would copy the estimate table twice per step. Tag models
  also return the gathered log-weights when they are known to be uniform (tag
  resampling at every detection) instead of a fresh constant.
* ``counts`` counts the steps in which a tag was detected (one per step,
  however many readers saw it): the "detection times" of [W] Fig. 3.5, and
  the ring position of PS-SLAM.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from jaxnav.core import filter as filter_api
from jaxnav.core import resampling, rng, sharded, weights
from jaxnav.core.particle_filter import PFInfo, at_least_one_slot, extend_info, finish_step, keep_finite
from jaxnav.core.validation import (
    check_choice,
    check_finite,
    check_fraction,
    check_nonnegative,
    check_positive_int,
    check_shape,
)
from jaxnav.models import hf_rfid
from jaxnav.models.motion import (
    check_motion_model,
    controls_in_domain,
    get_motion_model,
    noise_in_domain,
    validate_controls,
)
from jaxnav.models.motion import validate_noise as validate_motion_noise
from jaxnav.models.sensor import LandmarkSensor, check_landmark_sensor

_POSE_ANGLE_DIMS = (2,)
ROBOT_LIKELIHOODS = ("estimate", "mixture")
"""The choices of ``TagSLAMConfig.robot_likelihood``."""


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SLAMInfo(PFInfo):
    """Per-step diagnostics of PF-SLAM and PS-SLAM.

    Attributes:
        estimate: ``[3]`` robot pose estimate (weighted mean, circular θ) after the update (m, m, rad).
        ess: robot effective sample size before resampling.
        resampled: bool, the robot particles were resampled.
        log_likelihood: the log of the robot filter's normaliser, ``log Σ_i w̄_{t−1,i} ℓ_i`` with ``ℓ_i``
            the robot particle's likelihood of the step's detections against the tag estimates.
            A *pseudo*-likelihood, not ``log p(z_t | z_{1:t−1})``: those tag estimates were already
            updated with the same detections, and at a lost step the robot particles were redrawn
            first. Useful as a diagnostic (it falls when the robot is lost); it is not a marginal
            likelihood and must not be maximised to fit parameters (:mod:`jaxnav.calibration`).
        degenerate: bool, every robot weight was zero and the set was reset to uniform.
        lost: bool, kidnapping recovery redrew the robot particles (see ``config.recovery``).
        num_ignored: valid slots whose tag ID is outside ``[0, max_tags)``, and tags whose update was not
            finite (dropped, the tag's row left as it was).
        num_new: tags initialised this step.
        num_updated: tags re-detected (updated) this step.
        slot_ids: ``[K]`` tag ID per slot, −1 for empty or dropped slots.
        slot_estimates: ``[K, D]`` the slot's tag estimate after the step (m).
        slot_counts: ``[K]`` the slot's tag detection count after the step.
        invalid_inputs: bool, the step's odometry or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged (the step's detections were
            masked out, so that no row of the tag table is written).
    """

    lost: jax.Array
    num_ignored: jax.Array
    num_new: jax.Array
    num_updated: jax.Array
    slot_ids: jax.Array
    slot_estimates: jax.Array
    slot_counts: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# configuration and validation shared by both filters


@dataclass(frozen=True)
class TagSLAMConfig:
    """Static configuration shared by PF-SLAM and PS-SLAM (hashable; a static argument of ``jit``).

    Attributes:
        num_particles: ``I``, robot particles (500 in [W]).
        num_tag_particles: ``J``, particles per tag (100 in [W]).
        max_tags: tag-table capacity; tag IDs ``≥ max_tags`` are dropped and counted.
        motion_model: name in :data:`jaxnav.models.motion.MODELS`; "omni" is [W] eq. 3.6.
        resampling: scheme for robot and tag particles (:data:`jaxnav.core.resampling.SCHEMES`).
        ess_threshold: robot resampling when ESS < ``ess_threshold · I``; 1.0 = every step ([W] Alg. 1).
        tag_ess_threshold: the same for a tag's particles at each detection; 1.0 = always ([W] Alg. 1).
        recovery: redraw the robot particles when it is lost (kidnapping, [W] §3.4.3; module docstring).
            Either setting updates the tag table in place: a step's cost does not depend on ``max_tags``.
        recovery_log_likelihood: lost when the best robot particle averages below this per re-detection.
        recovery_heading_sd: ``None``: redrawn particles get a uniform heading (the robot may have
            been turned); a number: each keeps its own heading with a uniform error of this standard deviation (rad).
        robot_likelihood: how the robot particles are weighted by a re-detected landmark:
            ``"estimate"`` (default, [W] Alg. 1 lines 17–19): against the landmark's estimate after
            its update; ``"mixture"``: against its particle set before the update, ``log Σ_j w_j
            p(z | x, m_j)`` (the predictive density of the observation given the landmark's
            posterior so far; ``K·I·J`` likelihoods instead of ``K·I``). Use ``"mixture"`` when a
            landmark's particle set is far from one point: a range-only beacon seen from few places
            lies on a ring or an arc whose mean is nowhere near it.
        sensor: the landmark sensor (:class:`~jaxnav.models.sensor.LandmarkSensor`): its observations
            are the filter's, its parameters ``params.sensor``. Default
            :data:`~jaxnav.models.hf_rfid.HF_TAG_SENSOR`, [W]'s HF-RFID readers (the tags are the landmarks).
        parallel_slots: ``None`` (default): a step processes all ``K`` detection slots. A number
            ``L < K``: a step moves the valid slots to the front and processes the first ``L``,
            and all ``K`` only when more than ``L`` are valid, at the cost of ``L`` slots. The
            results are those of all slots up to float rounding: sums over the slots run in
            another order, and a particle filter can amplify a last-bit difference in a single
            run (in distribution nothing changes). Derivatives are those of the all-slot step.
            Worth it when the capacity ``K`` is much larger than what a step sees: at 100 tags/m²
            with 60 mm readers ``K = 24`` for about 3 detections. Under ``vmap`` a step where one
            run of the batch has more than ``L`` valid slots costs all ``K`` for the batch: choose
            ``L`` above what a step rarely exceeds (e.g. ``⌈λ + 3√λ⌉`` for ``λ`` expected
            detections per step).
    """

    num_particles: int = 500
    num_tag_particles: int = 100
    max_tags: int = 1024
    motion_model: str = "omni"
    resampling: str = "systematic"
    ess_threshold: float = 1.0
    tag_ess_threshold: float = 1.0
    recovery: bool = True
    recovery_log_likelihood: float = -8.0
    recovery_heading_sd: float | None = None
    parallel_slots: int | None = None
    robot_likelihood: str = "estimate"
    sensor: LandmarkSensor = hf_rfid.HF_TAG_SENSOR

    def __post_init__(self) -> None:
        validate_common_config(self)


def validate_common_config(config: Any) -> None:
    """Checks of the fields PF-SLAM and PS-SLAM configs share (raises ValueError)."""
    check_positive_int("num_particles", config.num_particles)
    check_positive_int("num_tag_particles", config.num_tag_particles)
    check_positive_int("max_tags", config.max_tags)
    check_motion_model("motion_model", config.motion_model)
    check_choice("resampling", config.resampling, resampling.SCHEMES)
    check_fraction("ess_threshold", config.ess_threshold)
    check_fraction("tag_ess_threshold", config.tag_ess_threshold)
    if not isinstance(config.recovery, bool):
        raise ValueError(f"recovery must be True or False, got {config.recovery!r}")
    if not np.isfinite(config.recovery_log_likelihood) or config.recovery_log_likelihood >= 0:
        raise ValueError(f"recovery_log_likelihood must be a negative number, got {config.recovery_log_likelihood!r}")
    if config.parallel_slots is not None:
        check_positive_int("parallel_slots", config.parallel_slots)
    check_choice("robot_likelihood", config.robot_likelihood, ROBOT_LIKELIHOODS)
    check_landmark_sensor("sensor", config.sensor)
    if config.recovery and config.sensor.locate is None:
        raise ValueError(
            f"recovery=True needs a sensor that can place the robot from a landmark (its locate); "
            f"sensor {config.sensor.name!r} has none: set recovery=False"
        )
    sd = config.recovery_heading_sd
    if sd is not None and not (isinstance(sd, (int, float)) and np.isfinite(sd) and sd >= 0):
        raise ValueError(f"recovery_heading_sd must be None (uniform heading) or a number ≥ 0 rad, got {sd!r}")


def check_capacity(config: Any, num_tags: int) -> None:
    """Refuse a tag table smaller than the carpet: IDs ``≥ max_tags`` would be dropped."""
    if int(num_tags) > config.max_tags:
        raise ValueError(
            f"max_tags={config.max_tags} is too small for a carpet of {int(num_tags)} tags: "
            f"set max_tags ≥ {int(num_tags)} (tag IDs index the table directly)"
        )


def validate_params(config: Any, params: Any, params_type: type) -> None:
    """Host-side checks of a tag-SLAM filter's ``params``: its type, the motion noise and the sensor's parameters."""
    if not isinstance(params, params_type):
        raise ValueError(f"params must be a {params_type.__name__}, got {type(params).__name__}")
    validate_motion_noise(config.motion_model, params.motion)
    config.sensor.check_params(params.sensor, "params.sensor")


def validate_state(config: Any, state: Any, table_shapes: dict[str, tuple[int, ...]]) -> None:
    """Shapes of the robot particles and of every field of the tag table (``table_shapes``)."""
    check_shape("state.poses", state.poses, (config.num_particles, 3))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))
    for field, shape in table_shapes.items():
        check_shape(f"state.tags.{field}", getattr(state.tags, field), shape)


def validate_inputs(config: Any, params: Any, controls: Any, detections: Any, time_axis: bool) -> None:
    """Odometry of the configured motion model and the sensor's observations of as many steps."""
    name = "controls" if time_axis else "control"
    validate_controls(name, controls, config.motion_model, time_axis)
    config.sensor.check_observations(detections, time_axis, params.sensor, "detections")
    if time_axis and np.shape(detections.ids)[0] != np.shape(controls)[0]:
        raise ValueError(
            f"controls and observations must have the same number of steps, got "
            f"{np.shape(controls)[0]} and {np.shape(detections.ids)[0]}"
        )


def inputs_in_domain(config: Any, params: Any, control: jax.Array, detections: Any) -> jax.Array:
    """``bool[]``, traceable: the odometry and the motion noise in the motion model's domain
    (:func:`jaxnav.models.motion.controls_in_domain`, :func:`jaxnav.models.motion.noise_in_domain`)
    and the sensor's parameters in its own (``config.sensor.params_in_domain``): the value
    checks of the host, as ``jnp``. The detections are not part of it (slots outside the table are
    dropped and counted)."""
    del detections
    return (
        controls_in_domain(control, config.motion_model)
        & noise_in_domain(config.motion_model, params.motion)
        & config.sensor.params_in_domain(params.sensor)
    )


def initial_particles(key: jax.Array, config: Any, initial_pose: Any, initial_sd: Any) -> tuple[jax.Array, jax.Array]:
    """Robot particles at ``N(initial_pose, diag(initial_sd²))`` ([W] Alg. 1 line 1: a known start) and uniform log-weights."""
    filter_api.check_key(key)
    pose = jnp.asarray(initial_pose, jnp.result_type(float))
    check_shape("initial_pose", pose, (3,))
    check_finite("initial_pose", pose)
    sd = jnp.zeros(3, pose.dtype) if initial_sd is None else jnp.asarray(initial_sd, pose.dtype)
    check_shape("initial_sd", sd, (3,))
    check_nonnegative("initial_sd", sd)
    n = config.num_particles
    poses = pose + rng.normal(key, (n, 3), pose.dtype) * sd
    poses = poses.at[:, 2].set(weights.wrap_angle(poses[:, 2]))
    return poses, jnp.full((n,), -np.log(n), pose.dtype)


# ---------------------------------------------------------------------------
# the step


def _valid_slots(det: Any, max_tags: int, sensor: LandmarkSensor):
    """``(valid [K], dropped count)``: masked slots with an ID in the table and a usable measurement
    (``sensor.usable``), and the masked ones without."""
    usable = (det.ids >= 0) & (det.ids < max_tags) & sensor.usable(det)
    mask = det.mask.astype(bool)  # an integer mask: nonzero = set (a bitwise & with 2 would drop it)
    return mask & usable, jnp.sum(mask & ~usable).astype(jnp.int32)


def _slots(det: Any, max_tags: int, sensor: LandmarkSensor):
    """Valid slots, safe IDs, same-tag groups ``[K, K]``, each slot's group leader, and dropped count."""
    valid, num_ignored = _valid_slots(det, max_tags, sensor)
    ids = jnp.clip(det.ids, 0, max_tags - 1).astype(jnp.int32)
    same = valid[:, None] & valid[None, :] & (ids[:, None] == ids[None, :])
    first = jnp.argmax(same, axis=1).astype(jnp.int32)
    leader = valid & (first == jnp.arange(ids.shape[0]))
    return valid, ids, same, first, leader, num_ignored


def _robot_log_likelihood(poses, tag_estimates, z, mask, sensor: LandmarkSensor, sensor_params) -> jax.Array:
    """``[I]`` Σ over the slots in ``mask`` of the sensor's log-likelihood of the robot particles
    against the landmark estimates ``[K, D]`` ([W] eq. 3.7 for HF tags)."""
    ll = jax.vmap(lambda tag, zk: sensor.robot_log_likelihood(poses, tag, zk, sensor_params))(tag_estimates, z)
    return jnp.sum(jnp.where(mask[:, None], ll, 0.0), axis=0)


def _robot_mixture_log_likelihood(poses, particles, log_w, z, same, leader, sensor, sensor_params) -> jax.Array:
    """``[I]`` Σ over the groups of re-detected slots (``leader``: a group's first slot) of
    ``log Σ_j w_j Π_{k ∈ group} p(z_k | x, m_j)``: each landmark's particle set ``[K, J, D]`` with
    normalised log-weights ``[K, J]`` before its update, as a mixture (``robot_likelihood="mixture"``)."""
    pair = jax.vmap(
        lambda p, zk: jax.vmap(lambda pose: sensor.landmark_log_likelihood(p, pose, zk, sensor_params))(poses)
    )(particles, z)  # [K, I, J]
    k, i, j = pair.shape
    joint = jnp.matmul(same.astype(pair.dtype), pair.reshape(k, i * j), precision=jax.lax.Precision.HIGHEST).reshape(
        k, i, j
    )
    mix = jax.scipy.special.logsumexp(joint + log_w[:, None, :], axis=-1)  # [K, I]
    return jnp.sum(jnp.where(leader[:, None], mix, 0.0), axis=0)


def _recover(key, poses, tag_estimates, z, known, config, sensor_params) -> jax.Array:
    """Robot particles redrawn around the re-detected tags (kidnapping recovery; module docstring).

    One block of uniforms serves every draw: the slot (the ``⌊u·n⌋``-th of the ``n`` re-detected
    slots), the point in its footprint and the heading. Under ``vmap`` over runs the recovery is
    computed at every step (a ``cond`` becomes a select), so it is kept to 4 uniforms per particle.
    The sensor's ``locate`` places the robot from the picked landmark and its slot's measurement.
    """
    n = poses.shape[0]
    u = rng.uniform(key, (n, 4), poses.dtype)
    num_known = jnp.sum(known)
    rank = jnp.minimum(jnp.floor(u[:, 0] * num_known), num_known - 1)  # which re-detected slot
    pick = jnp.sum(jnp.cumsum(known)[None, :] <= rank[:, None], axis=1)  # its index among all slots
    pick = jnp.clip(pick, 0, known.shape[0] - 1)
    if config.recovery_heading_sd is None:
        theta = (2.0 * u[:, 3] - 1.0) * jnp.pi
    else:
        spread = config.recovery_heading_sd * jnp.sqrt(3.0)  # uniform of that standard deviation
        theta = weights.wrap_angle(poses[:, 2] + (2.0 * u[:, 3] - 1.0) * spread)
    picked_z = jax.tree_util.tree_map(lambda a: a[pick], z)
    xy = config.sensor.locate(u[:, 1:3], theta, tag_estimates[pick], picked_z, sensor_params)
    return jnp.concatenate([xy, theta[:, None]], axis=1)


class TagModel(NamedTuple):
    """How one tag's estimator is updated, in two halves around the weighting.

    Attributes:
        propose: ``(key, row, is_new, pose_est, init_z, config, params) -> (particles [J, D], log_weights [J])``:
            a new tag's particles drawn by the sensor from its first measurement ``init_z``
            (``config.sensor.initialise``), or the row's (PS-SLAM: jittered).
        finish: ``(key, row, particles, log_weights, log_likelihood [J], is_new, config, params) -> row``:
            weight, resample, estimate.
        robot_target: ``None`` (PF-SLAM), or ``(rows, config) -> None | (points [K, P, D], log_weights [K, P])``:
            with points, a re-detected tag weights the robot by the mixture ``log Σ_p w_p Π_k p(z_k | x, m_p)``
            over the points of its updated rows (``rows`` batched over the ``K`` slots) instead of by its
            estimate (PS-SLAM's ``robot_target``). Only read with ``robot_likelihood="estimate"``.
        uses_robot_particles: ``None``, or ``config -> bool``: when true, ``propose`` is also given
            ``robot=(poses [I, 3], log_weights [I])``, the robot's moved particles (PS-SLAM's ``tag_init``).
    """

    propose: Callable[..., Any]
    finish: Callable[..., Any]
    robot_target: Callable[..., Any] | None = None
    uses_robot_particles: Callable[[Any], bool] | None = None


class StepResult(NamedTuple):
    """A step's outcome before the tag table is written: the rows to scatter (``write_ids [K]``,
    ``max_tags`` for slots that write nothing) and the robot's new particles."""

    write_ids: jax.Array
    rows: Any
    poses: jax.Array
    log_weights: jax.Array
    info: SLAMInfo


def slam_step(
    key: jax.Array,
    state: Any,
    config: Any,
    params: Any,
    control: jax.Array,
    det: Any,
    tag_model: TagModel,
    valid_inputs: Callable[..., jax.Array] = inputs_in_domain,
    axis_name: str | None = None,
) -> tuple[Any, SLAMInfo]:
    """One step of [W] Alg. 1 / Alg. 2 (module docstring). Returns ``(state, SLAMInfo)``.

    With ``config.parallel_slots = L`` smaller than the ``K`` detection slots, the valid slots
    are moved to the front and only the first ``L`` are processed (``_compacted_result``).

    A step whose inputs are outside the domain (``valid_inputs``, with
    :func:`jaxnav.core.filter.params_in_domain`) keeps the state and sets ``info.invalid_inputs``
    (:func:`jaxnav.core.filter.guard_inputs`): its detections are masked out, so no row of the
    table is written (a select over the whole table would cost a pass over it at every step),
    and only the robot's particles are selected.

    ``axis_name`` (inside ``jax.shard_map``): ``state.poses`` and ``state.log_weights`` are this
    device's block of the robot particles spread over that mesh axis, and the tag table is the whole
    table, the same on every device (:func:`run_sharded`).
    """
    ok = filter_api.inputs_in_domain(valid_inputs, config, params, control, det)
    det = at_least_one_slot(det)
    det = det._replace(mask=det.mask.astype(bool) & ok)
    num_slots = det.ids.shape[0]
    lanes = config.parallel_slots
    robot = (state.poses, state.log_weights)
    # gather: O(K·row); the loop below must not hold the table, or XLA copies it into the loop
    rows = jax.tree_util.tree_map(lambda a: a[jnp.clip(det.ids, 0, config.max_tags - 1)], state.tags)
    if lanes is None or lanes >= num_slots:
        res = _slot_result(key, robot, rows, config, params, control, det, tag_model, axis_name)
    else:
        res = _compacted_result(key, robot, rows, config, params, control, det, tag_model, lanes, axis_name)
    # the table is only written here, once: in place in a scan carry or a donated step. Every field
    # written is a select with its gathered row (module docstring, "In place"); the slots that
    # keep their row are dropped by the scatter, so the select changes no value written.
    writes = res.write_ids < config.max_tags
    new_rows = jax.tree_util.tree_map(
        lambda v, old: jnp.where(writes.reshape(writes.shape + (1,) * (v.ndim - 1)), v, old), res.rows, rows
    )
    tags = jax.tree_util.tree_map(lambda a, v: a.at[res.write_ids].set(v, mode="drop"), state.tags, new_rows)
    poses = jnp.where(ok, res.poses, state.poses)
    log_weights = jnp.where(ok, res.log_weights, state.log_weights)
    return state._replace(poses=poses, log_weights=log_weights, tags=tags), filter_api.flag_invalid_inputs(res.info, ok)


def _compact(det: Any, max_tags: int, lanes: int, sensor: LandmarkSensor):
    """The valid slots moved to the front, in their order: ``(order [L], detections [L], num_valid,
    num_ignored)`` (the compacted slots past the valid ones are masked)."""
    valid, num_ignored = _valid_slots(det, max_tags, sensor)
    order = jnp.argsort(~valid, stable=True)[:lanes].astype(jnp.int32)
    small = jax.tree_util.tree_map(lambda a: a[order], det)._replace(mask=valid[order])
    return order, small, jnp.sum(valid), num_ignored


def _expand(res: StepResult, order, num_slots: int, max_tags: int, num_ignored) -> StepResult:
    """A result on the ``L`` compacted slots put back on the ``K`` slots (the others write and report nothing)."""

    def put(fill, v):
        return jnp.full((num_slots,) + v.shape[1:], fill, v.dtype).at[order].set(v)

    info = res.info.replace(
        num_ignored=num_ignored + res.info.num_ignored,  # the compacted slots are all valid: only rows not written
        slot_ids=put(-1, res.info.slot_ids),
        slot_estimates=put(0, res.info.slot_estimates),
        slot_counts=put(0, res.info.slot_counts),
    )
    rows = jax.tree_util.tree_map(lambda v: put(0, v), res.rows)
    return res._replace(write_ids=put(max_tags, res.write_ids), rows=rows, info=info)


@partial(jax.custom_jvp, nondiff_argnums=(3, 7, 8, 9))
def _compacted_result(key, robot, rows, config, params, control, det, tag_model, lanes, axis_name):
    """:func:`_slot_result` on the first ``lanes`` valid slots, and on all ``K`` slots only when a
    step has more valid slots than that: the same result either way up to float rounding (sums
    over the slots run in another order), at the cost of ``L`` slots.

    The overflow is a ``while`` loop of zero or one iteration, so under ``vmap`` over runs the
    ``K``-slot update is computed only at the steps where some run of the batch needs it (a
    ``cond`` would compute both branches at every step). Derivatives are those of the ``K``-slot
    update (a custom JVP: reverse mode cannot go through a loop whose trip count depends on data).
    """
    num_slots = det.ids.shape[0]
    order, small, num_valid, num_ignored = _compact(det, config.max_tags, lanes, config.sensor)
    small_rows = jax.tree_util.tree_map(lambda a: a[order], rows)
    res = _slot_result(key, robot, small_rows, config, params, control, small, tag_model, axis_name)
    res = _expand(res, order, num_slots, config.max_tags, num_ignored)

    def all_slots(carry):
        _, k, _ = carry
        result = _slot_result(k, robot, rows, config, params, control, det, tag_model, axis_name)
        # The key is carried and changed so that the update is not loop-invariant: XLA hoists
        # invariant code out of a loop, which would compute it at every step.
        return jnp.zeros((), bool), jax.random.fold_in(k, 1), result

    return jax.lax.while_loop(lambda carry: carry[0], all_slots, (num_valid > lanes, key, res))[2]


@_compacted_result.defjvp
def _compacted_result_jvp(config, tag_model, lanes, axis_name, primals, tangents):
    def all_slots(key, robot, rows, params, control, det):
        return _slot_result(key, robot, rows, config, params, control, det, tag_model, axis_name)

    return jax.jvp(all_slots, primals, tangents)


def _slot_result(
    key, robot, rows, config, params, control, det: Any, tag_model: TagModel, axis_name: str | None = None
) -> StepResult:
    """The step on all ``K`` slots of ``det``, up to the table write (module docstring): ``robot`` is
    ``(poses, log_weights)``, ``rows`` the slots' rows of the tag table; with ``axis_name`` the robot's
    particles are this device's block (:func:`slam_step`): the robot's draws are blocks of the whole
    draw, its sums and maxima are over every device, and every device updates the same tags from the
    same robot estimate."""
    state_poses, state_log_weights = robot
    k_move, k_tags, k_recover, k_resample = jax.random.split(key, 4)
    model = get_motion_model(config.motion_model)
    sensor, sensor_params = config.sensor, params.sensor
    max_tags, num_slots = config.max_tags, det.ids.shape[0]

    # Per-particle draws only inside ``robot_blocks`` (a tag's draw of J rows must not be taken for one).
    robot_blocks = partial(_robot_blocks, axis_name, state_poses.shape[0])
    # Materialise the moved particles: otherwise XLA:CPU fuses the motion draw (erf⁻¹, logs) into
    # the [K, I] likelihoods below and recomputes it for every slot (K times the draw).
    with robot_blocks():
        poses = jax.lax.optimization_barrier(model.sample(k_move, state_poses, control, params.motion))
    pose_est = weights.mean_from_probabilities(poses, jnp.exp(state_log_weights), _POSE_ANGLE_DIMS, axis_name)

    valid, ids, same, first, leader, num_ignored = _slots(det, max_tags, sensor)
    z = sensor.measurements(det, sensor_params)  # every leaf [K, ...]
    known = valid & (rows.counts > 0)
    is_new = valid & ~known

    slots = jnp.arange(num_slots)

    # Slots of one tag share its key, its row and its initialising reader, so they propose the
    # same particles; each slot scores them against its own reader only (K·J evaluations) and a
    # [K, K] matrix sums the scores of the group (a new tag's first reader, which placed the
    # particles, is left out). This is the group's joint likelihood without a K·K·J evaluation.
    tag_keys = jax.vmap(lambda i: jax.random.fold_in(k_tags, i))(ids)
    first_z = jax.tree_util.tree_map(lambda a: a[first], z)
    propose_kw = {}
    if tag_model.uses_robot_particles is not None and tag_model.uses_robot_particles(config):
        if axis_name is not None:
            raise ValueError("a tag model that draws from the robot particles cannot have them spread over devices")
        propose_kw["robot"] = (poses, state_log_weights)
    particles, log_w = jax.vmap(
        lambda k, row, new, zk: tag_model.propose(k, row, new, pose_est, zk, config, params, **propose_kw)
    )(tag_keys, rows, is_new, first_z)
    # Materialised for the same reason as the poses: otherwise PS-SLAM's ring mean fuses the jitter
    # draw and recomputes it for every ring entry, which would dominate the step.
    particles = jax.lax.optimization_barrier(particles)

    # Kidnapping check against the previous estimates of the re-detected tags (their particle sets
    # before this step's update with robot_likelihood="mixture").
    num_known = jnp.sum(known)
    if config.robot_likelihood == "mixture":

        def mixture_log_likelihood(p: jax.Array) -> jax.Array:
            group_known, leader_known = same & known[:, None], leader & known
            return _robot_mixture_log_likelihood(
                p, particles, log_w, z, group_known, leader_known, sensor, sensor_params
            )

        ll_prev = mixture_log_likelihood(poses)
    else:
        ll_prev = _robot_log_likelihood(poses, rows.estimates, z, known, sensor, sensor_params)
    best = jnp.max(ll_prev) if axis_name is None else jax.lax.pmax(jnp.max(ll_prev), axis_name)
    lost = (
        jnp.asarray(config.recovery)
        & (num_known > 0)
        & (best < config.recovery_log_likelihood * num_known.astype(poses.dtype))
    )
    own = jax.vmap(lambda p, zk: sensor.landmark_log_likelihood(p, pose_est, zk, sensor_params))(particles, z)
    group = same & jnp.where(is_new[:, None], slots[None, :] != first[:, None], True)
    loglik = jnp.matmul(group.astype(own.dtype), own, precision=jax.lax.Precision.HIGHEST)
    new_rows = jax.vmap(lambda k, row, p, lw, ll, new: tag_model.finish(k, row, p, lw, ll, new, config, params))(
        tag_keys, rows, particles, log_w, loglik, is_new
    )
    # a row whose update is not finite (an overflow under a caller's jit) is not written, and counted
    row_ok = jnp.all(jnp.isfinite(new_rows.particles), axis=(1, 2)) & jnp.all(jnp.isfinite(new_rows.estimates), axis=-1)
    write = leader & ~lost & row_ok
    write_ids = jnp.where(write, ids, max_tags)  # out of range: dropped by the scatter

    estimates = jnp.where(lost | ~row_ok[:, None], rows.estimates, new_rows.estimates)
    if config.recovery:  # a cond: a step that is not lost draws nothing (under vmap both branches run)
        with robot_blocks():
            poses = jax.lax.cond(
                lost,
                lambda p: _recover(k_recover, p, rows.estimates, z, known, config, sensor_params),
                lambda p: p,
                poses,
            )
    uniform = jnp.full_like(state_log_weights, -jnp.log(jnp.asarray(config.num_particles, poses.dtype)))
    prior_lw = jnp.where(lost, uniform, state_log_weights)
    if config.robot_likelihood == "mixture":
        # the tags' particle sets are not updated before this weighting: the check's likelihoods
        # serve, unless the recovery redrew the particles
        robot_ll = jax.lax.cond(lost, mixture_log_likelihood, lambda p: ll_prev, poses) if config.recovery else ll_prev
    elif (target := _robot_target(tag_model, new_rows, rows, lost | ~row_ok, config)) is not None:
        points, point_lw = target
        robot_ll = _robot_mixture_log_likelihood(
            poses, points, point_lw, z, same & known[:, None], leader & known, sensor, sensor_params
        )
    else:
        robot_ll = _robot_log_likelihood(poses, estimates, z, known, sensor, sensor_params)
    poses, loglik = keep_finite(state_poses, poses, robot_ll)
    norm = weights.normalize(prior_lw + loglik, axis_name)
    resample_kw = {"threshold": config.ess_threshold, "scheme": config.resampling, "angle_dims": _POSE_ANGLE_DIMS}
    if axis_name is None:
        res, base = finish_step(k_resample, poses, norm, **resample_kw)
    else:
        res, base = sharded.finish_step(k_resample, poses, norm, axis_name, **resample_kw)

    counts_after = jnp.where(lost, rows.counts, new_rows.counts)
    info = extend_info(
        SLAMInfo,
        base,
        lost=lost,
        num_ignored=num_ignored + jnp.sum(leader & ~row_ok).astype(jnp.int32),
        num_new=jnp.sum(write & is_new).astype(jnp.int32),
        num_updated=jnp.sum(write & known).astype(jnp.int32),
        slot_ids=jnp.where(valid, ids, -1),
        slot_estimates=jnp.where(valid[:, None], estimates, 0.0),
        slot_counts=jnp.where(valid, counts_after, 0),
    )
    return StepResult(write_ids, new_rows, res.particles, res.log_weights, info)


def _robot_blocks(axis_name: str | None, rows: int):
    """A context in which a draw of ``rows`` robot particles is this device's block of the whole draw
    (:func:`jaxnav.core.rng.particle_blocks`); nothing without ``axis_name``."""
    return contextlib.nullcontext() if axis_name is None else rng.particle_blocks(axis_name, rows)


def _robot_target(tag_model: TagModel, new_rows: Any, rows: Any, keep: jax.Array, config: Any):
    """The tag model's mixture points for the robot weighting (``TagModel.robot_target``), or ``None``
    for the estimates. A slot whose row is not written (``keep [K]``: a lost step, an update that is
    not finite) gives the points of its gathered row, as the estimates do."""
    if tag_model.robot_target is None or (updated := tag_model.robot_target(new_rows, config)) is None:
        return None
    gathered = tag_model.robot_target(rows, config)
    return jax.tree_util.tree_map(
        lambda old, new: jnp.where(keep.reshape(keep.shape + (1,) * (new.ndim - 1)), old, new), gathered, updated
    )


def resampled_log_weights(row: Any, res: resampling.ResampleResult, config: Any) -> jax.Array:
    """A tag's log-weights after its update. With resampling at every detection
    (``tag_ess_threshold = 1``) they are uniform before and after, and the gathered
    row is returned so that the write-back stays in place (module docstring)."""
    return row.log_weights if config.tag_ess_threshold >= 1.0 else res.log_weights


def map_estimate(state: Any) -> tuple[jax.Array, jax.Array]:
    """``(estimates [max_tags, 2], seen [max_tags])``: every tag's current estimate (m) and whether it was detected.

    Reads the whole table, so it is a read-out for after (or between) steps, not part of one.
    """
    return state.tags.estimates, state.tags.counts > 0


def run_sharded(
    run: Any,
    kernel: Callable[..., Any],
    key: jax.Array,
    state: Any,
    config: Any,
    params: Any,
    controls: jax.Array,
    detections: Any,
    devices: Any = None,
) -> tuple[Any, SLAMInfo]:
    """``run(key, state, config, params, controls, detections)`` with the robot particles spread over
    ``devices`` (PF-SLAM's and PS-SLAM's ``run_sharded``): checked as ``run`` checks, then the program
    of :func:`jaxnav.core.sharded.scan_program`, the robot's ``poses`` and ``log_weights`` in blocks
    over the devices and every other field of the state (the tag table) whole on each. ``kernel`` is
    the filter's, taking ``axis_name``."""
    inputs = run.check(key, state, config, params, controls, detections)
    chosen = sharded.spread_devices(config.num_particles, config.resampling, devices)
    blocks = {field: P() for field in type(state)._fields}
    specs = type(state)(**{**blocks, "poses": P(sharded.PARTICLE_AXIS), "log_weights": P(sharded.PARTICLE_AXIS)})
    return sharded.scan_program(_spread_kernel(kernel), config, chosen, specs)(key, state, params, *inputs)


@lru_cache(maxsize=8)
def _spread_kernel(kernel: Callable[..., Any]) -> Callable[..., Any]:
    """``kernel`` with ``axis_name=PARTICLE_AXIS``, one object per kernel (a key of the program cache)."""
    return partial(kernel, axis_name=sharded.PARTICLE_AXIS)


RUN_SHARDED_DOC = """:func:`run` with the robot particles spread over ``devices`` (default: every local device).

    The ``I`` robot particles are split into ``D`` blocks of ``I / D`` consecutive particles, one per
    device; the tag table is held whole by every device, and every device updates the same detected
    tags from the same robot estimate. Each step runs :func:`kernel` with ``axis_name`` inside
    ``jax.shard_map``: the robot's motion draws are blocks of the whole draw
    (:func:`jaxnav.core.rng.particle_blocks`), its estimate, normaliser, ESS and kidnapping check
    are sums and maxima over the devices, and its resampling is the exact global scheme of
    :mod:`jaxnav.core.sharded` (from the same weights and key, :func:`run`'s ancestors).

    **The same numbers, to float rounding.** The sums over devices run in another order than one
    device's, so the robot estimate may differ from :func:`run`'s in its last bits, and the tags
    updated from it with it; a particle filter can amplify such a difference in a single run (in
    distribution nothing changes). ``tests/slam/test_tag_slam_sharded.py`` measures the agreement.

    What it buys: the robot's step costs ``O(I / D)`` per device, while the tags' ``O(K·J)`` is
    computed on every device. Worth it when ``I`` is large against ``K·J``.

    Args:
        devices: ``None`` (every local device), a number ``D`` of local devices, or a sequence of
            local devices (:func:`jaxnav.core.batch.run_devices`); ``config.num_particles`` must be
            a multiple of ``D``, and ``config.resampling`` ``"systematic"`` or ``"stratified"``
            (:data:`jaxnav.core.sharded.SCHEMES`).

    Returns:
        ``(final_state, trace)`` as :func:`run`; the final robot particles stay spread over the devices.

    The memory guard of :func:`run` is not applied: each device holds ``I / D`` robot particles and
    the whole tag table."""


def filter_spec(
    name: str,
    kernel: Callable[..., Any],
    config_type: type,
    check_params: Callable[[Any, Any], None],
    table_shapes: Callable[[Any], dict[str, tuple[int, ...]]],
    step_doc: str,
    run_doc: str,
    state_type: type | None = None,
    valid_inputs: Callable[..., jax.Array] = inputs_in_domain,
) -> filter_api.FilterSpec:
    """The :class:`~jaxnav.core.filter.FilterSpec` of a tag-SLAM filter: odometry and
    :class:`~jaxnav.models.hf_rfid.TagDetections` in, the state donated to ``step`` (the tag table
    is updated in place)."""
    return filter_api.FilterSpec(
        name=name,
        kernel=kernel,
        config_type=config_type,
        state_type=state_type,
        inputs=("control", "detections"),
        time_inputs=("controls", "detections"),
        check_params=check_params,
        check_state=lambda config, params, state: validate_state(config, state, table_shapes(config)),
        check_inputs=validate_inputs,
        valid_inputs=valid_inputs,
        donate_step=True,
        step_doc=step_doc,
        run_doc=run_doc,
    )
