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
from jaxnav.core.validation import all_nonnegative, check_nonnegative, check_positive_int, check_shape
from jaxnav.models import hf_rfid
from jaxnav.slam import tag_slam
from jaxnav.slam.tag_slam import SLAMInfo, check_capacity

__all__ = [
    "PSSLAMConfig",
    "PSSLAMParams",
    "SmootherTable",
    "PSSLAMState",
    "SLAMInfo",
    "default_jitter",
    "init",
    "kernel",
    "step",
    "run",
    "map_estimate",
    "check_capacity",
]


@dataclass(frozen=True)
class PSSLAMConfig(tag_slam.TagSLAMConfig):
    """Static configuration of PS-SLAM: the fields of :class:`~jaxnav.slam.tag_slam.TagSLAMConfig` plus ``lag``.

    Attributes:
        lag: ``L``, states kept per tag particle (20–30 in [W] §4.1); ``L = 1`` smooths nothing.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles", "num_tag_particles", "max_tags", "lag")
    lag: int = 20

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive_int("lag", self.lag)


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


def _propose(key, row: SmootherTable, is_new, pose_est, init_z, config, params):
    """[W] Alg. 2 lines 6–11: a new tag's particles over the initialising footprint, or the row's moved by the jitter."""
    j = config.num_tag_particles
    fresh = config.sensor.initialise(jax.random.fold_in(key, 0), pose_est, init_z, params.sensor, j)
    noise = rng.normal(jax.random.fold_in(key, 2), row.particles.shape, row.particles.dtype)
    particles = jnp.where(is_new, fresh, row.particles + params.tag_jitter_sd * noise)
    log_w = jnp.where(is_new, jnp.full_like(row.log_weights, -np.log(j)), row.log_weights)
    return particles, log_w


def _finish(key, row: SmootherTable, particles, log_w, loglik, is_new, config, params) -> SmootherTable:
    """[W] Alg. 2 lines 12–24: weight, push onto the ring, resample (with histories), smooth."""
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
    buf = buf._replace(data=jnp.take(buf.data, res.ancestors, axis=1))  # histories move with their particles
    smoothed = ring.ring_mean(buf)  # [J, 2]
    estimate = weights.mean_from_probabilities(smoothed, jnp.exp(res.log_weights))
    return SmootherTable(res.particles, tag_slam.resampled_log_weights(row, res, config), estimate, count + 1, buf.data)


TAG_MODEL = tag_slam.TagModel(_propose, _finish)


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
) -> tuple[PSSLAMState, SLAMInfo]:
    """One PS-SLAM step ([W] Alg. 2), pure and traceable (:func:`step` is it validated and jitted).

    A step whose odometry or parameters are outside the models' domain (refused on the host, so
    only inside a caller's ``jit``) keeps the state and sets ``info.invalid_inputs``
    (:func:`jaxnav.slam.tag_slam.slam_step`)."""
    return tag_slam.slam_step(key, state, config, params, control, detections, TAG_MODEL, _inputs_in_domain)


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
