"""Robot localization from UHF-RFID reads of anchor tags and odometry, [A] App. F Alg. 8.

**Overview**

The robot carries the reader; ``G`` anchor tags sit at known positions. The
particles are ``X = (x, y, z, φ, θ_1 … θ_G)``: the reader's position (m), the
yaw of its antenna (rad) and the unknown phase offset of each anchor (rad).
[A] Alg. 8, with where each line lives:

* lines 4–8, :func:`init`: positions uniform in the search box, ``φ``
  uniform in ``[φ_min, φ_max]``, every ``θ_i`` uniform on the circle;
* line 13, the motion: ``X_t ~ N(X_{t−1} + dX_t, σ_odometry²)`` on
  ``(x, y, z, φ)``. The offsets are constants, but a particle filter that
  never moves them keeps only the offset combinations its first ``M``
  draws happened to hold: with ``G`` offsets and a phase noise of ~1 rad,
  few initial particles match all of them, and the filter settled 0.2 m
  off in our runs (4 anchors, 4,000 particles). So each offset takes a small
  random walk, ``params.offset_sd`` rad per step (roughening, Gordon et al.
  1993; ours, not in [A]). [A] adds
  ``dX_t`` as it is, a world-frame increment (``config.odometry_frame =
  "world"``, the default); with ``"body"`` the ``(dx, dy)`` of a wheel
  odometry, measured in the robot frame, are turned by each particle's own
  ``φ`` first (our option, for robots whose heading is unknown);
* lines 14–18: every anchor ``j`` read this step weights the particle by
  ``W_RSSI`` (the reader at the particle's pose, the anchor at ``g_j``) and
  ``W_PHASE`` (with the particle's ``θ_j``), in log form
  (:func:`jaxnav.models.uhf_sensor.anchor_reads_log_likelihood`; ``config.weighting``
  keeps one or both);
* lines 20–25: normalise; resample (systematic, [A] App. B) when
  ``ESS < ess_threshold · M``. Unlike Alg. 6 there is no Gaussian refresh:
  the motion noise keeps the particles apart;
* line 26: the estimate, the weighted mean (``φ`` and the offsets on the
  circle). [A] takes it after resampling; we take it before (resampling adds
  noise and no information), as every jaxnav filter does.

The sensor. The reads' likelihood is :func:`jaxnav.models.uhf_sensor.anchor_reads_sensor`
(``config.sensor``). The filter is not MCL with that sensor: its particles ``[M, 4 + G]`` carry the
anchors' phase offsets beside a 3-D pose, and they move by an odometry increment with a random walk
on the offsets, not by one of MCL's planar motion models.

Observations: :class:`~jaxnav.models.uhf_sensor.AnchorReads`, one slot per anchor (``K ≤ G`` valid
reads per step, [A] line 10). The reader pose is the state, so unlike
:class:`~jaxnav.models.uhf_reads.UHFReads` a read carries no pose.

Interface::

    state = rfid_anchor.init(key, config, params)
    state, info = rfid_anchor.step(key, state, config, params, control, reads)
    final, trace = rfid_anchor.run(key, state, config, params, controls, reads)

``control`` is ``dX_t = (dx, dy, dz, dφ)`` (m, m, m, rad). [A] runs no
experiment with Alg. 8 ("no further analysis or experimental results are
conducted, due to its greater number of parameters which need tuning"); the
tests here check it on simulated reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, rng, weights
from jaxnav.core.particle_filter import PFInfo, extend_info, finish_step, keep_finite
from jaxnav.core.validation import (
    all_finite_within,
    all_nonnegative,
    check_choice,
    check_finite,
    check_fraction,
    check_magnitude,
    check_nonnegative,
    check_positive,
    check_positive_int,
    check_shape,
    is_concrete,
)
from jaxnav.localization.rfid_tag import WEIGHTINGS
from jaxnav.models import motion
from jaxnav.models import uhf_rfid as U
from jaxnav.models import uhf_sensor as US
from jaxnav.models.sensor import ParticleSensor

__all__ = [
    "AnchorReads",
    "RFIDAnchorConfig",
    "RFIDAnchorParams",
    "RFIDAnchorState",
    "RFIDAnchorInfo",
    "default_params",
    "init",
    "kernel",
    "step",
    "run",
]

FRAMES = motion.INCREMENT_FRAMES
"""Frames of the odometry increment (:data:`jaxnav.models.motion.INCREMENT_FRAMES`)."""


AnchorReads = US.AnchorReads
"""One step's reads, slot ``j`` = anchor ``j`` (:class:`jaxnav.models.uhf_sensor.AnchorReads`)."""


@dataclass(frozen=True)
class RFIDAnchorConfig:
    """Static configuration.

    Attributes:
        num_particles: M.
        weighting: one of :data:`jaxnav.localization.rfid_tag.WEIGHTINGS`.
        ess_threshold: resample when ESS < ``ess_threshold · M``, in (0, 1] (0.5, the common value).
        odometry_frame: ``"world"`` ([A]: ``X + dX``) or ``"body"`` (``(dx, dy)``
            turned by each particle's ``φ``).
        antenna_softness: optional relaxation (rad) of the antenna steps.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles",)
    num_particles: int = 2000
    weighting: str = "combined"
    ess_threshold: float = 0.5
    odometry_frame: str = "world"
    antenna_softness: float | None = None

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_choice("weighting", self.weighting, WEIGHTINGS)
        check_fraction("ess_threshold", self.ess_threshold)
        check_choice("odometry_frame", self.odometry_frame, FRAMES)
        if self.antenna_softness is not None:
            check_positive("antenna_softness", self.antenna_softness)

    @property
    def sensor(self) -> ParticleSensor:
        """The sensor this filter weighs with, :func:`jaxnav.models.uhf_sensor.anchor_reads_sensor` of
        ``weighting`` and ``antenna_softness``."""
        return US.anchor_reads_sensor(self.weighting, self.antenna_softness)


class RFIDAnchorParams(NamedTuple):
    """Differentiable parameters (use :func:`default_params`).

    Attributes:
        channel, gamma, phase_sigma: the read models, as in :mod:`jaxnav.localization.rfid_tag`.
        anchors: ``[G, 3]`` anchor positions (m).
        odometry_sd: ``[4]`` sd of the motion noise on ``(x, y, z, φ)`` per step (m, m, m, rad).
        offset_sd: sd (rad) of a random walk on the anchors' phase offsets per step
            (roughening, ours: not in [A]; module docstring).
        box_lo, box_hi: ``[3]`` corners of the initial search box (m).
        heading_range: ``[2]`` ``(φ_min, φ_max)`` of the initial yaw (rad).
    """

    channel: U.ChannelParams
    gamma: U.GammaParams
    phase_sigma: jax.Array
    anchors: jax.Array
    odometry_sd: jax.Array
    offset_sd: jax.Array
    box_lo: jax.Array
    box_hi: jax.Array
    heading_range: jax.Array


class RFIDAnchorState(NamedTuple):
    """``particles [M, 4 + G]`` = ``(x, y, z, φ, θ_1 … θ_G)``; ``log_weights [M]`` normalised."""

    particles: jax.Array
    log_weights: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RFIDAnchorInfo(PFInfo):
    """Per-step diagnostics: ``estimate [4 + G]`` (weighted mean; angles on the circle), ``ess``,
    ``resampled``, ``log_likelihood`` (increment), ``degenerate``, ``num_reads``, and
    ``num_ignored``: valid reads dropped because a value was not finite or out of range
    (:func:`jaxnav.models.uhf_reads.usable_reads`; the host refuses them, so only inside a
    caller's ``jit``), and ``invalid_inputs``: the step's control or parameters were outside the
    models' domain (a negative noise sd, a zero or negative power, gain, ``k``, ``θ`` or
    ``σ_phase``, a value that is not finite or exceeds
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
    caller's ``jit``: the state was carried over unchanged."""

    num_reads: jax.Array
    num_ignored: jax.Array
    invalid_inputs: jax.Array = False


def default_params(
    anchors: Any,
    box_lo: Any = (0.0, 0.0, 0.0),
    box_hi: Any = (2.0, 3.0, 2.0),
    odometry_sd: Any = (0.01, 0.01, 0.002, 0.01),
    heading_range: Any = (-math.pi, math.pi),
    channel: U.ChannelParams = U.DEFAULT_CHANNEL,
    gamma: U.GammaParams = U.DEFAULT_GAMMA,
    phase_sigma: Any = None,
    offset_sd: Any = 0.05,
) -> RFIDAnchorParams:
    """Parameters for anchors ``[G, 3]`` (m); odometry sd per step (ours: 1 cm, 1 cm, 2 mm, 0.01 rad);
    offset roughening 0.05 rad per step (ours).

    ``phase_sigma`` defaults to ``0.1 λ``. Validated.
    """
    if phase_sigma is None:
        phase_sigma = U.DEFAULT_PHASE_SIGMA_FRACTION * float(np.asarray(channel.wavelength))
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    channel, gamma = U.read_model_float32(channel, gamma)
    p = RFIDAnchorParams(
        channel=channel,
        gamma=gamma,
        phase_sigma=f32(phase_sigma),
        anchors=f32(anchors),
        odometry_sd=f32(odometry_sd),
        offset_sd=f32(offset_sd),
        box_lo=f32(box_lo),
        box_hi=f32(box_hi),
        heading_range=f32(heading_range),
    )
    _validate_params(p)
    return p


def _validate_params(p: RFIDAnchorParams) -> None:
    if not isinstance(p, RFIDAnchorParams):
        raise ValueError(f"params must be an RFIDAnchorParams, got {type(p).__name__}")
    U.validate_read_model(p.channel, p.gamma, p.phase_sigma)
    check_shape("params.anchors", p.anchors, (None, 3))
    if np.shape(p.anchors)[0] < 1:
        raise ValueError("params.anchors must hold at least one anchor tag")
    check_finite("params.anchors", p.anchors)
    check_shape("params.odometry_sd", p.odometry_sd, (4,))
    check_nonnegative("params.odometry_sd", p.odometry_sd)
    check_shape("params.offset_sd", p.offset_sd, ())
    check_nonnegative("params.offset_sd", p.offset_sd)
    for name in ("box_lo", "box_hi"):
        check_shape(f"params.{name}", getattr(p, name), (3,))
        check_finite(f"params.{name}", getattr(p, name))
    check_shape("params.heading_range", p.heading_range, (2,))
    check_finite("params.heading_range", p.heading_range)
    if is_concrete((p.box_lo, p.box_hi, p.heading_range, p.anchors)):
        lo, hi = np.asarray(p.box_lo), np.asarray(p.box_hi)
        if not np.all(hi > lo):
            raise ValueError(f"the search box must have a positive volume: box_lo {lo.tolist()} < box_hi {hi.tolist()}")
        h = np.asarray(p.heading_range)
        if not h[1] > h[0]:
            raise ValueError(f"heading_range must be (φ_min, φ_max) with φ_min < φ_max, got {h.tolist()}")
        if np.any(np.asarray(p.anchors)[:, 2] < 0):
            raise ValueError("anchor heights must be ≥ 0 (the ground is z = 0)")


@memory.guard_init
def init(key: jax.Array, config: RFIDAnchorConfig, params: RFIDAnchorParams) -> RFIDAnchorState:
    """[A] Alg. 8 lines 4–8: uniform positions, yaw in ``heading_range``, offsets on the circle."""
    if not isinstance(config, RFIDAnchorConfig):
        raise ValueError(f"config must be an RFIDAnchorConfig, got {type(config).__name__}")
    filter_api.check_key(key)
    _validate_params(params)
    m, g = config.num_particles, params.anchors.shape[0]
    k1, k2, k3 = jax.random.split(key, 3)
    xyz = params.box_lo + rng.uniform(k1, (m, 3)) * (params.box_hi - params.box_lo)
    phi = params.heading_range[0] + rng.uniform(k2, (m, 1)) * (params.heading_range[1] - params.heading_range[0])
    off = rng.uniform(k3, (m, g), minval=-math.pi, maxval=math.pi)
    parts = jnp.concatenate([xyz, weights.wrap_angle(phi), off], axis=-1)
    return RFIDAnchorState(parts, jnp.full((m,), -math.log(m), parts.dtype))


def _angle_dims(g: int) -> tuple[int, ...]:
    return (3,) + tuple(range(4, 4 + g))


def _inputs_in_domain(
    config: RFIDAnchorConfig, params: RFIDAnchorParams, control: jax.Array, reads: AnchorReads
) -> jax.Array:
    """``bool[]``, traceable: the odometry increment finite and at most
    :data:`~jaxnav.core.validation.MAX_MAGNITUDE`, the noise sd's non-negative and the read model in
    its domain (:func:`jaxnav.models.uhf_read_model.read_model_in_domain`): the value checks of the host, as
    ``jnp``. The reads are not part of it: an unusable read is dropped and counted."""
    del config, reads
    return (
        all_finite_within(control)
        & all_nonnegative(params.odometry_sd)
        & all_nonnegative(params.offset_sd)
        & U.read_model_in_domain(params.channel, params.gamma, params.phase_sigma)
    )


@filter_api.guard_inputs(_inputs_in_domain)
def kernel(
    key: jax.Array,
    state: RFIDAnchorState,
    config: RFIDAnchorConfig,
    params: RFIDAnchorParams,
    control: jax.Array,
    reads: AnchorReads,
) -> tuple[RFIDAnchorState, RFIDAnchorInfo]:
    """One step of [A] Alg. 8, pure and traceable (:func:`step` is it validated and jitted)."""
    m, d = state.particles.shape
    g = d - 4
    k_move, k_off, k_res = jax.random.split(key, 3)
    p = state.particles
    pose = motion.increment_sample(k_move, p[:, :4], control, params.odometry_sd, config.odometry_frame)
    offsets = weights.wrap_angle(p[:, 4:] + params.offset_sd * rng.normal(k_off, (m, g), p.dtype))
    moved = jnp.concatenate([pose, offsets], axis=-1)
    reads, num_ignored = US.usable_anchor_reads(reads)
    ll = US.anchor_reads_log_likelihood(moved, reads, params, config.weighting, config.antenna_softness)
    moved, ll = keep_finite(p, moved, ll)
    norm = weights.normalize(state.log_weights + ll)
    any_read = jnp.any(reads.mask)
    threshold = jnp.where(any_read, jnp.asarray(config.ess_threshold, jnp.float32), 0.0)
    res, base = finish_step(k_res, moved, norm, threshold=threshold, angle_dims=_angle_dims(g))
    info = extend_info(
        RFIDAnchorInfo,
        base.replace(log_likelihood=jnp.where(any_read, norm.log_norm, 0.0)),
        num_reads=jnp.sum(reads.mask, dtype=jnp.int32),
        num_ignored=num_ignored,
    )
    return RFIDAnchorState(res.particles, res.log_weights), info


def _validate_state(config: RFIDAnchorConfig, params: RFIDAnchorParams, state: RFIDAnchorState) -> None:
    g = np.shape(params.anchors)[0]
    check_shape("state.particles", state.particles, (config.num_particles, 4 + g))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))


def _validate_inputs(
    config: RFIDAnchorConfig, params: RFIDAnchorParams, controls: Any, reads: AnchorReads, time_axis: bool
) -> None:
    g = np.shape(params.anchors)[0]
    lead = 1 if time_axis else 0
    t = (None,) * lead
    check_shape("controls" if lead else "control", controls, t + (4,))
    check_magnitude("controls" if lead else "control", controls)
    US.check_anchor_reads(reads, np.shape(controls)[:lead], g)


def _prepare(config: RFIDAnchorConfig, controls: Any, reads: AnchorReads) -> tuple[jax.Array, AnchorReads]:
    return jnp.asarray(controls, jnp.float32), US.as_anchor_reads(reads)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="RFID anchor localization",
        kernel=kernel,
        config_type=RFIDAnchorConfig,
        state_type=RFIDAnchorState,
        inputs=("control", "reads"),
        time_inputs=("controls", "reads"),
        check_params=lambda config, params: _validate_params(params),
        check_state=_validate_state,
        check_inputs=_validate_inputs,
        valid_inputs=_inputs_in_domain,
        prepare=_prepare,
        step_doc="""One step of [A] Alg. 8 (lines 10–26): move by ``control = dX_t [4]``, weight by the anchors
        read (``reads`` an :class:`~jaxnav.models.uhf_sensor.AnchorReads` of ``[G]``).""",
        run_doc="""[A] Alg. 8 over ``T`` steps: ``controls [T, 4]``, ``reads`` an :class:`~jaxnav.models.uhf_sensor.AnchorReads` of ``[T, G]``,
        ``state`` from :func:`init`.""",
    ),
    __name__,
)
