"""PF-SLAM ([W] Alg. 1): a particle filter for the robot and an independent particle filter per RFID tag
(or per landmark of any :class:`~jaxnav.models.sensor.LandmarkSensor`, ``PFSLAMConfig.sensor``).

**Overview**

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
:mod:`jaxnav.slam.tag_slam`.

Interface::

    config = pf_slam.PFSLAMConfig(num_particles=500, num_tag_particles=100, max_tags=carpet.layout.num_tags)
    params = pf_slam.PFSLAMParams(motion=OmniNoise(sd), sensor=hf_rfid.reader_params(0.06))
    state = pf_slam.init(key, config, params, start_pose)
    state, info = pf_slam.step(key, state, config, params, odometry_t, detections_t)
    final, trace = pf_slam.run(key, state, config, params, odometry, detections)
    tags, seen = pf_slam.map_estimate(final)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, resampling, weights
from jaxnav.core.validation import check_finite
from jaxnav.slam import tag_slam
from jaxnav.slam.tag_slam import SLAMInfo, check_capacity

__all__ = [
    "PFSLAMConfig",
    "PFSLAMParams",
    "TagTable",
    "PFSLAMState",
    "SLAMInfo",
    "init",
    "kernel",
    "step",
    "run",
    "run_sharded",
    "map_estimate",
    "surveyed_tags",
    "check_capacity",
]


@dataclass(frozen=True)
class PFSLAMConfig(tag_slam.TagSLAMConfig):
    """Static configuration of PF-SLAM: the fields of :class:`~jaxnav.slam.tag_slam.TagSLAMConfig`."""


class PFSLAMParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: noise of the motion model (``OmniNoise(sd [3])`` for [W] eq. 3.6; m/s, m/s, rad/s).
        sensor: the parameters of ``config.sensor``: :class:`jaxnav.models.hf_rfid.HFReaderParams`
            (reader offsets, σ, log β) for the default HF readers.
    """

    motion: Any
    sensor: Any


class TagTable(NamedTuple):
    """Every tag's particle filter, indexed by tag ID (leading axis ``max_tags``).

    Attributes:
        particles: ``[max_tags, J, D]`` tag particles in the world frame (m; ``D = 2`` for points).
        log_weights: ``[max_tags, J]`` normalised.
        estimates: ``[max_tags, D]`` weighted mean of each tag's particles (m).
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
    t, j, d = config.max_tags, config.num_tag_particles, config.sensor.landmark_dim
    return TagTable(
        jnp.zeros((t, j, d), dtype),
        jnp.full((t, j), -np.log(j), dtype),
        jnp.zeros((t, d), dtype),
        jnp.zeros((t,), jnp.int32),
    )


def _propose(key, row: TagTable, is_new, pose_est, init_z, config, params):
    """[W] Alg. 1 lines 6–11: a new tag's particles uniform over the initialising footprint, or the row's."""
    j = config.num_tag_particles
    fresh = config.sensor.initialise(jax.random.fold_in(key, 0), pose_est, init_z, params.sensor, j)
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
    return TagTable(res.particles, tag_slam.resampled_log_weights(row, res, config), estimate, row.counts + 1)


TAG_MODEL = tag_slam.TagModel(_propose, _finish)


def _table_shapes(config: PFSLAMConfig) -> dict[str, tuple[int, ...]]:
    t, j, d = config.max_tags, config.num_tag_particles, config.sensor.landmark_dim
    return {"particles": (t, j, d), "log_weights": (t, j), "estimates": (t, d), "counts": (t,)}


def _validate_params(config: PFSLAMConfig, params: PFSLAMParams) -> None:
    tag_slam.validate_params(config, params, PFSLAMParams)


@memory.guard_init
def init(
    key: jax.Array, config: PFSLAMConfig, params: PFSLAMParams, initial_pose: Any, initial_sd: Any = None
) -> PFSLAMState:
    """Robot particles at ``N(initial_pose, diag(initial_sd²))`` (default: all at the known start, [W] Alg. 1) and an empty map."""
    filter_api.check_key(key)
    _validate_params(config, params)
    poses, log_w = tag_slam.initial_particles(key, config, initial_pose, initial_sd)
    return PFSLAMState(poses, log_w, _empty_table(config, poses.dtype))


def surveyed_tags(config: PFSLAMConfig, positions: Any) -> TagTable:
    """A tag table whose first ``M`` tags are surveyed: every one of tag ``n``'s ``J`` particles at
    ``positions[n]`` (``[M, D]``, m, ``M ≤ max_tags``), its estimate there and its count 1 (seen), the
    other rows empty. Put in a state from :func:`init` (``state._replace(tags=...)``), PF-SLAM becomes
    localization on the surveyed map through the same sensor model: PF-SLAM's tag particles are never
    jittered, so resampling keeps them on the surveyed points, and the robot is weighted against them.
    """
    pos = jnp.asarray(positions, jnp.result_type(float))
    t, j, d = config.max_tags, config.num_tag_particles, config.sensor.landmark_dim
    if pos.ndim != 2 or pos.shape[1] != d or pos.shape[0] > t:
        raise ValueError(f"positions must be [M, {d}] with M ≤ max_tags = {t}, got shape {tuple(pos.shape)}")
    check_finite("positions", pos)
    table = _empty_table(config, pos.dtype)
    m = pos.shape[0]
    return table._replace(
        particles=table.particles.at[:m].set(jnp.broadcast_to(pos[:, None, :], (m, j, d))),
        estimates=table.estimates.at[:m].set(pos),
        counts=table.counts.at[:m].set(1),
    )


def kernel(
    key: jax.Array,
    state: PFSLAMState,
    config: PFSLAMConfig,
    params: PFSLAMParams,
    control: jax.Array,
    detections: Any,
    axis_name: str | None = None,
) -> tuple[PFSLAMState, SLAMInfo]:
    """One PF-SLAM step ([W] Alg. 1), pure and traceable (:func:`step` is it validated and jitted).

    A step whose odometry or parameters are outside the models' domain (refused on the host, so
    only inside a caller's ``jit``) keeps the state and sets ``info.invalid_inputs``
    (:func:`jaxnav.slam.tag_slam.slam_step`). ``axis_name``: inside ``jax.shard_map``, the robot particles
    are this device's block (:func:`run_sharded`)."""
    return tag_slam.slam_step(
        key, state, config, params, control, detections, TAG_MODEL, tag_slam.inputs_in_domain, axis_name=axis_name
    )


step, run = filter_api.build(
    tag_slam.filter_spec(
        "PF-SLAM",
        kernel,
        PFSLAMConfig,
        _validate_params,
        _table_shapes,
        step_doc="""One PF-SLAM step ([W] Alg. 1) with the odometry ``control [control_dim]`` and one step's
        :class:`~jaxnav.models.hf_rfid.TagDetections` (slots ``[K]``). Returns ``(state, SLAMInfo)``.""",
        run_doc="""PF-SLAM over a sequence: ``controls [T, control_dim]`` odometry (for "omni":
        ``(v_x, v_y, ω, Δt)``) and detections with leading axis ``T``; ``state`` from :func:`init`.
        ``trace`` is a :class:`~jaxnav.slam.tag_slam.SLAMInfo` with leading axis ``T``. ``donate_state=True`` matters for
        large tables: without it the initial table is copied into the scan at every call.""",
        state_type=PFSLAMState,
    ),
    __name__,
)


map_estimate = jax.jit(tag_slam.map_estimate)
map_estimate.__doc__ = tag_slam.map_estimate.__doc__


def run_sharded(
    key: jax.Array,
    state: PFSLAMState,
    config: PFSLAMConfig,
    params: PFSLAMParams,
    controls: jax.Array,
    detections: Any,
    devices: Any = None,
) -> tuple[PFSLAMState, SLAMInfo]:
    return tag_slam.run_sharded(run, kernel, key, state, config, params, controls, detections, devices)


run_sharded.__doc__ = tag_slam.RUN_SHARDED_DOC
