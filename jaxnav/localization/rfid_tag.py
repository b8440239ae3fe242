"""Localization of a static UHF-RFID tag from RSSI and phase reads, [A] Alg. 6 (§4.3).

**Overview**

A reader on a robot whose path is known reads a tag that does not move. Each
read gives an RSSI ``y`` (W) and a phase ``φ`` (rad) at a known reader pose
(:class:`jaxnav.models.uhf_reads.UHFReads`). The particles are hypotheses
``X = (x, y, z, θ_off)`` of the tag's position (m) and of the constant phase
offset of its cables and antenna (rad). [A] Alg. 6, with where each line lives:

* lines 4–7, :func:`init`: ``M`` particles uniform in the search box, offset
  uniform on the circle, equal weights;
* lines 9–16, :func:`step`: every valid read ``j`` of the step multiplies the
  weight by ``W_RSSI`` (line 12, the scaled squared-Gamma density of [A]
  §4.3.1, :func:`jaxnav.models.uhf_read_model.log_w_rssi`, with ``a`` from the
  two-ray model at the particle, :func:`~jaxnav.models.uhf_channel.power_scale`)
  and by ``W_PHASE`` (line 13, ``N(Δ; 0, σ²)`` on the distance metric of
  [A] §4.3.2, :func:`~jaxnav.models.uhf_read_model.log_w_phase`), in log form.
  ``config.weighting`` keeps one of them (``"rssi"``, ``"phase"``) or both
  (``"combined"``): the three curves of [A] Figs. 5.5–5.6;
* lines 17–19: normalise; ESS; the estimate is the weighted mean (the
  offset on the circle), taken before resampling;
* lines 20–26: resample only when ``ESS < ess_threshold · M``, and then
  redraw the set from the fitted Gaussian ([A] §4.3.3: duplicates of a
  static target would stay duplicates forever). [A] fits it to the resampled
  particles; we fit it to the weighted set, whose moments those estimate
  (no ancestors drawn: the same Gaussian without the resampling's noise;
  :func:`jaxnav.core.refresh.gaussian_draw`).
  [A] asks for a threshold "significantly lower" than ``M/2`` because the
  Gaussian is unimodal while the early posterior is multimodal (a phase read
  is consistent with spheres ``λ/2`` apart); ours is 0.1 (our choice). The
  redrawn positions are clipped into the box (the tag is in it by
  assumption, and a position below the ground has no two-ray model).

2D ([A] §5.2.2): ``config.dims = 2`` keeps ``z`` at ``params.tag_height`` (a
known height) and searches ``(x, y, θ_off)`` only; the particles keep four
columns so that every shape is the same.

Several tags: :func:`run_tags` applies ``vmap`` to :func:`run` over a leading tag axis
(``[A]``: "localization of more than one tags simply requires the execution
inside a loop"; here it is one vectorised call, with each tag resampling only
when it must).

The sensor. The reads' likelihood is :func:`jaxnav.models.uhf_sensor.tag_reads_sensor`
(``config.sensor``), the seam every jaxnav particle filter weighs through. The filter is not MCL
with that sensor: its particles are hypotheses of a static tag ``[M, 4]``, not robot poses, so
there is no motion model and no control, and its Gaussian refresh clipped to the box is its own.

Interface (shared by every jaxnav filter)::

    state = rfid_tag.init(key, config, params)
    state, info = rfid_tag.step(key, state, config, params, reads)        # reads: UHFReads [J]
    final, trace = rfid_tag.run(key, state, config, params, reads_T)      # reads: UHFReads [T, J]

A static tag has no motion model, so there is no control argument. Step
``t`` of :func:`run` uses ``fold_in(key, t)``. A step without a valid read
changes nothing (weights, particles) but the estimate is reported. A step
where every particle has zero likelihood resets the weights and sets
``info.degenerate``, never NaN.

Units: m, rad, W. The Gamma parameters ``(k, θ)`` come from an anchor tag
(:func:`jaxnav.models.uhf_calibration.estimate_gamma`) or the defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, resampling, rng, weights
from jaxnav.core.particle_filter import PFInfo
from jaxnav.core.validation import (
    check_choice,
    check_finite,
    check_fraction,
    check_positive,
    check_positive_int,
    check_shape,
)
from jaxnav.models import uhf_rfid as U
from jaxnav.models import uhf_sensor as US
from jaxnav.models.sensor import ParticleSensor

__all__ = [
    "WEIGHTINGS",
    "RFIDTagConfig",
    "RFIDTagParams",
    "RFIDTagState",
    "RFIDTagInfo",
    "default_params",
    "init",
    "kernel",
    "step",
    "run",
    "run_tags",
    "log_likelihoods",
    "Weighed",
    "weigh",
    "resample",
    "run_tags_jitted",
]

WEIGHTINGS = US.WEIGHTINGS
"""Which weights Alg. 6 lines 12–14 multiply in, by name (:data:`jaxnav.models.uhf_sensor.WEIGHTINGS`).

``"combined"`` multiplies both (the proposal of [A]), ``"rssi"`` the RSSI weight only and ``"phase"``
the phase weight only."""

_OFFSET = 3  # column of θ_off, an angle in [−π, π)


@dataclass(frozen=True)
class RFIDTagConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        num_particles: M.
        dims: 3 (search x, y, z) or 2 (z fixed at ``params.tag_height``).
        weighting: one of :data:`WEIGHTINGS`.
        ess_threshold: resample when ESS < ``ess_threshold · M``, in (0, 1].
            [A] §4.3.3: well below the usual 0.5; default 0.1 (ours).
        refresh: how the resampled set is redrawn. ``True`` / ``"gaussian"``:
            from its Gaussian ([A] §4.3.3, Alg. 6 line 22). ``"kernel"``: every
            particle moves by a kernel of covariance ``h² Σ`` (the regularised
            particle filter, :func:`jaxnav.core.refresh.kernel_refresh`; ours,
            not [A]'s), which keeps the early posterior's modes; the
            ``uhf-refresh`` experiment compares the two. ``False`` keeps plain
            systematic resampling.
        antenna_softness: optional logistic relaxation (rad) of the antenna
            pattern's steps (:func:`jaxnav.models.uhf_antenna.antenna_gain`), for
            gradients with respect to positions; None is [A]'s stepped model.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles",)
    num_particles: int = 2000
    dims: int = 3
    weighting: str = "combined"
    ess_threshold: float = 0.1
    refresh: bool | str = True
    antenna_softness: float | None = None

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {self.dims!r}")
        check_choice("weighting", self.weighting, WEIGHTINGS)
        check_fraction("ess_threshold", self.ess_threshold)
        if not isinstance(self.refresh, bool):
            check_choice("refresh", self.refresh, resampling.REFRESHES)
        if self.antenna_softness is not None:
            check_positive("antenna_softness", self.antenna_softness)

    @property
    def sensor(self) -> ParticleSensor:
        """The sensor this filter weighs with, :func:`jaxnav.models.uhf_sensor.tag_reads_sensor` of
        ``weighting`` and ``antenna_softness``."""
        return US.tag_reads_sensor(self.weighting, self.antenna_softness)


class RFIDTagParams(NamedTuple):
    """Differentiable parameters (use :func:`default_params`).

    Attributes:
        channel: :class:`~jaxnav.models.uhf_channel.ChannelParams` (power model and antenna).
        gamma: :class:`~jaxnav.models.uhf_channel.GammaParams` ``(k, θ)`` of ``|h|²``.
        phase_sigma: ``σ_phase`` (m) of ``W_PHASE``; [A]: 0.05λ–0.2λ.
        box_lo, box_hi: ``[3]`` corners of the search box (m).
        tag_height: the known tag height ``z`` (m) when ``dims = 2``.
    """

    channel: U.ChannelParams
    gamma: U.GammaParams
    phase_sigma: jax.Array
    box_lo: jax.Array
    box_hi: jax.Array
    tag_height: jax.Array


class RFIDTagState(NamedTuple):
    """``particles [M, 4]`` = ``(x, y, z, θ_off)`` (m, m, m, rad in [−π, π)); ``log_weights [M]`` normalised."""

    particles: jax.Array
    log_weights: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RFIDTagInfo(PFInfo):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[4]`` weighted mean ``(x, y, z, θ_off)`` ([A] Alg. 6 line 19; offset on the circle).
        ess: effective sample size after the update, before resampling.
        resampled: bool.
        log_likelihood: log of the weighted mean likelihood of the step's reads (0 without reads).
        degenerate: bool, every particle had zero likelihood; the weights were reset.
        num_reads: int32, valid reads used.
        num_ignored: int32, valid reads dropped because a value was not finite or out of range
            (:func:`jaxnav.models.uhf_reads.usable_reads`; the host refuses them, so only inside
            a caller's ``jit``).
        invalid_inputs: bool, the step's parameters were outside the models' domain (a zero or negative
            power, gain, ``k``, ``θ`` or ``σ_phase``, an empty search box, a value that is not
            finite or exceeds :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host,
            so only inside a caller's ``jit``: the state was carried over unchanged.
    """

    num_reads: jax.Array
    num_ignored: jax.Array
    invalid_inputs: jax.Array = False


def default_params(
    box_lo: Any = (0.0, 0.0, 0.0),
    box_hi: Any = (2.0, 3.0, 2.0),
    channel: U.ChannelParams = U.DEFAULT_CHANNEL,
    gamma: U.GammaParams = U.DEFAULT_GAMMA,
    phase_sigma: Any = None,
    tag_height: Any = 1.0,
) -> RFIDTagParams:
    """Parameters with [A] §5.2's 2 × 3 × 2 m search box by default.

    ``phase_sigma`` defaults to ``0.1 λ`` (:data:`~jaxnav.models.uhf_read_model.DEFAULT_PHASE_SIGMA_FRACTION`
    of the channel's wavelength); ``tag_height`` (m) is used only in 2D. Validated.
    """
    if phase_sigma is None:
        phase_sigma = U.DEFAULT_PHASE_SIGMA_FRACTION * float(np.asarray(channel.wavelength))
    channel, gamma = U.read_model_float32(channel, gamma)
    p = RFIDTagParams(
        channel=channel,
        gamma=gamma,
        phase_sigma=jnp.asarray(phase_sigma, jnp.float32),
        box_lo=jnp.asarray(box_lo, jnp.float32),
        box_hi=jnp.asarray(box_hi, jnp.float32),
        tag_height=jnp.asarray(tag_height, jnp.float32),
    )
    _validate_params(p)
    return p


def _validate_params(params: RFIDTagParams) -> None:
    if not isinstance(params, RFIDTagParams):
        raise ValueError(f"params must be an RFIDTagParams, got {type(params).__name__}")
    U.validate_read_model(params.channel, params.gamma, params.phase_sigma)
    check_shape("params.box_lo", params.box_lo, (3,))
    check_shape("params.box_hi", params.box_hi, (3,))
    check_finite("params.box_lo", params.box_lo)
    check_finite("params.box_hi", params.box_hi)
    check_shape("params.tag_height", params.tag_height, ())
    check_finite("params.tag_height", params.tag_height)
    try:
        lo, hi = np.asarray(params.box_lo), np.asarray(params.box_hi)
    except jax.errors.TracerArrayConversionError:
        return
    if not np.all(hi > lo):
        raise ValueError(
            f"the search box must have a positive volume: box_lo {lo.tolist()} < box_hi {hi.tolist()} on every axis"
        )
    if lo[2] < 0:
        raise ValueError(f"the search box must lie above the ground z = 0 (box_lo z = {lo[2]:g})")


@memory.guard_init
def init(key: jax.Array, config: RFIDTagConfig, params: RFIDTagParams) -> RFIDTagState:
    """[A] Alg. 6 lines 4–7: ``M`` particles uniform in the box, ``θ_off`` uniform, equal weights."""
    if not isinstance(config, RFIDTagConfig):
        raise ValueError(f"config must be an RFIDTagConfig, got {type(config).__name__}")
    filter_api.check_key(key)
    _validate_params(params)
    return _init(key, config, params)


def _init(key, config, params):
    m = config.num_particles
    k_pos, k_off = jax.random.split(key)
    xyz = params.box_lo + rng.uniform(k_pos, (m, 3)) * (params.box_hi - params.box_lo)
    if config.dims == 2:
        xyz = xyz.at[:, 2].set(params.tag_height)
    off = rng.uniform(k_off, (m, 1), minval=-math.pi, maxval=math.pi)
    particles = jnp.concatenate([xyz, off], axis=-1)
    return RFIDTagState(particles, jnp.full((m,), -math.log(m), particles.dtype))


def log_likelihoods(config: RFIDTagConfig, params: RFIDTagParams, particles: jax.Array, reads: U.UHFReads) -> jax.Array:
    """``[M]`` Σ over the valid reads of ``log W_RSSI + log W_PHASE`` (or one of them), Alg. 6 lines 11–14:
    :func:`jaxnav.models.uhf_sensor.tag_reads_log_likelihood` with the configured weighting (``reads``
    usable, :func:`jaxnav.models.uhf_sensor.usable_tag_reads`)."""
    return US.tag_reads_log_likelihood(particles, reads, params, config.weighting, config.antenna_softness)


class Weighed(NamedTuple):
    """One step's reweighting (Alg. 6 lines 9–19), before the resampling decision is acted on."""

    log_weights: jax.Array
    probs: jax.Array
    info: RFIDTagInfo


def weigh(state: RFIDTagState, config: RFIDTagConfig, params: RFIDTagParams, reads: U.UHFReads) -> Weighed:
    """[A] Alg. 6 lines 9–19: weight the particles by the step's reads, estimate, and decide whether to resample."""
    reads, num_ignored = US.usable_tag_reads(reads)
    ll = log_likelihoods(config, params, state.particles, reads)
    norm = weights.normalize(state.log_weights + ll)
    probs = jnp.exp(norm.log_weights)
    estimate = weights.mean_from_probabilities(state.particles, probs, (_OFFSET,))
    any_read = jnp.any(reads.mask)
    # the rule of resampling.conditional_resample: ESS < threshold·M of the weights carried on, never without a read
    resample = any_read & (weights.ess_from_probabilities(probs) < config.ess_threshold * config.num_particles)
    info = RFIDTagInfo(
        estimate,
        weights.step_ess(probs, norm.degenerate),
        resample,
        jnp.where(any_read, norm.log_norm, 0.0),
        norm.degenerate,
        jnp.sum(reads.mask, dtype=jnp.int32),
        num_ignored,
    )
    return Weighed(norm.log_weights, probs, info)


def resample(
    key: jax.Array, particles: jax.Array, w: Weighed, config: RFIDTagConfig, params: RFIDTagParams
) -> tuple[jax.Array, jax.Array]:
    """Alg. 6 lines 20–26 taken: the resampling and refresh, the box clip; uniform weights.

    [A]'s Gaussian refresh (lines 21–22) resamples, then draws the new set from the Gaussian
    fitted to the resampled set. The moments of the resampled set estimate those of the
    weighted set, so the draw here uses the weighted set's directly: the mean is the step's
    estimate (already computed) and no ancestors are drawn. Same Gaussian up to the
    resampling's noise, at half the cost. The kernel refresh needs the resampled set itself.
    """
    if config.refresh is True or config.refresh == "gaussian":
        angle = (_OFFSET,)
        cov = weights.cov_from_probabilities(particles, w.probs, w.info.estimate, angle)
        new = resampling.gaussian_draw(key, w.info.estimate, cov, config.num_particles, angle)
        log_weights = jnp.full_like(w.log_weights, -math.log(config.num_particles))
    else:
        res = resampling.conditional_resample(
            key,
            particles,
            w.log_weights,
            threshold=1.0,
            scheme="systematic",
            refresh=config.refresh,
            angle_dims=(_OFFSET,),
            normalized=True,
        )
        new, log_weights = res.particles, res.log_weights
    xyz = jnp.clip(new[:, :3], params.box_lo, params.box_hi)
    if config.dims == 2:
        xyz = xyz.at[:, 2].set(params.tag_height)
    return jnp.concatenate([xyz, new[:, 3:]], axis=-1), log_weights


def _inputs_in_domain(config: RFIDTagConfig, params: RFIDTagParams, reads: U.UHFReads) -> jax.Array:
    """``bool[]``, traceable: the read model in its domain (:func:`jaxnav.models.uhf_read_model.read_model_in_domain`)
    and a search box of positive volume above the ground: the value checks of the host, as ``jnp``.
    The reads are not part of it: an unusable read is dropped and counted."""
    del config, reads
    lo, hi = params.box_lo, params.box_hi
    return U.read_model_in_domain(params.channel, params.gamma, params.phase_sigma) & jnp.all(hi > lo) & (lo[2] >= 0)


@filter_api.guard_inputs(_inputs_in_domain)
def kernel(
    key: jax.Array, state: RFIDTagState, config: RFIDTagConfig, params: RFIDTagParams, reads: U.UHFReads
) -> tuple[RFIDTagState, RFIDTagInfo]:
    """One step of [A] Alg. 6, pure and traceable (:func:`step` is it validated and jitted)."""
    w = weigh(state, config, params, reads)
    particles, log_weights = jax.lax.cond(
        w.info.resampled,
        lambda: resample(key, state.particles, w, config, params),
        lambda: (state.particles, w.log_weights),
    )
    return RFIDTagState(particles, log_weights), w.info


def _validate_state(config: RFIDTagConfig, params: Any, state: RFIDTagState) -> None:
    check_shape("state.particles", state.particles, (config.num_particles, 4))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))


def _validate_inputs(config: RFIDTagConfig, params: RFIDTagParams, reads: U.UHFReads, time_axis: bool) -> None:
    US.check_tag_reads(reads, time_axis)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="RFID tag localization",
        kernel=kernel,
        config_type=RFIDTagConfig,
        state_type=RFIDTagState,
        inputs=("reads",),
        check_params=lambda config, params: _validate_params(params),
        check_state=_validate_state,
        check_inputs=_validate_inputs,
        valid_inputs=_inputs_in_domain,
        prepare=lambda config, reads: (US.as_tag_reads(reads),),
        step_doc="""One step of [A] Alg. 6 (lines 9–26) on the ``J`` read slots of ``reads`` (a
        :class:`~jaxnav.models.uhf_reads.UHFReads` with mask shape ``[J]``); the reads are cast to float32.""",
        run_doc="""[A] Alg. 6 over ``T`` steps: ``reads`` with mask shape ``[T, J]``, ``state`` from :func:`init`;
        ``trace.estimate`` is ``[T, 4]``.""",
    ),
    __name__,
)


@partial(jax.jit, static_argnames=("config",))
def run_tags_jitted(
    key: jax.Array, config: RFIDTagConfig, params: RFIDTagParams, reads: U.UHFReads, states: RFIDTagState
) -> tuple[RFIDTagState, RFIDTagInfo]:
    """``vmap`` of :func:`run` over tags, except the resampling branch.

    Under ``vmap`` a per-tag ``lax.cond`` becomes a select that computes the resampling
    and refresh of every tag at every step. Here the tags are reweighed together (``vmap``);
    at steps where at least one tag resamples, a ``lax.map`` over the tags runs each tag's
    own ``cond``, so only the tags that resample pay for it. A step where none does costs
    G likelihoods.
    """
    filter_api.check_key(key)
    g = reads.mask.shape[0]
    tag_keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(g))
    reads_t = jax.tree_util.tree_map(lambda x: jnp.moveaxis(x, 1, 0), reads)  # [T, G, ...]

    def body(carry, inputs):
        t, r = inputs
        w = jax.vmap(weigh, in_axes=(0, None, None, 0))(carry, config, params, r)
        keys = jax.vmap(lambda k: jax.random.fold_in(k, t))(tag_keys)

        def resample_some():
            # one tag after another, each resampling only if it must (a vmapped cond would
            # compute every tag's branch)
            def one_tag(args):
                k, particles, wg = args
                return jax.lax.cond(
                    wg.info.resampled,
                    lambda: resample(k, particles, wg, config, params),
                    lambda: (particles, wg.log_weights),
                )

            return jax.lax.map(one_tag, (keys, carry.particles, w))

        particles, log_weights = jax.lax.cond(
            jnp.any(w.info.resampled), resample_some, lambda: (carry.particles, w.log_weights)
        )
        # the guard of kernel (filter_api.guard_inputs): parameters outside the domain keep every tag's state
        ok = filter_api.inputs_in_domain(_inputs_in_domain, config, params, r)
        particles = jnp.where(ok, particles, carry.particles)
        log_weights = jnp.where(ok, log_weights, carry.log_weights)
        return RFIDTagState(particles, log_weights), filter_api.flag_invalid_inputs(w.info, jnp.full((g,), ok))

    final, trace = jax.lax.scan(body, states, (jnp.arange(reads_t.mask.shape[0]), reads_t))
    return final, jax.tree_util.tree_map(lambda x: jnp.moveaxis(x, 0, 1), trace)


def run_tags(
    key: jax.Array,
    config: RFIDTagConfig,
    params: RFIDTagParams,
    reads: U.UHFReads,
    initial_states: RFIDTagState | None = None,
) -> tuple[RFIDTagState, RFIDTagInfo]:
    """:func:`run` for ``G`` tags at once (one scan, ``vmap`` over tags, no Python loop); reads have mask shape ``[G, T, J]``.

    The resampling runs tag by tag, only for the tags that resample (:func:`run_tags_jitted`),
    so G tags cost about G likelihood evaluations per step plus their own resamplings.

    Tag ``g`` runs with key ``key_g = fold_in(key, g)``; when ``initial_states`` is None
    its particles start from :func:`init` with ``fold_in(key_g, 2**31 − 1)``. All tags
    share ``params`` (one anchor's ``(k, θ)``). Returns states and traces with a leading
    ``G`` axis.
    """
    if not isinstance(config, RFIDTagConfig):
        raise ValueError(f"config must be an RFIDTagConfig, got {type(config).__name__}")
    filter_api.check_key(key)
    _validate_params(params)
    U.validate_reads(reads)
    if len(np.shape(reads.mask)) != 3:
        raise ValueError(f"reads must have shape [G, T, J], got mask shape {np.shape(reads.mask)}")
    g = np.shape(reads.mask)[0]
    if initial_states is None:
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(key, i), 2**31 - 1))(jnp.arange(g))
        initial_states = jax.vmap(lambda k: _init(k, config, params))(keys)
    check_shape("initial_states.particles", initial_states.particles, (g, config.num_particles, 4))
    return run_tags_jitted(key, config, params, US.as_tag_reads(reads), initial_states)
