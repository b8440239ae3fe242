"""Monte Carlo localization with a known landmark map, [A] Alg. 3.

**Overview**

A bootstrap particle filter over poses ``(x, y, θ)``. Each step ([A] Alg. 3):

1. move every particle with a draw of the motion model (line 3);
2. weight it by the sensor's likelihood ``p(z_t | x_t)`` (line 4), on the log scale and multiplied
   into the weights carried from the last step;
3. estimate the pose as the weighted mean, heading on the circle (line 11) —
   taken *before* resampling, which adds noise and no information;
4. resample (lines 7–10) when the ESS falls below ``ess_threshold · N``.
   The default threshold 1.0 resamples every step, exactly as Alg. 3.

Interface (shared by every jaxnav filter)::

    state = mcl.init(key, config, params, initial_pose, initial_sd)
    state, info = mcl.step(key, state, config, params, control, observation)
    final_state, trace = mcl.run(key, state, config, params, controls, observations)

``config`` (:class:`MCLConfig`) is static and fixes the shapes; ``params``
(:class:`MCLParams`) is a differentiable pytree; ``state``
(:class:`MCLState`) and ``info`` (:class:`MCLInfo`) are NamedTuples of arrays.
``run`` scans ``step`` over time; the key of step ``t`` is
``jax.random.fold_in(key, t)``, so ``run`` and a loop of ``step`` calls with
those keys give identical results.

**Sensors and motion models.** ``MCLConfig.sensor`` is any
:class:`~jaxnav.models.sensor.ParticleSensor`; the default,
:data:`~jaxnav.models.landmarks.RANGE_BEARING_SENSOR`, weights by range-bearing observations of the
landmarks of ``params.landmarks`` ([A] Alg. 3), with ``params`` an :class:`MCLParams`. Another
sensor brings its own observations and reads its own fields of ``params``, any pytree with a
``motion`` field (the motion model's noise). ``MCLConfig.motion_model`` is a name in
:data:`jaxnav.models.motion.MODELS` or any :class:`~jaxnav.models.motion.MotionModel`.
Augmented MCL and KLD-MCL take both the same way.

Robustness: a masked observation slot, or one whose landmark id is not in the
map, is ignored (and counted in ``info.num_ignored``); a step in which every
particle has zero likelihood resets the weights to uniform and sets
``info.degenerate`` instead of producing NaN.

**Gradients.** ``jax.grad`` of ``trace.log_likelihood.sum()`` (the log marginal-likelihood
estimate ``log Ẑ``) with respect to ``params`` passes the moves pathwise and the resampling
by ``MCLConfig.gradient``: by default stop-gradient resampling (:mod:`jaxnav.core.gradients`),
whose ``∇Ẑ`` is unbiased for ``∇Z`` with multinomial resampling (and passed the same test with
systematic); :mod:`jaxnav.calibration` fits ``params`` with it.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from jaxnav.core import filter as filter_api
from jaxnav.core import gradients, memory, resampling, rng, sharded, weights
from jaxnav.core.particle_filter import PFInfo, extend_info, finish_step, keep_finite, materialize
from jaxnav.core.validation import (
    check_bounds,
    check_choice,
    check_finite,
    check_fraction,
    check_nonnegative,
    check_positive_int,
    check_shape,
    float_array,
)
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import MotionModel, check_motion_model, get_motion_model
from jaxnav.models.sensor import (
    ParticleSensor,
    check_pose_filter_inputs,
    check_pose_filter_params,
    check_sensor,
    pose_filter_inputs_in_domain,
    prepare_pose_filter_inputs,
)

__all__ = [
    "MCLConfig",
    "MCLParams",
    "MCLState",
    "MCLInfo",
    "init",
    "init_uniform",
    "kernel",
    "step",
    "run",
    "sharded_kernel",
    "run_sharded",
    "move_and_weight",
    "Weighted",
]

_ANGLE_DIMS = (2,)


@dataclass(frozen=True)
class MCLConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        num_particles: N, number of pose particles.
        motion_model: a name in :data:`jaxnav.models.motion.MODELS` or a
            :class:`~jaxnav.models.motion.MotionModel`.
        resampling: name in :data:`jaxnav.core.resampling.SCHEMES`.
        ess_threshold: resample when ESS < ``ess_threshold · N``; in (0, 1];
            1.0 resamples every step ([A] Alg. 3).
        gaussian_refresh: redraw the resampled set from its fitted Gaussian
            ([A] §4.3.3); meant for static targets, off for a moving robot.
        sensor: the :class:`~jaxnav.models.sensor.ParticleSensor` that weights the particles
            (default: range-bearing observations of a known landmark map).
        gradient: how ``jax.grad`` of the log-likelihood passes resampling, a name in
            :data:`jaxnav.core.gradients.GRADIENT_ESTIMATORS`: ``"score"`` (default; the forward
            pass unchanged; ``∇Ẑ`` unbiased for ``∇Z`` with multinomial resampling), ``"soft"`` or ``"naive"``
            (:mod:`jaxnav.core.gradients` gives each one's bias and variance).
        soft_mixing: ``α`` in ``[0, 1]`` of ``"soft"`` resampling (ancestors drawn from
            ``α w̄ + (1 − α)/N``); unused by the other estimators.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles",)
    num_particles: int = 1000
    motion_model: str | MotionModel = "velocity"
    resampling: str = "systematic"
    ess_threshold: float = 1.0
    gaussian_refresh: bool = False
    sensor: ParticleSensor = lm.RANGE_BEARING_SENSOR
    gradient: str = "score"
    soft_mixing: float = 0.5

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_sensor("sensor", self.sensor)
        check_motion_model("motion_model", self.motion_model)
        check_choice("resampling", self.resampling, resampling.SCHEMES)
        check_fraction("ess_threshold", self.ess_threshold)
        gradients.check_gradient(self.gradient, self.soft_mixing)
        if self.gradient == "soft" and self.gaussian_refresh:  # the refresh would ignore the carried weights
            raise ValueError("gradient 'soft' cannot be combined with gaussian_refresh")


MCLParams = lm.LandmarkMapParams
"""MCL's differentiable parameters with its default sensor, :class:`jaxnav.models.landmarks.LandmarkMapParams`
(motion noise, range-bearing noise, landmarks ``[M, 2]`` in m), shared with the grid, EKF and UKF
filters. Another sensor takes any pytree with a ``motion`` field and the fields it reads."""


class MCLState(NamedTuple):
    """Filter state carried between steps.

    Attributes:
        particles: ``[N, 3]`` poses (m, m, rad).
        log_weights: ``[N]`` normalised log-weights.
    """

    particles: jax.Array
    log_weights: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MCLInfo(PFInfo):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` weighted mean pose after the update (circular θ).
        ess: effective sample size after the update, before resampling.
        resampled: bool, whether this step resampled.
        log_likelihood: ``log p(z_t | z_{1:t−1})`` estimate (−inf if degenerate).
        degenerate: bool, every particle had zero likelihood; weights were reset.
        num_ignored: int32, observation slots dropped because their id is not in the map.
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    num_ignored: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# host-side validation


def _validate_params(config: MCLConfig, params: MCLParams) -> None:
    if config.sensor is lm.RANGE_BEARING_SENSOR and not isinstance(params, MCLParams):
        raise ValueError(f"params must be an MCLParams, got {type(params).__name__}")
    check_pose_filter_params(config, params)


def _validate_state(config: MCLConfig, params: Any, state: MCLState) -> None:
    check_shape("state.particles", state.particles, (config.num_particles, 3))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))


# ---------------------------------------------------------------------------
# init


@memory.guard_init
def init(
    key: jax.Array,
    config: MCLConfig,
    params: MCLParams,
    initial_pose: jax.Array,
    initial_sd: jax.Array | None = None,
) -> MCLState:
    """Particles drawn from ``N(initial_pose, diag(initial_sd²))``, uniform weights.

    Args:
        key: one PRNG key (``jax.random.key(seed)`` or ``jax.random.PRNGKey(seed)``); a raw key of
            another length, a batch of keys or ``None`` raise ``ValueError`` naming it.
        config, params: as everywhere.
        initial_pose: ``[3]`` (m, m, rad).
        initial_sd: ``[3]`` standard deviations (m, m, rad); zeros (the
            default) start every particle at the known pose (pose tracking).
    """
    filter_api.check_key(key)
    _validate_params(config, params)
    initial_pose = float_array("initial_pose", initial_pose)
    check_shape("initial_pose", initial_pose, (3,))
    check_finite("initial_pose", initial_pose)
    sd = jnp.zeros((3,), initial_pose.dtype) if initial_sd is None else jnp.asarray(initial_sd, initial_pose.dtype)
    check_shape("initial_sd", sd, (3,))
    check_nonnegative("initial_sd", sd)
    n = config.num_particles
    eps = rng.normal(key, (n, 3), initial_pose.dtype)
    particles = initial_pose + eps * sd
    particles = particles.at[:, 2].set(weights.wrap_angle(particles[:, 2]))
    return MCLState(particles, _uniform(n, initial_pose.dtype))


@memory.guard_init
def init_uniform(
    key: jax.Array, config: MCLConfig, params: MCLParams, bounds: tuple[float, float, float, float]
) -> MCLState:
    """Global localization: positions uniform in ``bounds = (x_min, x_max, y_min, y_max)`` (m), θ uniform."""
    filter_api.check_key(key)
    _validate_params(config, params)
    x0, x1, y0, y1 = check_bounds("bounds", bounds)
    n = config.num_particles
    dtype = jnp.result_type(float)  # float64 under jax_enable_x64, like the particles of init
    u = rng.uniform(key, (n, 3), dtype)
    lo = jnp.asarray([x0, y0, -jnp.pi], dtype)
    hi = jnp.asarray([x1, y1, jnp.pi], dtype)
    return MCLState(lo + u * (hi - lo), _uniform(n, dtype))


def _uniform(n: int, dtype: Any) -> jax.Array:
    return jnp.full((n,), -np.log(n), dtype)


# ---------------------------------------------------------------------------
# step and run


class Weighted(NamedTuple):
    """Output of :func:`move_and_weight` (lines 3–4 of [A] Alg. 3).

    Attributes:
        particles: ``[N, 3]`` moved poses.
        norm: :class:`jaxnav.core.weights.Normalized` of ``log w̄_{t−1} + log p(z_t | x_t)``;
            ``norm.log_norm`` is the log marginal-likelihood increment.
        probs: ``[N]`` ``exp(norm.log_weights)``.
        num_ignored: int32, observation slots the sensor dropped (range-bearing: id not in the map).
    """

    particles: jax.Array
    norm: weights.Normalized
    probs: jax.Array
    num_ignored: jax.Array


def move_and_weight(
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array,
    motion_model: str | MotionModel,
    params: Any,
    control: jax.Array,
    obs: Any,
    sensor: ParticleSensor = lm.RANGE_BEARING_SENSOR,
    axis_name: str | None = None,
) -> Weighted:
    """Move ``particles [N, 3]`` by a draw of ``motion_model`` and weight them by ``sensor``'s
    likelihood of ``obs``.

    ``log_weights`` must be normalised (entries of ``-inf`` stay ``-inf``:
    masked particles keep zero weight). ``params`` needs the field ``motion`` and those the sensor
    reads (range-bearing: ``sensor`` and ``landmarks``). Shared by MCL and its augmented
    and KLD-sampling variants; traceable, not jitted on its own.

    ``axis_name`` (inside ``jax.shard_map``): ``particles`` are this device's block of particles spread
    over that mesh axis; the motion draws are blocks of the whole draw
    (:func:`jaxnav.core.rng.particle_blocks`) and the weights are normalised over every device.
    """
    model = get_motion_model(motion_model)
    blocks = contextlib.nullcontext() if axis_name is None else rng.particle_blocks(axis_name, particles.shape[0])
    with blocks:
        moved = materialize(model.sample(key, particles, control, params.motion))
    moved, loglik = keep_finite(particles, moved, sensor.log_likelihood(moved, obs, params))
    num_ignored = sensor.num_ignored(obs, params)
    # log_weights is normalised, so the normaliser of the product is the
    # log marginal-likelihood increment log Σ w̄_{t−1} p(z_t | x_t).
    norm = weights.normalize(log_weights + loglik, axis_name)
    return Weighted(moved, norm, jnp.exp(norm.log_weights), num_ignored)


@filter_api.guard_inputs(pose_filter_inputs_in_domain)
def kernel(
    key: jax.Array,
    state: MCLState,
    config: MCLConfig,
    params: MCLParams,
    control: jax.Array,
    obs: Any,
) -> tuple[MCLState, MCLInfo]:
    """One MCL update ([A] Alg. 3), pure and traceable (:func:`step` is it validated and jitted)."""
    k_move, k_resample = jax.random.split(key)
    w = move_and_weight(
        k_move, state.particles, state.log_weights, config.motion_model, params, control, obs, config.sensor
    )
    res, base = finish_step(
        k_resample,
        w.particles,
        w.norm,
        threshold=config.ess_threshold,
        scheme=config.resampling,
        refresh=config.gaussian_refresh,
        angle_dims=_ANGLE_DIMS,
        gradient=config.gradient,
        soft_mixing=config.soft_mixing,
    )
    return MCLState(res.particles, res.log_weights), extend_info(MCLInfo, base, num_ignored=w.num_ignored)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="MCL",
        kernel=kernel,
        config_type=MCLConfig,
        state_type=MCLState,
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=check_pose_filter_inputs,
        prepare=prepare_pose_filter_inputs,
        valid_inputs=pose_filter_inputs_in_domain,
        time_inputs=("controls", "observations"),
        step_doc="""One MCL update ([A] Alg. 3) with ``control [control_dim]`` and one step's observation
        of ``config.sensor`` (range-bearing: :class:`~jaxnav.models.landmarks.RangeBearingObs` with slots
        ``[K]``).""",
        run_doc="""MCL over a whole sequence: ``controls [T, control_dim]`` and observations with leading
        axis ``T``; ``state`` from :func:`init` or :func:`init_uniform`. ``trace`` is an
        :class:`MCLInfo` stacked over ``T`` (``trace.estimate`` is ``[T, 3]``).""",
    ),
    __name__,
)


# --------------------------------------------------------------------------- particles over devices


@filter_api.guard_inputs(pose_filter_inputs_in_domain)
def sharded_kernel(
    key: jax.Array,
    state: MCLState,
    config: MCLConfig,
    params: MCLParams,
    control: jax.Array,
    obs: Any,
) -> tuple[MCLState, MCLInfo]:
    """:func:`kernel` on this device's block of particles, inside ``jax.shard_map`` over the mesh axis
    :data:`jaxnav.core.sharded.PARTICLE_AXIS` (``state`` holds ``N / D`` particles; ``key``,
    ``params``, ``control`` and ``obs`` are the same on every device).

    Each particle moves with the noise it gets in the unsharded step (the draws are blocks of the
    whole draw, :func:`jaxnav.core.rng.particle_blocks`); the normaliser, the ESS and the
    resampling are those of the whole set (:func:`jaxnav.core.weights.normalize`,
    :func:`jaxnav.core.sharded.finish_step`, sums over devices: see :func:`run_sharded`).
    """
    if config.gaussian_refresh:
        raise ValueError("config.gaussian_refresh is not available with the particles spread over devices")
    axis_name = sharded.PARTICLE_AXIS
    k_move, k_resample = jax.random.split(key)
    w = move_and_weight(
        k_move, state.particles, state.log_weights, config.motion_model, params, control, obs, config.sensor, axis_name
    )
    res, base = sharded.finish_step(
        k_resample,
        w.particles,
        w.norm,
        axis_name,
        threshold=config.ess_threshold,
        scheme=config.resampling,
        angle_dims=_ANGLE_DIMS,
        gradient=config.gradient,
    )
    return MCLState(res.particles, res.log_weights), extend_info(MCLInfo, base, num_ignored=w.num_ignored)


def run_sharded(
    key: jax.Array,
    state: MCLState,
    config: MCLConfig,
    params: Any,
    controls: jax.Array,
    observations: Any,
    devices: Any = None,
) -> tuple[MCLState, MCLInfo]:
    """:func:`run` with the particles spread over ``devices`` (default: every local device).

    The ``N`` particles are split into ``D`` blocks of ``N / D`` consecutive particles, one per
    device, and each step runs :func:`sharded_kernel` on every block inside ``jax.shard_map``.
    Per step the devices exchange a few scalars (the largest log-weight, the sums of the weights
    and of their squares, the estimate's sums), the resampling's integer totals and its histogram
    of ``N`` offspring counts (reduce-scattered), and, on a resampling step, every block of
    particles passes once round the ring of devices (:mod:`jaxnav.core.sharded`).

    **The same numbers.** Each particle moves with the noise it gets in :func:`run` (the draws are
    blocks of the whole draw), and, from the same weights and key, the resampling draws
    :func:`run`'s ancestors exactly. The normaliser, the ESS and the estimate are sums over devices
    in another order than one device's: they agree with :func:`run`'s to float rounding, and the
    particles carried on are :func:`run`'s as long as no weight or resampling decision rounds
    differently (measured in ``tests/localization/test_mcl_sharded.py``: seven runs of 25 steps with
    whole rows of 1024 particles per device carried exactly :func:`run`'s particles).

    The other arguments are :func:`run`'s; ``config.resampling`` must be ``"systematic"`` or
    ``"stratified"`` (:data:`jaxnav.core.sharded.SCHEMES`), ``config.gaussian_refresh`` off and
    ``config.gradient`` not ``"soft"``.

    Args:
        devices: ``None`` (every local device), a number ``D`` of local devices, or a sequence of
            local devices (:func:`jaxnav.core.batch.run_devices`); ``N`` must be a multiple of ``D``.

    Returns:
        ``(final_state, trace)`` as :func:`run`; the final state's arrays stay spread over the devices.

    The memory guard of :func:`run` (a run refused before it allocates more than a device holds)
    is not applied: each device holds ``N / D`` particles and the trace is ``[T]`` scalars and poses.
    """
    inputs = run.check(key, state, config, params, controls, observations)  # type: ignore[attr-defined]
    if config.gaussian_refresh:
        raise ValueError("config.gaussian_refresh is not available with the particles spread over devices")
    if config.gradient == "soft":
        raise ValueError("config.gradient 'soft' is not available with the particles spread over devices")
    chosen = sharded.spread_devices(config.num_particles, config.resampling, devices)
    blocks = MCLState(P(sharded.PARTICLE_AXIS), P(sharded.PARTICLE_AXIS))
    return sharded.scan_program(sharded_kernel, config, chosen, blocks)(key, state, params, *inputs)
