"""EKF localization with a known landmark map, [A] Alg. 1 (Thrun et al. Tab. 7.2).

**Overview**

The belief over the pose ``(x, y, θ)`` is one Gaussian ``(μ, Σ)``. Each step:

1. predict with the motion model's mean ``g(u, x)`` ([A] Alg. 1 lines 2–3):
   ``μ̄ = g(u, μ)``, ``Σ̄ = G Σ Gᵀ + Q`` with ``G = ∂g/∂x`` from ``jax.jacfwd``
   and ``Q`` the model's linearised process noise
   (:func:`jaxnav.models.motion.get_motion_model` ``.process_cov``:
   ``V M Vᵀ`` plus any additive pose noise);
2. fuse the step's observations one after another (lines 4–8; known
   correspondences), Jacobians again by ``jax.jacfwd`` of the observation
   model's ``h(x, m)`` (:func:`jaxnav.models.landmarks.predict` for range and
   bearing), covariance in Joseph form, angular residuals wrapped.

The observation model is ``config.observation_model``
(:class:`jaxnav.models.observation.ObservationModel`): range and bearing by
default, a biased range to a beacon (:data:`jaxnav.models.observation.RANGE_ONLY`)
or any other; its sensor parameters are ``params.sensor``.

Optional Mahalanobis gating (``EKFConfig.gate_probability``): an observation
whose NIS exceeds the χ² quantile (``dz`` degrees of freedom) is rejected and counted in
``info.num_gated`` — the outlier handling real data such as MRCLAM needs.

Interface (deterministic: no key)::

    state = ekf.init(config, params, initial_pose, initial_cov)
    state, info = ekf.step(state, config, params, control, observation)
    final_state, trace = ekf.run(config, params, controls, observations, state)

:mod:`jaxnav.localization.ukf` shares the parameters, state and info types.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import kalman
from jaxnav.core.validation import check_covariance, check_magnitude, check_shape
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.models import observation as om
from jaxnav.models.motion import check_motion_model, get_motion_model

__all__ = ["EKFConfig", "KalmanParams", "KalmanState", "KalmanInfo", "init", "kernel", "step", "run"]

STATE_ANGLE_DIMS = (2,)
OBS_ANGLE_DIMS = (1,)  # range and bearing's; a configuration's model gives its own (Config.obs_model.angle_dims)


@dataclass(frozen=True)
class EKFConfig:
    """Static configuration.

    Attributes:
        motion_model: name in :data:`jaxnav.models.motion.MODELS` or a motion model.
        gate_probability: if set (e.g. 0.999), reject observations whose NIS
            exceeds the χ² quantile of that probability (``dz`` degrees of freedom, 2 for
            range and bearing); None disables gating.
        observation_model: a name in :data:`jaxnav.models.observation.OBSERVATION_MODELS` or an
            :class:`~jaxnav.models.observation.ObservationModel` (default range and bearing).
    """

    motion_model: str = "velocity"
    gate_probability: float | None = None
    observation_model: str | om.ObservationModel = "range_bearing"

    def __post_init__(self) -> None:
        check_kalman_config(self)

    @property
    def obs_model(self) -> om.ObservationModel:
        """The resolved :class:`~jaxnav.models.observation.ObservationModel`."""
        return om.get_observation_model(self.observation_model)

    @property
    def gate(self) -> float | None:
        """The NIS threshold (χ² quantile of ``dz`` degrees of freedom), or None."""
        return gate_of(self)


def check_kalman_config(config: Any) -> None:
    """The fields EKF and UKF configurations share: motion model, observation model, gate."""
    check_motion_model("motion_model", config.motion_model)
    om.check_observation_model("observation_model", config.observation_model)
    if config.gate_probability is not None:
        kalman.chi2_gate(config.gate_probability, config.obs_model.obs_dim)  # a ValueError naming the problem


def gate_of(config: Any) -> float | None:
    """The NIS threshold of ``config.gate_probability`` for its observation model's ``dz``, or None."""
    if config.gate_probability is None:
        return None
    return kalman.chi2_gate(config.gate_probability, config.obs_model.obs_dim)


KalmanParams = lm.LandmarkMapParams
"""EKF/UKF localization's differentiable parameters, :class:`jaxnav.models.landmarks.LandmarkMapParams`
(motion noise, the observation model's sensor parameters — range-bearing noise by default —, landmarks
``[M, D]`` in m), shared with MCL and the grid."""


class KalmanState(NamedTuple):
    """Gaussian pose belief: ``mean [3]`` (m, m, rad) and ``cov [3, 3]``."""

    mean: jax.Array
    cov: jax.Array


class KalmanInfo(NamedTuple):
    """Per-step diagnostics (stacked over time by ``run``).

    Attributes:
        estimate: ``[3]`` posterior mean.
        cov: ``[3, 3]`` posterior covariance (for NEES checks and plots).
        nis: ``[K]`` normalised innovation squared per observation slot (0 where invalid).
        accepted: ``[K]`` bool, slot was fused.
        log_likelihood: ``Σ log N(z; ẑ, S)`` over fused observations.
        num_ignored: slots whose landmark id is not in the map.
        num_gated: valid slots rejected by the gate.
        cholesky_failed: bool, a UKF factorisation fell back to the diagonal (EKF: always False).
        degenerate: bool, the step's result was not finite and was not applied: the state is carried
            over unchanged (:func:`jaxnav.core.kalman.finite_or_previous`).
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    estimate: jax.Array
    cov: jax.Array
    nis: jax.Array
    accepted: jax.Array
    log_likelihood: jax.Array
    num_ignored: jax.Array
    num_gated: jax.Array
    cholesky_failed: jax.Array
    degenerate: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# validation (shared with ukf)


def validate_params(config: Any, params: KalmanParams) -> None:
    """Host-side checks of :class:`KalmanParams` against ``config.motion_model`` and ``config.obs_model``."""
    if not isinstance(params, KalmanParams):
        raise ValueError(f"params must be a KalmanParams, got {type(params).__name__}")
    motion.validate_noise(config.motion_model, params.motion)
    config.obs_model.validate(params.sensor)
    lm.check_landmark_map(params.landmarks, config.obs_model.landmark_dim)


def check_inputs(config: Any, params: KalmanParams, controls: Any, obs: Any, time_axis: bool) -> None:
    """Host-side check of the control(s) and observation slots (``ids``, ``z [..., dz]``, ``mask``) of
    ``config.obs_model`` (range and bearing: :func:`jaxnav.models.landmarks.check_filter_inputs`)."""
    model = config.obs_model
    if model is om.RANGE_BEARING:
        lm.check_filter_inputs(config, params, controls, obs, time_axis)
        return
    motion.validate_controls("controls" if time_axis else "control", controls, config.motion_model, time_axis)
    if not all(hasattr(obs, field) for field in ("ids", "z", "mask")):
        raise ValueError(f"observations must have the fields ids, z and mask, got {type(obs).__name__}")
    lm.validate_observations(obs, time_axis, np.shape(params.landmarks)[0], model.obs_dim)
    if time_axis and np.shape(obs.ids)[0] != np.shape(controls)[0]:
        raise ValueError(
            f"controls and observations must have the same number of steps, got "
            f"{np.shape(controls)[0]} and {np.shape(obs.ids)[0]}"
        )


def inputs_in_domain(config: Any, params: KalmanParams, control: jax.Array, obs: Any) -> jax.Array:
    """``bool[]``, traceable: the control and motion noise in the motion model's domain and the sensor
    parameters in the observation model's (:func:`jaxnav.models.observation.noise_in_domain`)."""
    del obs
    return (
        motion.controls_in_domain(control, config.motion_model)
        & motion.noise_in_domain(config.motion_model, params.motion)
        & om.noise_in_domain(config.obs_model, params.sensor)
    )


def validate_state(state: KalmanState) -> None:
    """Shapes, finiteness and positive definiteness of a Gaussian pose state."""
    if not isinstance(state, KalmanState):
        raise ValueError(f"state must be a KalmanState, got {type(state).__name__}")
    check_shape("state.mean", state.mean, (3,))
    check_magnitude("state.mean", state.mean)
    check_covariance("state.cov", state.cov, 3)


def init(
    key: jax.Array | None, config: Any, params: KalmanParams, initial_pose: jax.Array, initial_cov: jax.Array
) -> KalmanState:
    """The Gaussian prior ``N(initial_pose, initial_cov)``.

    Args:
        key: ignored (the filter is deterministic): ``None`` or one PRNG key; a raw key of another
            length or a batch of keys raises ``ValueError`` naming it.
        initial_pose: ``[3]`` (m, m, rad).
        initial_cov: ``[3, 3]`` symmetric positive definite (m², rad²); a
            non-positive-definite matrix raises ``ValueError``.
    """
    filter_api.check_key(key, allow_none=True)
    validate_params(config, params)
    mean = jnp.asarray(initial_pose, jnp.result_type(float))
    state = KalmanState(mean, jnp.asarray(initial_cov, mean.dtype))
    validate_state(state)
    return state


# ---------------------------------------------------------------------------
# step and run


def kalman_step(
    state: KalmanState,
    params: KalmanParams,
    control: jax.Array,
    obs: Any,
    motion_model: str,
    predict: Callable[..., tuple[kalman.Gaussian, jax.Array]],
    update: Callable[..., kalman.UpdateResult],
    obs_model: om.ObservationModel = om.RANGE_BEARING,
) -> tuple[KalmanState, KalmanInfo]:
    """One Gaussian localization step; ``predict``/``update`` choose EKF or UKF, ``obs_model`` the
    measurement (its ``bias`` subtracted from ``z`` first)."""
    model = get_motion_model(motion_model)
    q = model.process_cov(state.mean, control, params.motion)
    prior, failed_predict = predict(state.mean, state.cov, lambda x: model.mean(x, control), q)
    positions, valid, num_ignored = lm.lookup(params.landmarks, obs)
    r = obs_model.noise_cov(params.sensor)
    z = om.unbiased_measurements(obs_model, obs.z, params.sensor)
    res = update(prior.mean, prior.cov, z, obs_model.mean, r, positions, valid=valid)
    num_gated = jnp.sum(valid & ~res.accepted).astype(jnp.int32)
    new, degenerate = kalman.finite_or_previous(KalmanState(res.mean, res.cov), state)
    info = KalmanInfo(
        new.mean,
        new.cov,
        jnp.where(degenerate, 0.0, res.nis),
        res.accepted & ~degenerate,
        jnp.where(degenerate, -jnp.inf, res.log_likelihood),
        num_ignored,
        num_gated,
        failed_predict | res.cholesky_failed,
        degenerate,
    )
    return new, info


def _ekf_predict(mean, cov, f, q):
    return kalman.ekf_predict(mean, cov, f, q), jnp.zeros((), bool)


@filter_api.guard_inputs(inputs_in_domain)
def kernel(
    key: jax.Array | None,
    state: KalmanState,
    config: EKFConfig,
    params: KalmanParams,
    control: jax.Array,
    obs: Any,
) -> tuple[KalmanState, KalmanInfo]:
    """One EKF step, pure and traceable (:func:`step` is it validated and jitted); the key is not used."""
    update = partial(
        kalman.ekf_update_sequential,
        gate=config.gate,
        state_angle_dims=STATE_ANGLE_DIMS,
        obs_angle_dims=config.obs_model.angle_dims,
    )
    return kalman_step(state, params, control, obs, config.motion_model, _ekf_predict, update, config.obs_model)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="EKF",
        kernel=kernel,
        config_type=EKFConfig,
        state_type=KalmanState,
        check_params=validate_params,
        check_state=lambda config, params, state: validate_state(state),
        check_inputs=check_inputs,
        valid_inputs=inputs_in_domain,
        time_inputs=("controls", "observations"),
        deterministic=True,
        step_doc="""One EKF localization step ([A] Alg. 1): prediction with ``control [control_dim]``, then one update per
        valid observation slot of ``config.obs_model``. Deterministic: ``key`` is not used (``None`` is accepted).""",
        run_doc="""The EKF over a sequence: ``controls [T, control_dim]`` and observations with leading axis ``T``;
        ``trace.estimate`` is ``[T, 3]``. Deterministic: ``key`` is not used (``None`` is accepted).""",
    ),
    __name__,
)
