"""PS-SLAM ([W] Alg. 2): a particle filter for the robot and a fixed-lag particle smoother per RFID tag
(or per landmark of any :class:`~jaxnav.models.sensor.LandmarkSensor`, ``PSSLAMConfig.sensor``).

**Overview**

As :mod:`jaxnav.slam.pf_slam`, except that each detected tag is estimated by
Kitagawa's fixed-lag particle smoother ([W] §4.1–4.2, eq. 4.4). A tag
particle carries the ring of its last ``L`` states (eq. 4.5; ``L`` = 20–30
in [W] §4.1). On a re-detection of tag ``n`` (Alg. 2 lines 9–23):

1. every particle moves by a Gaussian jitter, ``m_t = m_{t−1} + N(0, s²)``
   with ``s = params.tag_jitter_sd`` (line 11);
2. it is weighted by [W] eq. 3.7 with the robot estimate (line 12) and the
   new state is pushed onto its ring (line 13);
3. the particles are resampled (lines 16–19). Resampling selects whole
   lagged states: a chosen particle's *history moves with it* (Kitagawa
   1996 resamples the augmented state ``x_{t−L+1:t}``), so the ring rows are
   gathered with the same ancestor indices;
4. the smoothed particle is the mean of its ring, ``m̄^{[j]} = Σ_{i=t+1−L}^{t} m_i^{[j]} / L``
   (over the states held, while fewer than ``L``; lines 20–22), and the
   tag's estimate is the weighted mean of the smoothed particles (line 24).
   The robot is then weighted against that estimate (lines 25–27).

A new tag's particles are spread over the detecting reader's footprint and
stored as the first entry of their rings (lines 6–8). The ring's position
is the tag's detection count mod ``L``, so no head or count is stored
twice. The ring lives in the tag table as ``history [max_tags, L, J, 2]``:
a step gathers and scatters the ``K`` detected tags' rings only, ``O(K·L·J)``,
independent of the map size; the memory is ``O(max_tags·L·J)``.

**Readings**

[W] Alg. 2 and §4.1–4.2 leave the following open. Each is a static field of :class:`PSSLAMConfig`
whose default is the reading above; the ablations ``ps-slam-readings`` and ``ps-slam-mixtures-tuned``
(:mod:`jaxnav.experiments.hf_slam.readings`) run every value against PF-SLAM.

==========  ====================================================  ========================================
Alg. 2      what the text leaves open                             option (default first)
==========  ====================================================  ========================================
6–8         where a new tag's particles are drawn: "in the        ``tag_init``: ``"footprint"`` (from
            detection area of the reader", seen from the robot    ``x̂``), ``"robot_particles"`` (each
            estimate or from each robot particle                  from a robot particle drawn by weight)

11          the jitter's standard deviation ("a Gaussian          ``params.tag_jitter_sd``
            random number"): [W] gives none                       (:func:`default_jitter`: σ/10)

12–13, 20   the lag ``L``: 20–30 ([W] §4.1, after its ref. 85);   ``lag`` (20)
            the ring holds the tag's last ``L`` *detections*,
            not ``L`` time steps (a tag is updated only when
            it is detected)

16–18       whether a resampled particle takes its ancestor's     ``history``: ``"with_particles"``,
            ring (Kitagawa's augmented state, eq. 4.4) or ring    ``"in_place"``
            ``j`` stays with slot ``j``

16–18       "Add m̄^{[k]} to S_{n,t}": the resampled set holds     ``resampled_state``: ``"current"``,
            the current states (smoothing only makes the          ``"smoothed"`` (m̄^{[k]}, fed back: the
            estimate) or the ring means                           next jitter starts from it)

16–24       the order of resampling and smoothing: the text       ``smoothing_order``:
            has smoothing follow resampling; the estimate may     ``"after_resampling"``,
            also weight the ring means by line 12's weights       ``"before_resampling"``

24–26       what the robot is weighted against: "Update x_n       ``robot_target``: ``"smoothed_mean"``,
            based on S̃_{n,t}", then "as Algorithm 1"              ``"smoothed_particles"``,
                                                                  ``"particles"``, ``"current_mean"``
==========  ====================================================  ========================================

The order of jitter (line 11), weighting (line 12) and pushing onto the ring (line 13) is fixed by
the text; so is a new tag's weight 1 (line 7: uniform) and its first state stored in the ring
(line 8). ``robot_target`` other than ``"smoothed_mean"`` weights the robot by a mixture over ``J``
points per re-detected tag (``K·I·J`` likelihoods; ``"current_mean"`` by one point, as PF-SLAM)
and needs ``robot_likelihood="estimate"`` (``"mixture"`` weights the robot *before* the tag update).

Interface: as PF-SLAM, with ``PSSLAMConfig.lag`` and ``PSSLAMParams.tag_jitter_sd``::

    config = ps_slam.PSSLAMConfig(max_tags=carpet.layout.num_tags, lag=20)
    params = ps_slam.PSSLAMParams(OmniNoise(sd), hf_rfid.reader_params(0.3), tag_jitter_sd=0.015)
    final, trace = ps_slam.run(key, ps_slam.init(key0, config, params, start), config, params, odometry, detections)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, resampling, ring, rng, weights
from jaxnav.core.validation import all_nonnegative, check_choice, check_nonnegative, check_positive_int, check_shape
from jaxnav.models import hf_rfid
from jaxnav.slam import tag_slam
from jaxnav.slam.tag_slam import SLAMInfo, check_capacity

__all__ = [
    "PSSLAMConfig",
    "PSSLAMParams",
    "ROBOT_TARGETS",
    "RESAMPLED_STATES",
    "HISTORIES",
    "SMOOTHING_ORDERS",
    "TAG_INITS",
    "SmootherTable",
    "PSSLAMState",
    "SLAMInfo",
    "default_jitter",
    "init",
    "kernel",
    "step",
    "run",
    "run_sharded",
    "map_estimate",
    "check_capacity",
]


ROBOT_TARGETS = ("smoothed_mean", "smoothed_particles", "particles", "current_mean")
"""The choices of ``PSSLAMConfig.robot_target`` ([W] Alg. 2 lines 24–26)."""
RESAMPLED_STATES = ("current", "smoothed")
"""The choices of ``PSSLAMConfig.resampled_state`` ([W] Alg. 2 lines 16–18)."""
HISTORIES = ("with_particles", "in_place")
"""The choices of ``PSSLAMConfig.history`` ([W] Alg. 2 lines 16–18 with eq. 4.4)."""
SMOOTHING_ORDERS = ("after_resampling", "before_resampling")
"""The choices of ``PSSLAMConfig.smoothing_order`` ([W] Alg. 2 lines 16–24)."""
TAG_INITS = ("footprint", "robot_particles")
"""The choices of ``PSSLAMConfig.tag_init`` ([W] Alg. 2 lines 6–8)."""


@dataclass(frozen=True)
class PSSLAMConfig(tag_slam.TagSLAMConfig):
    """Static configuration of PS-SLAM: the fields of :class:`~jaxnav.slam.tag_slam.TagSLAMConfig`, ``lag``
    and the readings of [W] Alg. 2 where the text leaves a choice (module docstring, "Readings").
    Every default is the reading jaxnav has always run.

    Attributes:
        lag: ``L``, states kept per tag particle (20–30 in [W] §4.1); ``L = 1`` smooths nothing.
        robot_target: what a re-detected tag's robot weight is computed against (lines 24–26, eq. 3.7):
            ``"smoothed_mean"`` (default): the tag estimate, the weighted mean of the smoothed particles;
            ``"smoothed_particles"``: the smoothed particles ``m̄^{[j]}`` as a mixture,
            ``log Σ_j w_j Π_k p(z_k | x, m̄^{[j]})``; ``"particles"``: the current (resampled) tag
            particles ``m_t^{[j]}`` as a mixture; ``"current_mean"``: the weighted mean of the current
            particles, as PF-SLAM (the smoother then only makes the reported map). The mixtures cost
            ``K·I·J`` likelihoods instead of ``K·I``. Only with ``robot_likelihood="estimate"``.
        resampled_state: what a resampled particle holds (lines 16–18, "Add m̄^{[k]} to S_{n,t}"):
            ``"current"`` (default): its current state ``m_t^{[k]}``, smoothing only makes the estimate;
            ``"smoothed"``: its ring mean ``m̄^{[k]}``, so the smoothed value is jittered at the next
            detection (the ring keeps the raw states of line 13).
        history: ``"with_particles"`` (default): a resampled particle takes its ancestor's ring (Kitagawa's
            augmented state, eq. 4.4); ``"in_place"``: ring ``j`` stays with slot ``j``.
        smoothing_order: ``"after_resampling"`` (default, the order of lines 16–24 and of [W] §4.2's
            text): the estimate is the uniform mean of the resampled smoothed particles;
            ``"before_resampling"``: the estimate is ``Σ_j w_j m̄^{[j]}`` with the weights of line 12,
            before resampling adds its noise.
        tag_init: where a new tag's particles are drawn (lines 6–8): ``"footprint"`` (default): over the
            detecting reader's footprint seen from the robot estimate ``x̂``; ``"robot_particles"``:
            particle ``j`` over the footprint seen from a robot particle drawn by its weight, so the
            tag's set carries the robot's uncertainty.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles", "num_tag_particles", "max_tags", "lag")
    lag: int = 20
    robot_target: str = "smoothed_mean"
    resampled_state: str = "current"
    history: str = "with_particles"
    smoothing_order: str = "after_resampling"
    tag_init: str = "footprint"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive_int("lag", self.lag)
        check_choice("robot_target", self.robot_target, ROBOT_TARGETS)
        check_choice("resampled_state", self.resampled_state, RESAMPLED_STATES)
        check_choice("history", self.history, HISTORIES)
        check_choice("smoothing_order", self.smoothing_order, SMOOTHING_ORDERS)
        check_choice("tag_init", self.tag_init, TAG_INITS)
        if self.robot_target != "smoothed_mean" and self.robot_likelihood != "estimate":
            raise ValueError(
                f"robot_target={self.robot_target!r} needs robot_likelihood='estimate' (the mixture of "
                f"robot_likelihood='mixture' weights the robot before the tag update), got {self.robot_likelihood!r}"
            )


class PSSLAMParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: motion-model noise (``OmniNoise`` for [W] eq. 3.6).
        sensor: the parameters of ``config.sensor`` (:class:`jaxnav.models.hf_rfid.HFReaderParams` for
            the default HF readers).
        tag_jitter_sd: standard deviation of the Gaussian move of a tag particle at each re-detection
            ([W] Alg. 2 line 11; m). [W] gives no value; ``default_jitter`` is σ/10.
    """

    motion: Any
    sensor: Any
    tag_jitter_sd: jax.Array


def default_jitter(sensor: hf_rfid.HFReaderParams) -> jax.Array:
    """A tag jitter of a tenth of the footprint half-width σ (3 mm for 60 mm readers, 15 mm for 300 mm)."""
    return jnp.asarray(sensor.half_width) / 10.0


class SmootherTable(NamedTuple):
    """Every tag's fixed-lag smoother, indexed by tag ID.

    Attributes:
        particles: ``[max_tags, J, D]`` current tag particles (m; ``D = 2`` for points).
        log_weights: ``[max_tags, J]`` normalised.
        estimates: ``[max_tags, D]`` smoothed estimate: weighted mean of the ring means (m).
        counts: ``[max_tags]`` int32 detection count; the ring holds ``min(count, L)`` states and
            its next slot is ``count mod L``.
        history: ``[max_tags, L, J, D]`` the rings of past states (m).
    """

    particles: jax.Array
    log_weights: jax.Array
    estimates: jax.Array
    counts: jax.Array
    history: jax.Array


class PSSLAMState(NamedTuple):
    """Robot particles (``poses [I, 3]``, ``log_weights [I]``) and the smoother table ``tags``."""

    poses: jax.Array
    log_weights: jax.Array
    tags: SmootherTable


def _empty_table(config: PSSLAMConfig, dtype) -> SmootherTable:
    t, j, lag, d = config.max_tags, config.num_tag_particles, config.lag, config.sensor.landmark_dim
    return SmootherTable(
        jnp.zeros((t, j, d), dtype),
        jnp.full((t, j), -np.log(j), dtype),
        jnp.zeros((t, d), dtype),
        jnp.zeros((t,), jnp.int32),
        jnp.zeros((t, lag, j, d), dtype),
    )


def _fresh_particles(key, pose_est, init_z, config, params, robot):
    """A new tag's ``J`` particles (Alg. 2 lines 6–7): over the footprint seen from ``x̂``, or with
    ``tag_init="robot_particles"`` each over the footprint seen from a robot particle drawn by weight."""
    j = config.num_tag_particles
    if config.tag_init == "footprint":
        return config.sensor.initialise(key, pose_est, init_z, params.sensor, j)
    poses, log_w = robot
    picks = jax.random.categorical(jax.random.fold_in(key, 1), log_w, shape=(j,))
    keys = jax.random.split(key, j)
    one = lambda k, pose: config.sensor.initialise(k, pose, init_z, params.sensor, 1)[0]  # noqa: E731
    return jax.vmap(one)(keys, poses[picks])


def _propose(key, row: SmootherTable, is_new, pose_est, init_z, config, params, robot=None):
    """[W] Alg. 2 lines 6–11: a new tag's particles over the initialising footprint, or the row's moved by the jitter.

    ``robot``: the robot's moved particles and log-weights ``([I, 3], [I])``, read by ``tag_init="robot_particles"``.
    """
    j = config.num_tag_particles
    fresh = _fresh_particles(jax.random.fold_in(key, 0), pose_est, init_z, config, params, robot)
    noise = rng.normal(jax.random.fold_in(key, 2), row.particles.shape, row.particles.dtype)
    particles = jnp.where(is_new, fresh, row.particles + params.tag_jitter_sd * noise)
    log_w = jnp.where(is_new, jnp.full_like(row.log_weights, -np.log(j)), row.log_weights)
    return particles, log_w


def _finish(key, row: SmootherTable, particles, log_w, loglik, is_new, config, params) -> SmootherTable:
    """[W] Alg. 2 lines 12–24: weight, push onto the ring, resample (with histories), smooth.

    The readings of lines 16–24 (module docstring) are ``config.resampled_state``, ``config.history``
    and ``config.smoothing_order``."""
    lag = config.lag
    norm = weights.normalize(log_w + loglik)
    count = jnp.where(is_new, 0, row.counts)
    buf = ring.ring_push(ring.RingBuffer(row.history, count % lag, jnp.minimum(count, lag)), particles)
    res = resampling.conditional_resample(
        jax.random.fold_in(key, 1),
        particles,
        norm.log_weights,
        threshold=config.tag_ess_threshold,
        scheme=config.resampling,
        normalized=True,
    )
    before = ring.ring_mean(buf) if _smooths_before_resampling(config) else None  # m̄^{[k]} of line 17
    if config.history == "with_particles":
        buf = buf._replace(data=jnp.take(buf.data, res.ancestors, axis=1))  # histories move with their particles
    new_particles = res.particles if config.resampled_state == "current" else jnp.take(before, res.ancestors, axis=0)
    if config.smoothing_order == "after_resampling":
        smoothed = ring.ring_mean(buf)  # [J, 2]
        estimate = weights.mean_from_probabilities(smoothed, jnp.exp(res.log_weights))
    else:
        estimate = weights.mean_from_probabilities(before, jnp.exp(norm.log_weights))
    return SmootherTable(new_particles, tag_slam.resampled_log_weights(row, res, config), estimate, count + 1, buf.data)


def _smooths_before_resampling(config: PSSLAMConfig) -> bool:
    """Whether the ring means are needed before the resampling (lines 20–22 moved, or line 17's ``m̄^{[k]}``)."""
    return config.smoothing_order == "before_resampling" or config.resampled_state == "smoothed"


def _smoothed_particles(row: SmootherTable, config: PSSLAMConfig) -> jax.Array:
    """``[J, D]`` the ring means ``m̄^{[j]}`` of a row after its update (lines 20–22)."""
    held = jnp.minimum(row.counts, config.lag)
    return ring.ring_mean(ring.RingBuffer(row.history, row.counts % config.lag, held))


def _robot_target(rows: SmootherTable, config: PSSLAMConfig):
    """What the robot is weighted against (``config.robot_target``; lines 24–26): ``None`` for the
    tag estimate, else the points ``[K, P, D]`` and normalised log-weights ``[K, P]`` of a mixture."""
    target = config.robot_target
    if target == "smoothed_mean":
        return None
    lw = rows.log_weights
    if target == "current_mean":
        mean = jax.vmap(lambda p, w: weights.mean_from_probabilities(p, jnp.exp(w)))(rows.particles, lw)
        return mean[:, None, :], jnp.zeros(lw.shape[:1] + (1,), lw.dtype)
    if target == "particles":
        return rows.particles, lw
    return jax.vmap(lambda r: _smoothed_particles(r, config))(rows), lw


TAG_MODEL = tag_slam.TagModel(_propose, _finish, _robot_target, lambda config: config.tag_init != "footprint")


def _table_shapes(config: PSSLAMConfig) -> dict[str, tuple[int, ...]]:
    t, j, d = config.max_tags, config.num_tag_particles, config.sensor.landmark_dim
    return {
        "particles": (t, j, d),
        "log_weights": (t, j),
        "estimates": (t, d),
        "counts": (t,),
        "history": (t, config.lag, j, d),
    }


def _validate_params(config: PSSLAMConfig, params: PSSLAMParams) -> None:
    tag_slam.validate_params(config, params, PSSLAMParams)
    check_shape("params.tag_jitter_sd", params.tag_jitter_sd, ())
    check_nonnegative("params.tag_jitter_sd", params.tag_jitter_sd)


@memory.guard_init
def init(
    key: jax.Array, config: PSSLAMConfig, params: PSSLAMParams, initial_pose: Any, initial_sd: Any = None
) -> PSSLAMState:
    """Robot particles at ``N(initial_pose, diag(initial_sd²))`` (default: the known start) and an empty map."""
    filter_api.check_key(key)
    _validate_params(config, params)
    poses, log_w = tag_slam.initial_particles(key, config, initial_pose, initial_sd)
    return PSSLAMState(poses, log_w, _empty_table(config, poses.dtype))


def _inputs_in_domain(config: PSSLAMConfig, params: PSSLAMParams, control: jax.Array, detections: Any) -> jax.Array:
    """``bool[]``: :func:`jaxnav.slam.tag_slam.inputs_in_domain` and a tag jitter ``≥ 0`` m."""
    return tag_slam.inputs_in_domain(config, params, control, detections) & all_nonnegative(params.tag_jitter_sd)


def kernel(
    key: jax.Array,
    state: PSSLAMState,
    config: PSSLAMConfig,
    params: PSSLAMParams,
    control: jax.Array,
    detections: Any,
    axis_name: str | None = None,
) -> tuple[PSSLAMState, SLAMInfo]:
    """One PS-SLAM step ([W] Alg. 2), pure and traceable (:func:`step` is it validated and jitted).

    A step whose odometry or parameters are outside the models' domain (refused on the host, so
    only inside a caller's ``jit``) keeps the state and sets ``info.invalid_inputs``
    (:func:`jaxnav.slam.tag_slam.slam_step`). ``axis_name``: inside ``jax.shard_map``, the robot particles
    are this device's block (:func:`run_sharded`)."""
    return tag_slam.slam_step(
        key, state, config, params, control, detections, TAG_MODEL, _inputs_in_domain, axis_name=axis_name
    )


step, run = filter_api.build(
    tag_slam.filter_spec(
        "PS-SLAM",
        kernel,
        PSSLAMConfig,
        _validate_params,
        _table_shapes,
        step_doc="""One PS-SLAM step ([W] Alg. 2) with the odometry ``control [control_dim]`` and one step's
        :class:`~jaxnav.models.hf_rfid.TagDetections` (slots ``[K]``). Returns ``(state, SLAMInfo)``.""",
        run_doc="""PS-SLAM over a sequence: ``controls [T, control_dim]`` odometry and detections with leading
        axis ``T``; ``state`` from :func:`init`. ``trace`` is a :class:`~jaxnav.slam.tag_slam.SLAMInfo` with leading axis ``T``.
        ``donate_state=True`` matters for large tables: without it the initial table and its rings are
        copied into the scan at every call.""",
        state_type=PSSLAMState,
        valid_inputs=_inputs_in_domain,
    ),
    __name__,
)


map_estimate = jax.jit(tag_slam.map_estimate)
map_estimate.__doc__ = tag_slam.map_estimate.__doc__


def run_sharded(
    key: jax.Array,
    state: PSSLAMState,
    config: PSSLAMConfig,
    params: PSSLAMParams,
    controls: jax.Array,
    detections: Any,
    devices: Any = None,
) -> tuple[PSSLAMState, SLAMInfo]:
    return tag_slam.run_sharded(run, kernel, key, state, config, params, controls, detections, devices)


run_sharded.__doc__ = tag_slam.RUN_SHARDED_DOC
