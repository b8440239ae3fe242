"""Augmented Monte Carlo localization: random-particle injection for the kidnapped robot.

**Overview**

[A] §2.1.3: "Solving the kidnapped robot problem [...] in Monte Carlo
localization requires just a slight modification [...] add some random
particles [...]. The amount of the random particles may be [...] adaptive by
comparing the short-term with the long-term likelihood of the observations
(Augmented MCL)". This is Thrun, Burgard & Fox, *Probabilistic Robotics*,
Tab. 8.3. Each step:

1. move every particle with a draw of the motion model and weight it by the
   sensor's likelihood (as :mod:`jaxnav.localization.mcl`, [A] Alg. 3
   lines 3–4; the shared helper :func:`jaxnav.localization.mcl.move_and_weight`);
2. the average observation likelihood ``w_avg = Σ_i w̄_{t−1,i} p(z_t | x_t^i)``
   (Tab. 8.3 line 6 with uniform ``w̄_{t−1}``, which it always is here,
   because every step resamples) updates two exponential averages (lines 8–9)::

       w_slow ← w_slow + α_slow (w_avg − w_slow)
       w_fast ← w_fast + α_fast (w_avg − w_fast),    0 < α_slow < α_fast ≤ 1;

3. the pose estimate is the weighted mean before resampling (circular θ);
4. resample N particles with the configured scheme; then each resampled
   particle is replaced, independently with probability
   ``p_inject = max(0, 1 − w_fast / w_slow)`` (line 11), by a pose drawn
   uniformly in the map bounds ``(x_min, x_max, y_min, y_max)`` with θ
   uniform in ``[−π, π)``. Fixed shapes: all N random poses are drawn and a
   per-particle Bernoulli mask picks which replace the resampled ones.

Log domain. ``w_avg``, ``w_slow`` and ``w_fast`` are densities of the whole
observation vector (with 8 landmarks at σ = (0.1 m, 0.05 rad) ``w_avg ≈ e²⁰``;
after a kidnap ``≈ e⁻³⁰⁰⁰``), so they are kept as logarithms:
``log w_avg`` is the step's log marginal-likelihood increment
(``info.log_likelihood``) and the averages are updated with
``log w ← logaddexp(log(1 − α) + log w, log α + log w_avg)``;
``p_inject = −expm1(log w_fast − log w_slow)`` clipped to ``[0, 1]``.
Both averages start at ``w = 0`` (``log w = −inf``), as in Tab. 8.3; while
``w_slow = 0`` nothing is injected. Since ``α_fast > α_slow`` the fast
average rises first, so a filter that starts well does not inject during the
first ``~1/α_slow`` steps. A step whose likelihood is zero for every
particle (``log w_avg = −inf``, flagged ``info.degenerate``) only decays the
averages, so repeated failures raise ``p_inject`` towards 1 — the global
re-initialisation one wants when the robot is lost.

Where the constants live. ``alpha_slow`` and ``alpha_fast`` are in
:class:`AugmentedMCLConfig` (static): they only shape ``p_inject``, which
feeds a Bernoulli draw, so no gradient reaches the estimate through them;
as static floats they are validated strictly when the config is built; and
they play the role of ``ess_threshold`` in :class:`~jaxnav.localization.mcl.MCLConfig`.
Changing them recompiles. The map ``bounds`` are in :class:`AugmentedMCLParams`
(a ``[4]`` array): they describe the map, like ``landmarks``, so a ``vmap``
over maps or rooms needs them batched alongside the landmarks, and the
uniform draw ``lo + u·(hi − lo)`` is reparameterised, hence differentiable
in the bounds.

Caveat (Thrun et al. §8.3.5): ``w_avg`` is a density of *all* the step's
observations, so its scale depends on how many landmarks are seen; when that
number changes a lot between steps (a limited field of view), ``w_fast/w_slow``
swings with it and particles are injected spuriously. The averages work best
when the number of observations per step is roughly constant.

Interface (as :mod:`jaxnav.localization.mcl`)::

    state = augmented_mcl.init(key, config, params, initial_pose, initial_sd)
    state = augmented_mcl.init_uniform(key, config, params)        # bounds from params
    state, info = augmented_mcl.step(key, state, config, params, control, observation)
    final_state, trace = augmented_mcl.run(key, state, config, params, controls, observations)

Gradients: the weights after resampling are uniform constants (the ``"naive"`` estimator of
:mod:`jaxnav.core.gradients`: no derivative passes the resampling or the injection mask), and the
injected poses carry no weight, so ``info.log_likelihood`` is a likelihood increment only at a step
without injection; fit parameters with MCL (:mod:`jaxnav.calibration`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import memory, resampling, rng, weights
from jaxnav.core.particle_filter import PFInfo
from jaxnav.core.validation import check_choice, check_finite, check_positive_int, check_shape, is_concrete
from jaxnav.localization import mcl
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
    "AugmentedMCLConfig",
    "AugmentedMCLParams",
    "AugmentedMCLState",
    "AugmentedMCLInfo",
    "init",
    "init_uniform",
    "kernel",
    "step",
    "run",
    "update_average",
]

_ANGLE_DIMS = (2,)


@dataclass(frozen=True)
class AugmentedMCLConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        num_particles: N, number of pose particles.
        motion_model: a name in :data:`jaxnav.models.motion.MODELS` or a
            :class:`~jaxnav.models.motion.MotionModel`.
        resampling: name in :data:`jaxnav.core.resampling.SCHEMES`; every
            step resamples (Tab. 8.3), so there is no ESS threshold.
        alpha_slow: decay rate of the long-term likelihood average, per step.
        alpha_fast: decay rate of the short-term average;
            ``0 < alpha_slow < alpha_fast ≤ 1`` (Thrun et al. §8.3.5).
            With the defaults ``w_slow`` remembers ~1/α_slow = 50 steps and
            ``w_fast`` ~5; in the kidnapped-robot test (1,000 particles, 8
            landmarks, a 3.5 m kidnap after 120 steps) they recover within
            25 steps and inject nothing during ordinary tracking. A larger
            ``alpha_slow`` forgets the pre-kidnap likelihood sooner but injects
            during tracking too; a smaller one keeps ``p_inject ≈ 1`` longer
            after a kidnap, which throws away good hypotheses as they appear.
        sensor: the :class:`~jaxnav.models.sensor.ParticleSensor` that weights the particles
            (default: range-bearing observations of a known landmark map, with
            :class:`AugmentedMCLParams`; another sensor takes any params pytree with the fields
            ``motion``, ``bounds`` and those it reads).
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles",)
    num_particles: int = 1000
    motion_model: str | MotionModel = "velocity"
    resampling: str = "systematic"
    alpha_slow: float = 0.02
    alpha_fast: float = 0.2
    sensor: ParticleSensor = lm.RANGE_BEARING_SENSOR

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_sensor("sensor", self.sensor)
        check_motion_model("motion_model", self.motion_model)
        check_choice("resampling", self.resampling, resampling.SCHEMES)
        for name in ("alpha_slow", "alpha_fast"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ValueError(f"{name} must be a real number, got {value!r}")
        if not (0.0 < self.alpha_slow < self.alpha_fast <= 1.0):
            raise ValueError(
                "augmented MCL needs 0 < alpha_slow < alpha_fast <= 1, got "
                f"alpha_slow={self.alpha_slow!r}, alpha_fast={self.alpha_fast!r}"
            )


class AugmentedMCLParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: noise of the configured motion model (e.g. ``VelocityNoise``).
        sensor: range-bearing noise ``(σ_r [m], σ_φ [rad])``.
        landmarks: ``[M, 2]`` known landmark positions (m).
        bounds: ``[4]`` map bounds ``(x_min, x_max, y_min, y_max)`` (m) in which
            random particles are injected (and :func:`init_uniform` draws).
    """

    motion: Any
    sensor: lm.RangeBearingNoise
    landmarks: jax.Array
    bounds: jax.Array


class AugmentedMCLState(NamedTuple):
    """Filter state carried between steps.

    Attributes:
        particles: ``[N, 3]`` poses (m, m, rad).
        log_weights: ``[N]`` normalised log-weights (uniform after every step).
        log_w_slow: scalar, log of the long-term likelihood average (−inf = 0).
        log_w_fast: scalar, log of the short-term likelihood average (−inf = 0).
    """

    particles: jax.Array
    log_weights: jax.Array
    log_w_slow: jax.Array
    log_w_fast: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class AugmentedMCLInfo(PFInfo):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` weighted mean pose after the update, before
            resampling and injection (circular θ).
        ess: effective sample size after the update, before resampling.
        resampled: bool, always True (kept for the common MCL info layout).
        log_likelihood: ``log w_avg = log p(z_t | z_{1:t−1})`` estimate (−inf if degenerate).
        degenerate: bool, every particle had zero likelihood; weights were reset.
        num_ignored: int32, observation slots dropped because their id is not in the map.
        injection_probability: ``max(0, 1 − w_fast/w_slow)`` of this step.
        num_injected: int32, particles replaced by random poses this step.
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    num_ignored: jax.Array
    injection_probability: jax.Array
    num_injected: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# host-side validation


def _validate_params(config: AugmentedMCLConfig, params: AugmentedMCLParams) -> None:
    if config.sensor is lm.RANGE_BEARING_SENSOR and not isinstance(params, AugmentedMCLParams):
        raise ValueError(f"params must be an AugmentedMCLParams, got {type(params).__name__}")
    check_pose_filter_params(config, params)
    if not hasattr(params, "bounds"):
        raise ValueError(f"params must have a 'bounds' field (x_min, x_max, y_min, y_max), got {type(params).__name__}")
    check_shape("params.bounds", params.bounds, (4,))
    check_finite("params.bounds", params.bounds)
    if is_concrete(params.bounds):
        x0, x1, y0, y1 = (float(b) for b in np.asarray(params.bounds))
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"params.bounds must satisfy x_min < x_max and y_min < y_max, got {(x0, x1, y0, y1)}")


def _validate_state(config: AugmentedMCLConfig, params: Any, state: AugmentedMCLState) -> None:
    check_shape("state.particles", state.particles, (config.num_particles, 3))
    check_shape("state.log_weights", state.log_weights, (config.num_particles,))
    check_shape("state.log_w_slow", state.log_w_slow, ())
    check_shape("state.log_w_fast", state.log_w_fast, ())


# ---------------------------------------------------------------------------
# init


def _with_averages(state: mcl.MCLState) -> AugmentedMCLState:
    minus_inf = jnp.asarray(-jnp.inf, state.log_weights.dtype)
    return AugmentedMCLState(state.particles, state.log_weights, minus_inf, minus_inf)


def _as_mcl_params(config: AugmentedMCLConfig, params: AugmentedMCLParams) -> Any:
    if config.sensor is not lm.RANGE_BEARING_SENSOR:
        return params  # another sensor's params are the user's pytree, read by field
    return mcl.MCLParams(params.motion, params.sensor, params.landmarks)


def _as_mcl_config(config: AugmentedMCLConfig) -> mcl.MCLConfig:
    return mcl.MCLConfig(config.num_particles, config.motion_model, config.resampling, sensor=config.sensor)


@memory.guard_init
def init(
    key: jax.Array,
    config: AugmentedMCLConfig,
    params: AugmentedMCLParams,
    initial_pose: jax.Array,
    initial_sd: jax.Array | None = None,
) -> AugmentedMCLState:
    """Particles from ``N(initial_pose, diag(initial_sd²))`` (m, m, rad), uniform weights,
    ``w_slow = w_fast = 0``. Same draw as :func:`jaxnav.localization.mcl.init` for the same key."""
    filter_api.check_key(key)
    _validate_params(config, params)
    return _with_averages(
        mcl.init(key, _as_mcl_config(config), _as_mcl_params(config, params), initial_pose, initial_sd)
    )


@memory.guard_init
def init_uniform(
    key: jax.Array,
    config: AugmentedMCLConfig,
    params: AugmentedMCLParams,
    bounds: tuple[float, float, float, float] | None = None,
) -> AugmentedMCLState:
    """Global localization: positions uniform in ``bounds`` (default ``params.bounds``), θ uniform."""
    filter_api.check_key(key)
    _validate_params(config, params)
    if bounds is None:
        bounds = tuple(float(b) for b in np.asarray(params.bounds))
    return _with_averages(mcl.init_uniform(key, _as_mcl_config(config), _as_mcl_params(config, params), bounds))


# ---------------------------------------------------------------------------
# step and run


def update_average(log_w: jax.Array, log_w_avg: jax.Array, alpha: float) -> jax.Array:
    """``log((1 − α)·w + α·w_avg)`` (Tab. 8.3 lines 8–9) without leaving the log domain."""
    log_keep = np.log1p(-alpha) if alpha < 1.0 else -np.inf
    return jnp.logaddexp(log_keep + log_w, np.log(alpha) + log_w_avg)


def injection_probability(log_w_slow: jax.Array, log_w_fast: jax.Array) -> jax.Array:
    """``max(0, 1 − w_fast/w_slow)`` from the log averages (Tab. 8.3 line 11); 0 while ``w_slow = 0``."""
    diff = log_w_fast - jnp.where(jnp.isfinite(log_w_slow), log_w_slow, 0.0)
    p = jnp.clip(-jnp.expm1(jnp.minimum(diff, 0.0)), 0.0, 1.0)
    return jnp.where(jnp.isfinite(log_w_slow), p, jnp.zeros_like(p))


def _inputs_in_domain(
    config: AugmentedMCLConfig, params: AugmentedMCLParams, control: jax.Array, obs: Any
) -> jax.Array:
    """``bool[]``: :func:`jaxnav.models.sensor.pose_filter_inputs_in_domain` and map bounds with
    ``x_min < x_max``, ``y_min < y_max`` (the value checks of the host, as ``jnp``)."""
    b = params.bounds
    return pose_filter_inputs_in_domain(config, params, control, obs) & (b[1] > b[0]) & (b[3] > b[2])


@filter_api.guard_inputs(_inputs_in_domain)
def kernel(
    key: jax.Array,
    state: AugmentedMCLState,
    config: AugmentedMCLConfig,
    params: AugmentedMCLParams,
    control: jax.Array,
    obs: Any,
) -> tuple[AugmentedMCLState, AugmentedMCLInfo]:
    """One augmented-MCL update, pure and traceable (:func:`step` is it validated and jitted)."""
    k_move, k_resample, k_mask, k_pose = jax.random.split(key, 4)
    w = mcl.move_and_weight(
        k_move, state.particles, state.log_weights, config.motion_model, params, control, obs, config.sensor
    )
    particles, probs = w.particles, w.probs
    dtype = particles.dtype

    estimate = weights.mean_from_probabilities(particles, probs, _ANGLE_DIMS)
    ess = weights.step_ess(probs, w.norm.degenerate)

    log_w_avg = w.norm.log_norm
    log_w_slow = update_average(state.log_w_slow, log_w_avg, config.alpha_slow).astype(dtype)
    log_w_fast = update_average(state.log_w_fast, log_w_avg, config.alpha_fast).astype(dtype)
    p_inject = injection_probability(log_w_slow, log_w_fast)

    n = config.num_particles
    idx = resampling.get_resampler(config.resampling)(k_resample, w.norm.log_weights, n)
    resampled = jnp.take(particles, idx, axis=0, mode="clip")
    inject = rng.uniform(k_mask, (n,), dtype) < p_inject
    bounds = params.bounds.astype(dtype)
    lo = jnp.stack([bounds[0], bounds[2], jnp.asarray(-jnp.pi, dtype)])
    hi = jnp.stack([bounds[1], bounds[3], jnp.asarray(jnp.pi, dtype)])
    random_poses = lo + rng.uniform(k_pose, (n, 3), dtype) * (hi - lo)
    new_particles = jnp.where(inject[:, None], random_poses, resampled)
    new_particles = new_particles.at[:, 2].set(weights.wrap_angle(new_particles[:, 2]))
    uniform = jnp.full((n,), -np.log(n), dtype)

    info = AugmentedMCLInfo(
        estimate,
        ess,
        jnp.asarray(True),
        log_w_avg,
        w.norm.degenerate,
        w.num_ignored,
        p_inject,
        jnp.sum(inject).astype(jnp.int32),
    )
    return AugmentedMCLState(new_particles, uniform, log_w_slow, log_w_fast), info


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="augmented MCL",
        kernel=kernel,
        config_type=AugmentedMCLConfig,
        state_type=AugmentedMCLState,
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=check_pose_filter_inputs,
        prepare=prepare_pose_filter_inputs,
        valid_inputs=_inputs_in_domain,
        time_inputs=("controls", "observations"),
        step_doc="""One augmented-MCL update (Thrun et al. Tab. 8.3) with ``control [control_dim]`` and one
        step's observation of ``config.sensor`` (range-bearing: a
        :class:`~jaxnav.models.landmarks.RangeBearingObs`).""",
        run_doc="""Augmented MCL over a sequence: ``controls [T, control_dim]``, observations with leading axis
        ``T``, ``state`` from :func:`init` or :func:`init_uniform`; ``trace`` an :class:`AugmentedMCLInfo`.""",
    ),
    __name__,
)
