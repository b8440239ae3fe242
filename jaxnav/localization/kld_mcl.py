"""KLD-sampling Monte Carlo localization: an adaptive number of particles in fixed-shape arrays.

**Overview**

[A] §2.1.3 (ref. [9], Fox 2001, "KLD-sampling: adaptive particle filters";
Thrun, Burgard & Fox, *Probabilistic Robotics*, Tab. 8.4) chooses the number
of particles so that, with probability ``1 − δ``, the Kullback–Leibler
divergence between the sample-based maximum-likelihood estimate and the true
posterior, both discretised on a histogram, stays below ``ε``. If the samples
occupy ``k`` histogram bins that takes (Fox 2001 eq. 7, the Wilson–Hilferty
approximation of the χ² quantile)::

    n_χ(k) = (k − 1)/(2ε) · (1 − 2/(9(k − 1)) + √(2/(9(k − 1))) · z_{1−δ})³
           ≈ χ²_{k−1, 1−δ} / (2ε),

with ``z_{1−δ}`` the standard normal upper ``δ`` quantile; ``n_χ(1) = 0``
(one occupied bin needs no more samples than the minimum).

Fixed shapes. JAX cannot grow an array, so the set lives in a capacity of
``N_max = config.max_particles`` slots: the first ``n_t`` slots are *active*
(``state.num_active``; :attr:`KLDMCLState.active` is the mask) and the other
slots carry log-weight ``−inf``. Inactive slots are never read: their poses
are replaced by zeros before the motion draw, their weights are masked to
``−inf`` before normalising, and every sum (mean, ESS, likelihood) sees zero
weight there, so garbage (even NaN) in them changes nothing.

Each step:

1. move and weight the active particles (the shared helper
   :func:`jaxnav.localization.mcl.move_and_weight`; [A] Alg. 3 lines 3–4);
   the estimate is their weighted mean (circular θ) and the ESS counts only
   them;
2. draw ``N_max`` *candidates* i.i.d. from the weighted set (inverse CDF of
   ``N_max`` unsorted uniforms, i.e. multinomial draws in random order), bin
   each at ``config.bin_size = (Δx [m], Δy [m], Δθ [rad])`` on a grid
   anchored at ``(0, 0, −π)``, and compute for *every* prefix length ``m`` the
   number ``k(m)`` of distinct bins among candidates ``1..m``: one stable
   lexicographic sort of the bin triples marks the first occurrence of each
   bin, and a cumulative sum of those marks gives ``k(m)`` for all ``m`` at
   once (O(N_max log N_max), no hashing, so no collisions);
3. the new count is Fox's stopping rule applied to that sequence:
   ``n_t = min{m : m ≥ n_χ(k(m)) and m ≥ n_min}``, or ``N_max`` when no
   prefix satisfies it;
4. systematic resampling of ``n_t`` particles from the weighted set into
   slots ``0..n_t−1`` (points ``(u + j)/n_t``); slots ``≥ n_t`` become inactive.

How this differs from Fox's sequential loop (Tab. 8.4), precisely:

* Fox draws one sample at a time — an ancestor from the *previous* weights,
  moved by the motion model — and bins the *predicted* (moved, not yet
  weighted) sample; its weight comes after. Here the filter moves and
  weights first, and the candidates are draws from the *current weighted*
  set, the distribution the kept set is meant to represent (the derivation
  of eq. 7 assumes samples from the distribution being approximated; a
  sequential loop can only bin predictive samples, because it must decide
  whether to stop before it weights). The price: resampled copies of one
  ancestor are identical and fall in the same bin, so ``k ≤`` the number of
  distinct ancestors with non-negligible weight.
* Given the candidate sequence, ``n_t`` is exactly where Fox's loop would
  stop (its "until M ≥ M_χ and M ≥ M_χmin"), except that it is capped at
  ``N_max`` (Fox has no cap; a capped step is visible as ``num_active == N_max``).
* Fox keeps the ``n_t`` samples he drew. Here the candidates only decide
  ``n_t``; the kept set is a systematic resample of size ``n_t`` (lower
  variance than the i.i.d. draws). ``info.num_bins`` is ``k(n_t)`` of the
  candidates, the ``k`` that set the bound, not the bin count of the kept set.
* Every step resamples (as Tab. 8.4).
* Cost: with fixed shapes every step does O(N_max log N_max) work whatever
  ``n_t`` is; the adaptive count decides which slots carry weight, and
  reports the sample size a variable-size implementation would need. What
  KLD-sampling buys here is statistical (an error bound at the chosen size),
  not time per step.

Interface (as :mod:`jaxnav.localization.mcl`)::

    state = kld_mcl.init(key, config, params, initial_pose, initial_sd)    # n_0 = N_max
    state = kld_mcl.init_uniform(key, config, params, bounds)              # n_0 = N_max
    state, info = kld_mcl.step(key, state, config, params, control, observation)
    final_state, trace = kld_mcl.run(key, state, config, params, controls, observations)

``params`` is a :class:`~jaxnav.localization.mcl.MCLParams` (motion and
sensor noise, landmark map); ε, δ, the bin sizes and the count limits are
static config (they set a discrete count; no gradient flows through them).
A degenerate step (every active particle has zero likelihood) resets the
active weights to uniform and is flagged in ``info.degenerate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, resampling, rng, weights
from jaxnav.core.particle_filter import PFInfo
from jaxnav.core.validation import check_positive_int, check_shape, is_concrete
from jaxnav.localization import mcl
from jaxnav.localization.mcl import MCLParams
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import MotionModel, check_motion_model
from jaxnav.models.sensor import (
    ParticleSensor,
    check_pose_filter_inputs,
    check_pose_filter_params,
    check_sensor,
    pose_filter_inputs_in_domain,
    prepare_pose_filter_inputs,
)

__all__ = [
    "KLDMCLConfig",
    "KLDMCLParams",
    "KLDMCLState",
    "KLDMCLInfo",
    "kld_bound",
    "init",
    "init_uniform",
    "kernel",
    "step",
    "run",
    "choose_count",
    "occupied_bins_per_prefix",
]

_ANGLE_DIMS = (2,)
_BIN_LIMIT = 2**30  # bin indices are clipped to ±2^30 (int32-safe); far beyond any map

KLDMCLParams = MCLParams
"""KLD-sampling MCL uses the parameters of plain MCL (motion, sensor, landmarks)."""


@dataclass(frozen=True)
class KLDMCLConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        max_particles: ``N_max``, the capacity: array shapes are ``[N_max, ...]``.
        min_particles: ``n_min`` (Thrun's ``M_χmin``), the least active count, ``≤ N_max``.
        epsilon: ε, the KL-divergence bound (nats), > 0.
        delta: δ in (0, 1); the bound holds with probability ``1 − δ``.
        bin_size: histogram bin ``(Δx [m], Δy [m], Δθ [rad])``, each > 0;
            default 0.25 m × 0.25 m × 10°.
        motion_model: a name in :data:`jaxnav.models.motion.MODELS` or a
            :class:`~jaxnav.models.motion.MotionModel`.
        sensor: the :class:`~jaxnav.models.sensor.ParticleSensor` that weights the particles
            (default: range-bearing observations of a known landmark map, with :class:`KLDMCLParams`;
            another sensor takes any params pytree with a ``motion`` field and those it reads).

    Defaults ε = 0.05, δ = 0.01 give ``n_χ`` ≈ 66 for k = 2, ≈ 1,350 for
    k = 100 and ≈ 11,000 for k = 1,000 bins.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("max_particles",)
    max_particles: int = 5000
    min_particles: int = 100
    epsilon: float = 0.05
    delta: float = 0.01
    bin_size: tuple[float, float, float] = (0.25, 0.25, math.radians(10.0))
    motion_model: str | MotionModel = "velocity"
    sensor: ParticleSensor = lm.RANGE_BEARING_SENSOR

    def __post_init__(self) -> None:
        check_positive_int("max_particles", self.max_particles)
        check_sensor("sensor", self.sensor)
        check_positive_int("min_particles", self.min_particles)
        if self.min_particles > self.max_particles:
            raise ValueError(f"min_particles must be <= max_particles, got {self.min_particles} > {self.max_particles}")
        eps = _real("epsilon", self.epsilon)
        if not (eps > 0.0 and math.isfinite(eps)):
            raise ValueError(f"epsilon must be finite and > 0, got {self.epsilon!r}")
        d = _real("delta", self.delta)
        if not (0.0 < d < 1.0):
            raise ValueError(f"delta must be in (0, 1), got {self.delta!r}")
        if not isinstance(self.bin_size, tuple) or len(self.bin_size) != 3:
            raise ValueError(f"bin_size must be a tuple (dx, dy, dtheta), got {self.bin_size!r}")
        for b in self.bin_size:
            v = _real("bin_size", b)
            if not (v > 0.0 and math.isfinite(v)):
                raise ValueError(f"bin_size entries must be finite and > 0, got {self.bin_size!r}")
        check_motion_model("motion_model", self.motion_model)


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    return float(value)


class KLDMCLState(NamedTuple):
    """Filter state carried between steps.

    Attributes:
        particles: ``[N_max, 3]`` poses (m, m, rad); slots ``≥ num_active`` are unused.
        log_weights: ``[N_max]`` log-weights, normalised over the active slots,
            ``−inf`` on the inactive ones.
        num_active: int32 scalar ``n_t`` in ``[1, N_max]``; the active slots are ``0..n_t−1``.
    """

    particles: jax.Array
    log_weights: jax.Array
    num_active: jax.Array

    @property
    def active(self) -> jax.Array:
        """``[N_max]`` bool mask of the active slots (``slot < num_active``)."""
        n_max = self.log_weights.shape[-1]
        return jnp.arange(n_max) < jnp.asarray(self.num_active)[..., None]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class KLDMCLInfo(PFInfo):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` weighted mean of the active particles after the
            update, before resampling (circular θ).
        ess: effective sample size of the active particles, before resampling.
        resampled: bool, always True.
        log_likelihood: ``log p(z_t | z_{1:t−1})`` estimate (−inf if degenerate).
        degenerate: bool, every active particle had zero likelihood; weights were reset.
        num_ignored: int32, observation slots dropped because their id is not in the map.
        num_active: int32, the new active count ``n_t`` (after resampling).
        num_bins: int32, ``k(n_t)``: occupied bins among the first ``n_t`` candidates.
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    num_ignored: jax.Array
    num_active: jax.Array
    num_bins: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# the bound


def kld_bound(k: jax.Array, epsilon: float | jax.Array, delta: float | jax.Array) -> jax.Array:
    """Fox 2001 eq. 7: samples needed for KL error ``≤ ε`` w.p. ``1 − δ`` with ``k`` occupied bins.

    ``n = (k−1)/(2ε) · (1 − 2/(9(k−1)) + √(2/(9(k−1))) z_{1−δ})³`` for ``k ≥ 2``
    (the Wilson–Hilferty form of ``χ²_{k−1,1−δ}/(2ε)``), and 0 for ``k ≤ 1``.
    Returns a float array (not rounded) of the shape of ``k``.
    """
    k = jnp.asarray(k)
    dtype = jnp.result_type(k.dtype, jnp.float32) if jnp.issubdtype(k.dtype, jnp.floating) else jnp.result_type(float)
    df = jnp.maximum(k.astype(dtype) - 1.0, 1.0)
    z = ndtri(1.0 - jnp.asarray(delta, dtype))
    a = 2.0 / (9.0 * df)
    n = df / (2.0 * jnp.asarray(epsilon, dtype)) * (1.0 - a + jnp.sqrt(a) * z) ** 3
    return jnp.where(k > 1, n, jnp.zeros_like(n))


def occupied_bins_per_prefix(poses: jax.Array, bin_size: tuple[float, float, float]) -> jax.Array:
    """``k[m]`` = number of distinct histogram bins among ``poses[0..m]``, for every ``m``.

    A stable lexicographic sort of the integer bin triples puts equal bins
    next to each other in original order, so the head of each run is the
    first occurrence of its bin; scattering those heads back to their
    original positions and taking a cumulative sum counts new bins along the
    original order.
    """
    n = poses.shape[0]
    origin = jnp.asarray([0.0, 0.0, -jnp.pi], poses.dtype)
    theta = weights.wrap_angle(poses[:, 2])
    shifted = jnp.stack([poses[:, 0], poses[:, 1], theta], axis=-1) - origin
    cells = jnp.floor(shifted / jnp.asarray(bin_size, poses.dtype))
    cells = jnp.clip(cells, -_BIN_LIMIT, _BIN_LIMIT).astype(jnp.int32)
    pos = jnp.arange(n, dtype=jnp.int32)
    bx, by, bt, order = jax.lax.sort((cells[:, 0], cells[:, 1], cells[:, 2], pos), num_keys=3, is_stable=True)
    differs = (bx[1:] != bx[:-1]) | (by[1:] != by[:-1]) | (bt[1:] != bt[:-1])
    head = jnp.concatenate([jnp.ones((1,), bool), differs])
    first = jnp.zeros((n,), jnp.int32).at[order].set(head.astype(jnp.int32))
    return jnp.cumsum(first)


def choose_count(k_prefix: jax.Array, config: KLDMCLConfig, dtype: Any) -> jax.Array:
    """Fox's stopping rule on the prefix sequence: the first ``m`` with ``m ≥ n_χ(k(m))`` and ``m ≥ n_min``."""
    n_max = config.max_particles
    m = jnp.arange(1, n_max + 1)
    bound = kld_bound(k_prefix, jnp.asarray(config.epsilon, dtype), jnp.asarray(config.delta, dtype))
    ok = (m.astype(dtype) >= bound) & (m >= config.min_particles)
    return jnp.where(jnp.any(ok), jnp.argmax(ok) + 1, n_max).astype(jnp.int32)


# ---------------------------------------------------------------------------
# host-side validation


def _validate_params(config: KLDMCLConfig, params: MCLParams) -> None:
    if config.sensor is lm.RANGE_BEARING_SENSOR and not isinstance(params, MCLParams):
        raise ValueError(f"params must be an MCLParams (KLDMCLParams), got {type(params).__name__}")
    check_pose_filter_params(config, params)


def _validate_state(config: KLDMCLConfig, params: Any, state: KLDMCLState) -> None:
    check_shape("state.particles", state.particles, (config.max_particles, 3))
    check_shape("state.log_weights", state.log_weights, (config.max_particles,))
    check_shape("state.num_active", state.num_active, ())
    if is_concrete(state.num_active):
        n = int(np.asarray(state.num_active))
        if not (1 <= n <= config.max_particles):
            raise ValueError(f"state.num_active must be in [1, {config.max_particles}], got {n}")


# ---------------------------------------------------------------------------
# init


def _as_mcl_config(config: KLDMCLConfig) -> mcl.MCLConfig:
    return mcl.MCLConfig(num_particles=config.max_particles, motion_model=config.motion_model, sensor=config.sensor)


def _with_count(state: mcl.MCLState, n: int) -> KLDMCLState:
    return KLDMCLState(state.particles, state.log_weights, jnp.asarray(n, jnp.int32))


@memory.guard_init
def init(
    key: jax.Array,
    config: KLDMCLConfig,
    params: MCLParams,
    initial_pose: jax.Array,
    initial_sd: jax.Array | None = None,
) -> KLDMCLState:
    """All ``N_max`` slots active, drawn from ``N(initial_pose, diag(initial_sd²))`` (m, m, rad).

    The same draw as :func:`jaxnav.localization.mcl.init` with ``N_max`` particles.
    """
    filter_api.check_key(key)
    _validate_params(config, params)
    return _with_count(mcl.init(key, _as_mcl_config(config), params, initial_pose, initial_sd), config.max_particles)


@memory.guard_init
def init_uniform(
    key: jax.Array, config: KLDMCLConfig, params: MCLParams, bounds: tuple[float, float, float, float]
) -> KLDMCLState:
    """Global localization: all ``N_max`` slots active, uniform in ``bounds = (x_min, x_max, y_min, y_max)`` (m), θ uniform."""
    filter_api.check_key(key)
    _validate_params(config, params)
    return _with_count(mcl.init_uniform(key, _as_mcl_config(config), params, bounds), config.max_particles)


# ---------------------------------------------------------------------------
# step and run


@filter_api.guard_inputs(pose_filter_inputs_in_domain)
def kernel(
    key: jax.Array,
    state: KLDMCLState,
    config: KLDMCLConfig,
    params: MCLParams,
    control: jax.Array,
    obs: Any,
) -> tuple[KLDMCLState, KLDMCLInfo]:
    """One KLD-sampling MCL update, pure and traceable (:func:`step` is it validated and jitted)."""
    n_max = config.max_particles
    k_move, k_cand, k_res = jax.random.split(key, 3)
    n_prev = jnp.clip(jnp.asarray(state.num_active, jnp.int32), 1, n_max)
    active = jnp.arange(n_max) < n_prev
    dtype = state.particles.dtype

    # Inactive slots are never read: zero poses in, -inf weight.
    particles_in = jnp.where(active[:, None], state.particles, jnp.zeros_like(state.particles))
    log_w_in = jnp.where(
        active, weights.normalize(jnp.where(active, state.log_weights, -jnp.inf)).log_weights, -jnp.inf
    )
    w = mcl.move_and_weight(k_move, particles_in, log_w_in, config.motion_model, params, control, obs, config.sensor)
    # normalize() resets a degenerate set to uniform over all N_max slots: re-mask it.
    uniform_active = jnp.where(active, -jnp.log(n_prev.astype(dtype)), -jnp.inf)
    log_w = jnp.where(w.norm.degenerate, uniform_active, jnp.where(active, w.norm.log_weights, -jnp.inf))
    probs = jnp.where(active, jnp.exp(log_w), 0.0)
    particles = jnp.where(active[:, None], w.particles, 0.0)

    estimate = weights.mean_from_probabilities(particles, probs, _ANGLE_DIMS)
    ess = weights.step_ess(probs, w.norm.degenerate)

    # Candidates: N_max i.i.d. draws from the weighted set, in random order
    # (the exact inverse CDF of unsorted uniforms; masked slots have weight zero and are never drawn).
    u = rng.uniform(k_cand, (n_max,), dtype)
    cand_idx = resampling.inverse_cdf(u, probs)
    k_prefix = occupied_bins_per_prefix(jnp.take(particles, cand_idx, axis=0), config.bin_size)
    n_new = choose_count(k_prefix, config, dtype)
    num_bins = jnp.take(k_prefix, n_new - 1)

    # Systematic resampling of n_new particles into slots 0..n_new-1.
    new_active = jnp.arange(n_max) < n_new
    idx = resampling.resample_weights(k_res, probs, n_max, "systematic", num_active=n_new)
    new_particles = jnp.where(new_active[:, None], jnp.take(particles, idx, axis=0), 0.0)
    new_log_w = jnp.where(new_active, -jnp.log(n_new.astype(dtype)), -jnp.inf)

    info = KLDMCLInfo(
        estimate,
        ess,
        jnp.asarray(True),
        w.norm.log_norm,
        w.norm.degenerate,
        w.num_ignored,
        n_new,
        num_bins.astype(jnp.int32),
    )
    return KLDMCLState(new_particles, new_log_w, n_new), info


def _active_slots(state: KLDMCLState) -> KLDMCLState:
    """The active slots of a concrete state, on the host (the others are never read)."""
    n = int(np.asarray(state.num_active))
    return state._replace(particles=np.asarray(state.particles)[:n], log_weights=np.asarray(state.log_weights)[:n])


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="KLD-sampling MCL",
        kernel=kernel,
        config_type=KLDMCLConfig,
        state_type=KLDMCLState,
        state_values=_active_slots,
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=check_pose_filter_inputs,
        prepare=prepare_pose_filter_inputs,
        valid_inputs=pose_filter_inputs_in_domain,
        time_inputs=("controls", "observations"),
        step_doc="""One KLD-sampling MCL update (Thrun et al. Tab. 8.4, fixed shapes) with ``control
        [control_dim]`` and one step's observation of ``config.sensor`` (range-bearing: a
        :class:`~jaxnav.models.landmarks.RangeBearingObs`).""",
        run_doc="""KLD-sampling MCL over a sequence: ``controls [T, control_dim]``, observations with leading
        axis ``T``, ``state`` from :func:`init` or :func:`init_uniform`; ``trace`` a :class:`KLDMCLInfo`
        (``trace.num_active`` is ``[T]``).""",
    ),
    __name__,
)
