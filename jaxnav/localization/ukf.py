"""UKF localization with a known landmark map ([A] §2.1.1; Thrun et al. Tab. 7.4).

The same filter as :mod:`jaxnav.localization.ekf` with the linearisations
replaced by the scaled unscented transform (:mod:`jaxnav.core.kalman`):
``2n + 1 = 7`` sigma points of the pose are moved through the motion model's
mean and then through the observation model (``config.observation_model``, range and bearing by
default) for each observation in turn.
The process noise is the motion model's linearised covariance, added after
the transform (Thrun's Tab. 7.4 augments the state with the control noise
instead; for the small control noises of indoor robots the two agree to
first order and the additive form keeps one code path for every model).

A failed Cholesky factorisation (a covariance that lost positive
definiteness) falls back to the diagonal and is flagged in
``info.cholesky_failed``; no NaN is produced.

Interface (deterministic: no key), with the parameter, state and info types
of the EKF module::

    state = ukf.init(config, params, initial_pose, initial_cov)
    state, info = ukf.step(state, config, params, control, observation)
    final_state, trace = ukf.run(config, params, controls, observations, state)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any

import jax

from jaxnav.core import filter as filter_api
from jaxnav.core import kalman
from jaxnav.localization import ekf
from jaxnav.localization.ekf import KalmanInfo, KalmanParams, KalmanState
from jaxnav.models import observation as om

__all__ = ["UKFConfig", "KalmanParams", "KalmanState", "KalmanInfo", "init", "kernel", "step", "run"]


@dataclass(frozen=True)
class UKFConfig:
    """Static configuration.

    Attributes:
        motion_model: name in :data:`jaxnav.models.motion.MODELS` or a motion model.
        gate_probability: χ² gating probability, or None (see :class:`~jaxnav.localization.ekf.EKFConfig`).
        alpha, beta, kappa: scaled sigma-point parameters (van der Merwe);
            the default α = 1, β = 2, κ = 0 puts the points at ±√3 σ.
    """

    motion_model: str = "velocity"
    gate_probability: float | None = None
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    observation_model: str | om.ObservationModel = "range_bearing"

    def __post_init__(self) -> None:
        ekf.check_kalman_config(self)
        if not self.alpha > 0:
            raise ValueError(f"alpha must be > 0, got {self.alpha}")
        kalman.sigma_weights(3, self.alpha, self.beta, self.kappa)  # raises if n + λ ≤ 0

    @property
    def obs_model(self) -> om.ObservationModel:
        """The resolved :class:`~jaxnav.models.observation.ObservationModel`."""
        return om.get_observation_model(self.observation_model)

    @property
    def gate(self) -> float | None:
        """The NIS threshold (χ² quantile of ``dz`` degrees of freedom), or None."""
        return ekf.gate_of(self)


def init(
    key: jax.Array | None, config: UKFConfig, params: KalmanParams, initial_pose: jax.Array, initial_cov: jax.Array
) -> KalmanState:
    """The Gaussian prior ``N(initial_pose, initial_cov)`` (as :func:`jaxnav.localization.ekf.init`)."""
    filter_api.check_key(key, allow_none=True)
    return ekf.init(None, config, params, initial_pose, initial_cov)


@filter_api.guard_inputs(ekf.inputs_in_domain)
def kernel(
    key: jax.Array | None,
    state: KalmanState,
    config: UKFConfig,
    params: KalmanParams,
    control: jax.Array,
    obs: Any,
) -> tuple[KalmanState, KalmanInfo]:
    """One UKF step, pure and traceable (:func:`step` is it validated and jitted); the key is not used."""
    weights = kalman.sigma_weights(3, config.alpha, config.beta, config.kappa, state.mean.dtype)
    predict = partial(kalman.ukf_predict, weights=weights, state_angle_dims=ekf.STATE_ANGLE_DIMS)
    update = partial(
        kalman.ukf_update_sequential,
        gate=config.gate,
        state_angle_dims=ekf.STATE_ANGLE_DIMS,
        obs_angle_dims=config.obs_model.angle_dims,
        weights=weights,
    )
    return ekf.kalman_step(state, params, control, obs, config.motion_model, predict, update, config.obs_model)


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="UKF",
        kernel=kernel,
        config_type=UKFConfig,
        state_type=ekf.KalmanState,
        check_params=ekf.validate_params,
        check_state=lambda config, params, state: ekf.validate_state(state),
        check_inputs=ekf.check_inputs,
        valid_inputs=ekf.inputs_in_domain,
        time_inputs=("controls", "observations"),
        deterministic=True,
        step_doc="""One UKF localization step (unscented prediction and sequential updates). Deterministic: ``key`` is not
        used (``None`` is accepted).""",
        run_doc="""The UKF over a sequence: ``controls [T, control_dim]`` and observations with leading axis ``T``;
        ``trace.estimate`` is ``[T, 3]``. Deterministic: ``key`` is not used (``None`` is accepted).""",
    ),
    __name__,
)
