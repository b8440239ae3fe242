"""PF-SLAM ([W] Alg. 1): a particle filter for the robot and an independent particle filter per RFID tag.

Overview
--------
The HF-RFID SLAM of [W] ch. 3. The robot pose is tracked by ``I`` particles
(eq. 3.4); every tag ``n`` detected so far has its own set of ``J`` particles
``ʷm_n^{[j]}`` with log-weights (eq. 3.5). Per step, for the tags detected
by the robot's readers:

* a tag seen for the first time gets ``J`` particles uniform over the
  detecting reader's footprint, in the world frame from the current robot
  estimate (Alg. 1 line 7);
* a re-detected tag's particles are weighted by [W] eq. 3.7 with the robot
  estimate (line 10), then resampled (lines 13–16; conditional on the tag
  ESS, every time by default); its estimate is their weighted mean;
* the robot particles are weighted by eq. 3.7 against the updated tag
  estimates and resampled (lines 17–24).

The tag particles are never jittered: after repeated resampling a tag's set
collapses onto few distinct points, the degeneracy [W] ch. 4 cures with the
smoother of :mod:`jaxnav.slam.ps_slam`.

Everything is fixed-capacity: a table of ``max_tags`` rows indexed by tag ID
(with a detection count; ``count > 0`` is the seen mask). A step gathers the
``K`` detected rows, updates them ``vmap``-ed over slots and scatters them
back, so it costs ``O(I + K·J)`` however many tags the map holds ([W]
§3.3.1, Figs. 3.6 and 3.8). The shared step, its treatment of two readers
detecting one tag, and the kidnapping recovery are documented in
:mod:`jaxnav.slam._tag_slam`.

Interface::

    config = pf_slam.PFSLAMConfig(num_particles=500, num_tag_particles=100, max_tags=carpet.layout.num_tags)
    params = pf_slam.PFSLAMParams(motion=OmniNoise(sd), sensor=hf_rfid.reader_params(0.06))
    state = pf_slam.init(key, config, params, start_pose)
    state, info = pf_slam.step(key, state, config, params, odometry_t, detections_t)
    final, trace = pf_slam.run(key, config, params, odometry, detections, state)
    tags, seen = pf_slam.map_estimate(final)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import resampling, weights
from jaxnav.core.batch import scan_filter
from jaxnav.models import hf_rfid
from jaxnav.slam import _tag_slam
from jaxnav.slam._tag_slam import SLAMInfo, check_capacity

__all__ = [
    "PFSLAMConfig",
    "PFSLAMParams",
    "TagTable",
    "PFSLAMState",
    "SLAMInfo",
    "init",
    "step",
    "run",
    "map_estimate",
    "check_capacity",
]


@dataclass(frozen=True)
class PFSLAMConfig:
    """Static configuration of PF-SLAM.

    Attributes:
        num_particles: ``I``, robot particles (500 in [W]).
        num_tag_particles: ``J``, particles per tag (100 in [W]).
        max_tags: tag-table capacity; tag IDs ``≥ max_tags`` are dropped and counted.
        motion_model: name in :data:`jaxnav.models.motion.MODELS`; "omni" is [W] eq. 3.6.
        resampling: scheme for robot and tag particles (:data:`jaxnav.core.resampling.SCHEMES`).
        ess_threshold: robot resampling when ESS < ``ess_threshold · I``; 1.0 = every step ([W] Alg. 1).
        tag_ess_threshold: the same for a tag's particles at each detection; 1.0 = always ([W] Alg. 1).
        recovery: redraw the robot particles when it is lost (kidnapping, [W] §3.4.3; see ``_tag_slam``).
        recovery_log_likelihood: lost when the best robot particle averages below this per re-detection.
        recovery_heading_sd: ``None``: redrawn particles get a uniform heading (the robot may have
            been turned); a number: each keeps its own heading with a uniform error of this standard deviation (rad).
        parallel_slots: ``None`` (default): a step processes all ``K`` detection slots. A number
            ``L < K``: a step moves the valid slots to the front and processes the first ``L``,
            and all ``K`` only when more than ``L`` are valid, at the cost of ``L`` slots. The
            results are those of all slots up to float rounding: sums over the slots run in
            another order, and a particle filter can amplify a last-bit difference in a single
            run (in distribution nothing changes). Derivatives are those of the all-slot step.
            Worth it when the capacity ``K`` is much larger than what a step sees: at 100 tags/m²
            with 60 mm readers ``K = 24`` for about 3 detections; Table 3.1's cell, R = 25
            vmapped runs: 0.37 → 0.32 s per run with ``L = 8``; the online step (500 / 100
            particles) 8–10 % faster. Under ``vmap`` a step where one run of the batch has more
            than ``L`` valid slots costs all ``K`` for the batch: choose ``L`` above what a step
            rarely exceeds (e.g. ``⌈λ + 3√λ⌉`` for ``λ`` expected detections per step).
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

    def __post_init__(self) -> None:
        _tag_slam.validate_common_config(self)


class PFSLAMParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: noise of the motion model (``OmniNoise(sd [3])`` for [W] eq. 3.6; m/s, m/s, rad/s).
        sensor: :class:`jaxnav.models.hf_rfid.HFReaderParams` (reader offsets, σ, log β).
    """

    motion: Any
    sensor: hf_rfid.HFReaderParams


class TagTable(NamedTuple):
    """Every tag's particle filter, indexed by tag ID (leading axis ``max_tags``).

    Attributes:
        particles: ``[max_tags, J, 2]`` tag particles in the world frame (m).
        log_weights: ``[max_tags, J]`` normalised.
        estimates: ``[max_tags, 2]`` weighted mean of each tag's particles (m).
        counts: ``[max_tags]`` int32, steps in which the tag was detected (0 = never seen).
    """

    particles: jax.Array
    log_weights: jax.Array
    estimates: jax.Array
    counts: jax.Array


class PFSLAMState(NamedTuple):
    """Robot particles and the tag table.

    Attributes:
        poses: ``[I, 3]`` robot particles (m, m, rad).
        log_weights: ``[I]`` normalised.
        tags: :class:`TagTable`.
    """

    poses: jax.Array
    log_weights: jax.Array
    tags: TagTable


def _empty_table(config: PFSLAMConfig, dtype) -> TagTable:
    t, j = config.max_tags, config.num_tag_particles
    return TagTable(
        jnp.zeros((t, j, 2), dtype),
        jnp.full((t, j), -np.log(j), dtype),
        jnp.zeros((t, 2), dtype),
        jnp.zeros((t,), jnp.int32),
    )


def _propose(key, row: TagTable, is_new, pose_est, init_offset, config, params):
    """[W] Alg. 1 lines 6–11: a new tag's particles uniform over the initialising footprint, or the row's."""
    j = config.num_tag_particles
    fresh = hf_rfid.sample_in_footprint(jax.random.fold_in(key, 0), pose_est, init_offset, params.sensor.half_width, j)
    particles = jnp.where(is_new, fresh, row.particles)
    log_w = jnp.where(is_new, jnp.full_like(row.log_weights, -np.log(j)), row.log_weights)
    return particles, log_w


def _finish(key, row: TagTable, particles, log_w, loglik, is_new, config, params) -> TagTable:
    """[W] Alg. 1 lines 10–16: weight by eq. 3.7, resample, estimate."""
    norm = weights.normalize(log_w + loglik)
    res = resampling.conditional_resample(
        jax.random.fold_in(key, 1),
        particles,
        norm.log_weights,
        threshold=config.tag_ess_threshold,
        scheme=config.resampling,
        normalized=True,
    )
    estimate = weights.mean_from_probabilities(res.particles, jnp.exp(res.log_weights))
    return TagTable(res.particles, _tag_slam.resampled_log_weights(row, res, config), estimate, row.counts + 1)


TAG_MODEL = _tag_slam.TagModel(_propose, _finish)


def _table_shapes(config: PFSLAMConfig) -> dict[str, tuple[int, ...]]:
    t, j = config.max_tags, config.num_tag_particles
    return {"particles": (t, j, 2), "log_weights": (t, j), "estimates": (t, 2), "counts": (t,)}


def init(key: jax.Array, config: PFSLAMConfig, params: PFSLAMParams, initial_pose, initial_sd=None) -> PFSLAMState:
    """Robot particles at ``N(initial_pose, diag(initial_sd²))`` (default: all at the known start, [W] Alg. 1) and an empty map."""
    _tag_slam.validate_params(config, params, PFSLAMParams)
    poses, log_w = _tag_slam.initial_particles(key, config, initial_pose, initial_sd)
    return PFSLAMState(poses, log_w, _empty_table(config, poses.dtype))


def _step(key, state: PFSLAMState, config: PFSLAMConfig, params: PFSLAMParams, control, detections):
    return _tag_slam.slam_step(key, state, config, params, control, detections, TAG_MODEL)


_step_jit = jax.jit(_step, static_argnames=("config",), donate_argnames=("state",))


def _validate(config, params, state, controls, detections, time_axis):
    _tag_slam.validate_params(config, params, PFSLAMParams)
    _tag_slam.validate_state(config, state, _table_shapes(config))
    _tag_slam.validate_inputs(config, params, controls, detections, time_axis)


def step(
    key, state: PFSLAMState, config: PFSLAMConfig, params: PFSLAMParams, control, detections: hf_rfid.TagDetections
):
    """One PF-SLAM step, validated on the host, then jitted.

    ``state`` is *donated*: the tag table is updated in place, so do not use
    the old ``state`` after the call. Returns ``(state, SLAMInfo)``.
    """
    _validate(config, params, state, control, detections, time_axis=False)
    return _step_jit(key, state, config, params, control, detections)


def _run_scan(key, config, params, controls, detections, state):
    return scan_filter(_step, config, params, controls, detections, state, key)


_run_jit = jax.jit(_run_scan, static_argnames=("config",))
_run_jit_donated = jax.jit(_run_scan, static_argnames=("config",), donate_argnames=("state",))


def run(
    key,
    config: PFSLAMConfig,
    params: PFSLAMParams,
    controls,
    detections: hf_rfid.TagDetections,
    initial_state: PFSLAMState,
    donate_state: bool = False,
):
    """Filter a sequence in one ``lax.scan``; step ``t`` uses ``fold_in(key, t)``.

    Args:
        controls: ``[T, control_dim]`` odometry (for "omni": ``(v_x, v_y, ω, Δt)``).
        detections: :class:`~jaxnav.models.hf_rfid.TagDetections` with leading axis ``T``.
        donate_state: reuse ``initial_state``'s buffers for the filter's state, which must not be
            used after the call. Without it XLA copies the initial state into the scan once per
            call: for large tables that copy costs more than the steps (S2: PF-SLAM at 100,000
            tags, 120 MB, 0.55 → 0.27 ms per step over 200 steps).

    Returns ``(final_state, trace)``, ``trace`` a :class:`SLAMInfo` with leading axis ``T``.
    """
    _validate(config, params, initial_state, controls, detections, time_axis=True)
    run_jit = _run_jit_donated if donate_state else _run_jit
    return run_jit(key, config, params, controls, detections, initial_state)


map_estimate = jax.jit(_tag_slam.map_estimate)
map_estimate.__doc__ = _tag_slam.map_estimate.__doc__
