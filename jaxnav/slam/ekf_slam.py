"""EKF-SLAM with known correspondences, [A] Alg. 4 (Thrun et al. Tab. 10.1).

**Overview**

One Gaussian over the joint state ``[x, y, θ, m₁ₓ, m₁ᵧ, …, m_Mₓ, m_Mᵧ]``
([A] eq. 2.1) of a fixed capacity of ``M = config.num_landmarks`` landmark
slots, with a ``seen [M]`` mask. Observation ids are slot indices (known data
association; in simulation the landmark id *is* the slot). Each step:

1. **Predict** ([A] Alg. 4 lines 1–2; Thrun Tab. 10.1 lines 2–5): the pose
   moves by the motion model's mean ``g(u, x)``; with ``G = ∂g/∂x`` from
   ``jax.jacfwd`` and ``Q`` the model's linearised process noise
   (:func:`jaxnav.models.motion.get_motion_model` ``.process_cov``),
   ``Σ_xx ← G Σ_xx Gᵀ + Q`` and ``Σ_xm ← G Σ_xm``. The map block is not
   touched: ``O(M)`` work, not the ``O(M³)`` of a dense ``G Σ Gᵀ``.
2. **Correct** with the step's ``K`` observation slots one after another
   (lines 3–11; a ``lax.scan``, so several observations of one landmark in
   one step, or a landmark first seen and re-observed in the same step, are
   handled exactly like observations in consecutive steps without motion):

   * a slot whose landmark has **never been seen** initialises it (line 6)
     by the inverse observation model ``m = h⁻¹(x, z)``
     (:func:`jaxnav.models.landmarks.inverse`) linearised by ``jax.jacfwd``
     (``J_x = ∂h⁻¹/∂x``, ``J_z = ∂h⁻¹/∂z``)::

         Σ_mm = J_x Σ_xx J_xᵀ + J_z R J_zᵀ,    Σ_m· = J_x Σ_x·

     (the cross covariance with the pose *and* every landmark already in
     the map), and marks the slot seen;
   * a slot whose landmark **is in the map** is fused by an EKF update of
     the *whole* joint state (lines 8–10): ``ẑ = h(x, m_j)``
     (:func:`jaxnav.models.landmarks.predict`), ``H`` by ``jax.jacfwd`` of
     ``h`` with respect to the five entries it depends on (pose and
     ``m_j``, gathered from the state), ``S = H Σ Hᵀ + R``,
     ``K = Σ Hᵀ S⁻¹``, bearing residual wrapped, and the covariance in
     Joseph form ``(I − KH) Σ (I − KH)ᵀ + K R Kᵀ`` — evaluated from the
     gathered columns ``Σ Hᵀ = Σ[:, idx] H₅ᵀ`` in ``O(n²)`` instead of the
     ``O(n³)`` dense products, but the full joint update all the same;
   * a masked slot, or one whose id lies outside ``[0, M)``, is skipped;
     the latter are counted in ``info.num_ignored``.

Optional Mahalanobis gating (``config.gate_probability``) as in
:mod:`jaxnav.localization.ekf`: an update whose NIS exceeds the χ²₂
quantile is rejected and counted in ``info.num_gated``. A landmark's
initialising observation cannot be gated (there is nothing to compare it
with) and is counted in ``info.num_new``.

Unseen slots hold mean 0, a placeholder variance :data:`UNSEEN_VARIANCE`
(m²) on their diagonal block and zero cross covariances. They influence
nothing: prediction only touches the pose rows and columns, and an update's
gain ``K = Σ Hᵀ S⁻¹`` has exact zero rows for them, so their entries stay
as they are until the first sighting overwrites them.

Choices where the thesis and Thrun et al. differ or are silent:

* Fixed capacity instead of "increase size of μ̂, Σ̂" ([A] Alg. 4 line 6):
  shapes never depend on data, so a new landmark never causes a retrace.
* Initialisation from the inverse model with its linearised covariance,
  and the initialising observation is *not* fused a second time. Thrun
  Tab. 10.1 lines 9–10 set the mean the same way but keep an infinite prior
  covariance and then run the ordinary update with the same observation;
  in the limit this is the same posterior, but an "infinite" variance in
  float32 destroys the other entries' precision.
* The prior must be positive definite: [A] starts from a zero covariance
  (the origin of the map frame is the start pose); pass a tiny one
  (e.g. ``1e-8·I``) for that convention.
* ``info.log_likelihood`` sums ``log N(y; 0, S)`` over fused observations
  (the prediction-error decomposition); initialising observations have no
  predictive density under the model and contribute 0.

Interface (deterministic: no key; as :mod:`jaxnav.localization.ekf`)::

    state = ekf_slam.init(config, params, initial_pose, initial_cov)
    state, info = ekf_slam.step(state, config, params, control, observation)
    final_state, trace = ekf_slam.run(config, params, controls, observations, state)

Cost per step ``O(n·K + n²·K_used)`` for ``n = 3 + 2M`` state entries and
``K_used`` slots that initialise or update (a ``lax.switch`` skips empty
slots; under ``vmap`` the branches become selects and every slot costs
``O(n²)``). Memory ``O(n²)``, inherent to EKF-SLAM.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.core import kalman, memory
from jaxnav.core.validation import (
    check_covariance,
    check_finite,
    check_magnitude,
    check_positive_int,
    check_shape,
)
from jaxnav.core.weights import wrap_angle
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import check_motion_model, get_motion_model
from jaxnav.models.motion import validate_noise as validate_motion_noise

__all__ = [
    "EKFSLAMConfig",
    "EKFSLAMParams",
    "EKFSLAMState",
    "EKFSLAMInfo",
    "UNSEEN_VARIANCE",
    "init",
    "kernel",
    "step",
    "run",
]

POSE_DIM = 3
UNSEEN_VARIANCE = 100.0
"""The placeholder variance (m²) of an unseen landmark slot (never read by the filter)."""

_SKIP, _INITIALISE, _UPDATE = 0, 1, 2


@dataclass(frozen=True)
class EKFSLAMConfig:
    """Static configuration (hashable; a static argument of ``jit``).

    Attributes:
        num_landmarks: M, the capacity of the map (landmark slots); the state
            has ``3 + 2M`` entries.
        motion_model: name in :data:`jaxnav.models.motion.MODELS`.
        gate_probability: if set (e.g. 0.999), reject updates whose NIS exceeds
            the χ²₂ quantile of that probability; None disables gating.
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_landmarks",)
    num_landmarks: int = 8
    motion_model: str = "velocity"
    gate_probability: float | None = None

    def __post_init__(self) -> None:
        check_positive_int("num_landmarks", self.num_landmarks)
        check_motion_model("motion_model", self.motion_model)
        if self.gate_probability is not None:
            kalman.chi2_gate(self.gate_probability, 2)  # raises a ValueError naming the problem

    @property
    def state_dim(self) -> int:
        """``n = 3 + 2M``."""
        return POSE_DIM + 2 * self.num_landmarks

    @property
    def gate(self) -> float | None:
        """The NIS threshold (χ²₂ quantile), or None."""
        return None if self.gate_probability is None else kalman.chi2_gate(self.gate_probability, 2)


class EKFSLAMParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: noise of the configured motion model (e.g. ``VelocityNoise``).
        sensor: range-bearing noise ``(σ_r [m], σ_φ [rad])``.
    """

    motion: Any
    sensor: lm.RangeBearingNoise


class EKFSLAMState(NamedTuple):
    """The joint Gaussian.

    Attributes:
        mean: ``[3 + 2M]`` pose (m, m, rad) then landmark positions (m).
        cov: ``[3 + 2M, 3 + 2M]`` joint covariance.
        seen: ``[M]`` bool, the slot holds an initialised landmark.
    """

    mean: jax.Array
    cov: jax.Array
    seen: jax.Array


class EKFSLAMInfo(NamedTuple):
    """Per-step diagnostics (stacked over time by :func:`run`).

    Attributes:
        estimate: ``[3]`` posterior pose mean.
        pose_cov: ``[3, 3]`` its covariance.
        landmarks: ``[M, 2]`` landmark means (0 where unseen).
        landmark_cov: ``[M, 2, 2]`` landmark marginal covariances
            (``UNSEEN_VARIANCE·I`` where unseen).
        seen: ``[M]`` bool.
        nis: ``[K]`` NIS of each slot's update (0 where the slot did not update).
        accepted: ``[K]`` bool, the slot was fused (in the map and passed the gate).
        log_likelihood: ``Σ log N(y; 0, S)`` over fused slots.
        num_ignored: slots whose id is outside ``[0, M)``.
        num_gated: updates rejected by the gate.
        num_new: landmarks initialised in this step.
        degenerate: bool, the step's result was not finite and was not applied: the state is carried
            over unchanged (:func:`jaxnav.core.kalman.finite_or_previous`).
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    estimate: jax.Array
    pose_cov: jax.Array
    landmarks: jax.Array
    landmark_cov: jax.Array
    seen: jax.Array
    nis: jax.Array
    accepted: jax.Array
    log_likelihood: jax.Array
    num_ignored: jax.Array
    num_gated: jax.Array
    num_new: jax.Array
    degenerate: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# host-side validation


def validate_params(config: EKFSLAMConfig, params: EKFSLAMParams) -> None:
    """Host-side checks of :class:`EKFSLAMParams` against ``config.motion_model``."""
    if not isinstance(config, EKFSLAMConfig):
        raise ValueError(f"config must be an EKFSLAMConfig, got {type(config).__name__}")
    if not isinstance(params, EKFSLAMParams):
        raise ValueError(f"params must be an EKFSLAMParams, got {type(params).__name__}")
    validate_motion_noise(config.motion_model, params.motion)
    lm.validate_noise(params.sensor)


def validate_state(config: EKFSLAMConfig, params: Any, state: EKFSLAMState) -> None:
    """Shapes, finiteness and positive definiteness of a joint state."""
    if not isinstance(state, EKFSLAMState):
        raise ValueError(f"state must be an EKFSLAMState, got {type(state).__name__}")
    n = config.state_dim
    check_shape("state.mean", state.mean, (n,))
    check_magnitude("state.mean", state.mean)
    check_covariance("state.cov", state.cov, n)
    check_shape("state.seen", state.seen, (config.num_landmarks,))
    if jnp.result_type(state.seen) != jnp.bool_:
        raise ValueError(f"state.seen must be bool, got {jnp.result_type(state.seen)}")


def _landmark_prior(config: EKFSLAMConfig, landmarks, landmark_cov, known, dtype):
    """Means ``[M, 2]``, covariance blocks ``[M, 2, 2]`` and seen mask of the map prior."""
    m = config.num_landmarks
    placeholder = jnp.broadcast_to(UNSEEN_VARIANCE * jnp.eye(2, dtype=dtype), (m, 2, 2))
    if landmarks is None:
        if landmark_cov is not None or known is not None:
            raise ValueError("landmark_cov and known need landmarks")
        return jnp.zeros((m, 2), dtype), placeholder, jnp.zeros((m,), bool)
    check_shape("landmarks", landmarks, (m, 2))
    check_magnitude("landmarks", landmarks)
    if landmark_cov is None:
        raise ValueError("landmarks need landmark_cov ([2, 2] or [M, 2, 2])")
    blocks = jnp.asarray(landmark_cov, dtype)
    if blocks.shape == (2, 2):
        blocks = jnp.broadcast_to(blocks, (m, 2, 2))
    check_shape("landmark_cov", blocks, (m, 2, 2))
    known = jnp.ones((m,), bool) if known is None else jnp.asarray(known)
    check_shape("known", known, (m,))
    if known.dtype != jnp.bool_:
        raise ValueError(f"known must be bool, got {known.dtype}")
    for i in np.flatnonzero(np.asarray(known)):
        check_covariance(f"landmark_cov[{i}]", blocks[i], 2)
    means = jnp.where(known[:, None], jnp.asarray(landmarks, dtype), 0.0)
    return means, jnp.where(known[:, None, None], blocks, placeholder), known


@memory.guard_init
def init(
    key: jax.Array | None,
    config: EKFSLAMConfig,
    params: EKFSLAMParams,
    initial_pose: jax.Array,
    initial_cov: jax.Array,
    landmarks: jax.Array | None = None,
    landmark_cov: jax.Array | None = None,
    known: jax.Array | None = None,
) -> EKFSLAMState:
    """The prior: the pose ``N(initial_pose, initial_cov)`` and an empty map.

    Args:
        initial_pose: ``[3]`` (m, m, rad).
        initial_cov: ``[3, 3]`` symmetric positive definite (m², rad²); a
            non-positive-definite matrix raises ``ValueError``.
        landmarks: optional ``[M, 2]`` prior landmark positions (m), e.g. a
            surveyed map; such slots start seen, independent of the pose.
        landmark_cov: their covariance, ``[2, 2]`` for all or ``[M, 2, 2]``
            (m²); required with ``landmarks``.
        known: optional ``[M]`` bool, which of ``landmarks`` are known
            (default all); the others start unseen.
    """
    filter_api.check_key(key, allow_none=True)
    validate_params(config, params)
    dtype = jnp.result_type(float)
    check_shape("initial_pose", initial_pose, (POSE_DIM,))
    check_finite("initial_pose", initial_pose)
    check_covariance("initial_cov", initial_cov, POSE_DIM)
    means, blocks, seen = _landmark_prior(config, landmarks, landmark_cov, known, dtype)
    m = config.num_landmarks
    map_cov = jnp.einsum("ij,iab->iajb", jnp.eye(m, dtype=dtype), blocks).reshape(2 * m, 2 * m)
    n = config.state_dim
    cov = jnp.zeros((n, n), dtype)
    cov = cov.at[:POSE_DIM, :POSE_DIM].set(jnp.asarray(initial_cov, dtype))
    cov = cov.at[POSE_DIM:, POSE_DIM:].set(map_cov)
    mean = jnp.concatenate([jnp.asarray(initial_pose, dtype), means.reshape(-1)])
    mean = mean.at[2].set(wrap_angle(mean[2]))
    state = EKFSLAMState(mean, kalman.symmetrize(cov), seen)
    validate_state(config, params, state)
    return state


# ---------------------------------------------------------------------------
# the filter


def _predict(mean: jax.Array, cov: jax.Array, model, control: jax.Array, motion_params) -> tuple[jax.Array, jax.Array]:
    """Pose-block prediction: ``Σ ← A Σ Aᵀ + Fₓᵀ Q Fₓ`` with ``A = diag(G, I)``, in ``O(n)``."""
    pose = mean[:POSE_DIM]
    f = lambda x: model.mean(x, control)  # noqa: E731
    g = jax.jacfwd(f)(pose)
    q = model.process_cov(pose, control, motion_params)
    mean = mean.at[:POSE_DIM].set(f(pose))
    cov = cov.at[:POSE_DIM, :].set(g @ cov[:POSE_DIM, :])  # rows of A Σ
    cov = cov.at[:, :POSE_DIM].set(cov[:, :POSE_DIM] @ g.T)  # columns of (A Σ) Aᵀ
    cov = cov.at[:POSE_DIM, :POSE_DIM].add(q)
    return mean, kalman.ensure_pd(cov)


def _slot_indices(j: jax.Array) -> jax.Array:
    """State indices ``[x, y, θ, m_jx, m_jy]`` that landmark ``j``'s observation depends on."""
    base = POSE_DIM + 2 * j
    return jnp.stack([jnp.int32(0), jnp.int32(1), jnp.int32(2), base, base + 1]).astype(jnp.int32)


def _observe(x5: jax.Array) -> jax.Array:
    return lm.predict(x5[:POSE_DIM], x5[POSE_DIM:])


def _update(mean, cov, j, z, r):
    """EKF update of the joint state with one observation of landmark ``j`` (Joseph form, sparse ``H``).

    Returns the posterior mean and covariance, the NIS and ``log N(y; 0, S)``.
    """
    idx = _slot_indices(j)
    x5 = mean[idx]
    z_hat = _observe(x5)
    h5 = jax.jacfwd(_observe)(x5)  # [2, 5]
    y = z - z_hat
    y = y.at[1].set(wrap_angle(y[1]))
    c = cov[:, idx] @ h5.T  # Σ Hᵀ, [n, 2]
    s = kalman.symmetrize(h5 @ c[idx] + r)
    log_lik, nis = kalman.gaussian_log_pdf(y, s)
    k = jnp.linalg.solve(s, c.T).T  # [n, 2]
    new_mean = mean + k @ y
    new_mean = new_mean.at[2].set(wrap_angle(new_mean[2]))
    b = cov - k @ c.T  # (I − KH) Σ
    new_cov = kalman.ensure_pd(b - (b[:, idx] @ h5.T) @ k.T + k @ r @ k.T)  # … (I − KH)ᵀ + K R Kᵀ
    return new_mean, new_cov, nis, log_lik


def _initialise(mean, cov, j, z, r):
    """Insert landmark ``j`` from ``z`` by the linearised inverse observation model."""
    pose = mean[:POSE_DIM]
    jx, jz = jax.jacfwd(lm.inverse, argnums=(0, 1))(pose, z)  # [2, 3], [2, 2]
    cross = jx @ cov[:POSE_DIM, :]  # cov(m_j, whole state), [2, n]
    block = kalman.symmetrize(jx @ cov[:POSE_DIM, :POSE_DIM] @ jx.T + jz @ r @ jz.T)
    base = POSE_DIM + 2 * j
    mean = jax.lax.dynamic_update_slice(mean, lm.inverse(pose, z), (base,))
    zero = jnp.zeros_like(base)
    cov = jax.lax.dynamic_update_slice(cov, cross, (base, zero))
    cov = jax.lax.dynamic_update_slice(cov, cross.T, (zero, base))
    cov = jax.lax.dynamic_update_slice(cov, block, (base, base))
    return mean, kalman.ensure_pd(cov)


def _correct(mean, cov, seen, obs: lm.RangeBearingObs, r, gate):
    """Fuse the ``K`` slots in turn; returns the posterior and per-slot diagnostics."""
    m = seen.shape[0]
    _, valid, num_ignored = lm.lookup(mean[POSE_DIM:].reshape(m, 2), obs)
    zero = jnp.zeros((), mean.dtype)

    def body(carry, slot):
        mean, cov, seen = carry
        j, z, ok = slot
        j = jnp.clip(j, 0, m - 1).astype(jnp.int32)
        was_seen = seen[j]
        branch = jnp.where(ok, jnp.where(was_seen, _UPDATE, _INITIALISE), _SKIP)
        # Inputs of branches that are not taken stay finite (vmap turns the switch into a select).
        z = jnp.where(ok, z, jnp.asarray([1.0, 0.0], mean.dtype))

        def skip(mean, cov):
            return mean, cov, zero, zero, jnp.asarray(False)

        def initialise(mean, cov):
            return (*_initialise(mean, cov, j, z, r), zero, zero, jnp.asarray(False))

        def update(mean, cov):
            # a dummy landmark 1 m from the pose keeps h differentiable where the slot is unused
            base = POSE_DIM + 2 * j
            dummy = mean[:2] + jnp.asarray([1.0, 0.0], mean.dtype)
            lmk = jnp.where(was_seen, jax.lax.dynamic_slice(mean, (base,), (2,)), dummy)
            safe = jax.lax.dynamic_update_slice(mean, lmk, (base,))
            new_mean, new_cov, nis, ll = _update(safe, cov, j, z, r)
            passed = was_seen if gate is None else was_seen & (nis <= gate)
            return jnp.where(passed, new_mean, mean), jnp.where(passed, new_cov, cov), nis, ll, passed

        mean, cov, nis, ll, passed = jax.lax.switch(branch, (skip, initialise, update), mean, cov)
        is_update = branch == _UPDATE
        accepted = is_update & passed
        seen = seen.at[j].set(was_seen | (branch == _INITIALISE))
        out = (
            jnp.where(is_update, nis, zero),
            jnp.where(accepted, ll, zero),
            accepted,
            is_update & ~passed,
            branch == _INITIALISE,
        )
        return (mean, cov, seen), out

    (mean, cov, seen), (nis, ll, accepted, gated, new) = jax.lax.scan(body, (mean, cov, seen), (obs.ids, obs.z, valid))
    counts = (num_ignored, jnp.sum(gated).astype(jnp.int32), jnp.sum(new).astype(jnp.int32))
    return mean, cov, seen, nis, jnp.sum(ll), accepted, counts


@filter_api.guard_inputs(lm.filter_inputs_in_domain)
def kernel(
    key: jax.Array | None,
    state: EKFSLAMState,
    config: EKFSLAMConfig,
    params: EKFSLAMParams,
    control: jax.Array,
    obs: lm.RangeBearingObs,
) -> tuple[EKFSLAMState, EKFSLAMInfo]:
    """One EKF-SLAM step, pure and traceable (:func:`step` is it validated and jitted); the key is not used."""
    model = get_motion_model(config.motion_model)
    mean, cov = _predict(state.mean, state.cov, model, control, params.motion)
    r = jnp.diag(params.sensor.sd**2).astype(mean.dtype)
    mean, cov, seen, nis, ll, accepted, (num_ignored, num_gated, num_new) = _correct(
        mean, cov, state.seen, obs, r, config.gate
    )
    (mean, cov), degenerate = kalman.finite_or_previous((mean, cov), (state.mean, state.cov))
    seen = jnp.where(degenerate, state.seen, seen)
    m = config.num_landmarks
    map_blocks = cov[POSE_DIM:, POSE_DIM:].reshape(m, 2, m, 2)
    ar = jnp.arange(m)
    info = EKFSLAMInfo(
        estimate=mean[:POSE_DIM],
        pose_cov=cov[:POSE_DIM, :POSE_DIM],
        landmarks=mean[POSE_DIM:].reshape(m, 2),
        landmark_cov=map_blocks[ar, :, ar, :],
        seen=seen,
        accepted=accepted & ~degenerate,
        nis=jnp.where(degenerate, 0.0, nis),
        log_likelihood=jnp.where(degenerate, -jnp.inf, ll),
        num_ignored=num_ignored,
        num_gated=num_gated,
        num_new=jnp.where(degenerate, 0, num_new),
        degenerate=degenerate,
    )
    return EKFSLAMState(mean, cov, seen), info


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="EKF-SLAM",
        kernel=kernel,
        config_type=EKFSLAMConfig,
        state_type=EKFSLAMState,
        check_params=validate_params,
        check_state=validate_state,
        check_inputs=lm.check_filter_inputs,
        valid_inputs=lm.filter_inputs_in_domain,
        time_inputs=("controls", "observations"),
        deterministic=True,
        step_doc="""One EKF-SLAM step ([A] Alg. 4). Deterministic: ``key`` is not used (``None`` is accepted).""",
        run_doc="""EKF-SLAM over a sequence: ``trace.estimate`` is ``[T, 3]``, ``trace.landmarks`` ``[T, M, 2]``.
        Deterministic: ``key`` is not used (``None`` is accepted).""",
    ),
    __name__,
)
