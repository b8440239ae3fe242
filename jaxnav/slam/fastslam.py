"""FastSLAM 1.0 and 2.0 with known data association, generic over the observation model.

**Overview**

A Rao-Blackwellised particle filter ([A] Alg. 5, [W] eq. 3.2; Montemerlo et
al. 2002/2003; Thrun et al. Tab. 13.1–13.2): each of the ``N`` particles
holds a pose ``(x, y, θ)`` and its own map of ``M`` landmarks, every landmark
a small Gaussian ``(μ [D], Σ [D, D])`` updated by its own EKF.

One step:

1. **Pose.** FastSLAM 1.0 draws the pose from the motion model
   (:mod:`jaxnav.models.motion`). FastSLAM 2.0 draws it from the proposal
   that also uses the step's observations of already-mapped landmarks: an EKF
   update of the predicted pose ``N(g(u, x), Q_t)`` with each observation in
   turn, measurement noise ``R + H_m Σ_j H_mᵀ`` (Montemerlo et al. 2003,
   eqs. 10–11, in Kalman form so that ``Q_t`` need not be inverted), and the
   weight is that update's marginal likelihood ``N(z; ẑ, H_x Q_t H_xᵀ + H_m Σ_j H_mᵀ + R)``
   (their eq. 15, multiplied over observations sequentially).
2. **Landmarks.** The valid observation slots update their landmarks in
   every particle, with the result of applying them one after the other (so
   two observations of one landmark in a step are applied in turn): each an
   EKF update (:func:`jaxnav.core.kalman.ekf_update`, Jacobian by
   ``jax.jacfwd`` of the model's ``mean``, vmapped over particles, or the
   model's closed form), and the rows are scattered back: a step costs
   ``O(N·K)`` and never touches unobserved landmarks. Up to
   ``config.parallel_slots`` first observations of a landmark are updated at
   once; the rest go through a loop. A landmark
   seen for the first time is initialised from the inverse model,
   ``μ = h⁻¹(x, z)``, ``Σ = J R Jᵀ`` with ``J = ∂h⁻¹/∂z`` (Thrun et al.
   Tab. 13.1 lines 9–11); it adds nothing to the weight (the default
   importance ``p₀`` of Tab. 13.1 is the same for every particle under known
   association, so it is left out).
3. **Weights** are multiplied in the log domain (FastSLAM 1.0: the landmark
   EKFs' innovation likelihoods), normalised with logsumexp; a degenerate
   step resets to uniform and is flagged.
4. **Resampling** (conditional on the ESS; every step by default, as [A]
   Alg. 5) copies every chosen particle's *whole map*: ``O(N·M)`` memory
   traffic, the cost of FastSLAM that benchmark W3 measures. Large maps are
   copied in place (every resampling scheme returns sorted ancestors), so a
   jitted ``step`` with donated state moves each map once.

**Observation models**

The observation models are :mod:`jaxnav.models.observation`'s
:class:`~jaxnav.models.observation.ObservationModel` (``mean(pose, landmark) -> z``,
``inverse(pose, z) -> landmark``, ``noise_cov(sensor_params) -> R``, the circular
components of ``z``): ``RANGE_BEARING``, the point landmarks of
:mod:`jaxnav.models.landmarks`, and ``HF_FOOTPRINT``, the HF-RFID reader detection
with its footprint as a Gaussian ([W] §3.2, the FastSLAM baseline of [W] ch. 3–4).
Other sensors plug in by passing their own model as ``config.observation_model``.
Observations are fixed-slot arrays with fields ``ids [K]`` (landmark slot),
``z [K, dz]`` and ``mask [K]`` (e.g. :class:`~jaxnav.models.landmarks.RangeBearingObs`);
masked slots and ids outside ``[0, M)`` are ignored, the latter counted.

Interface::

    state = fastslam.init(key, config, params, initial_pose)
    state, info = fastslam.step(key, state, config, params, control, observation)
    final_state, trace = fastslam.run(key, state, config, params, controls, observations)
    landmarks, seen = fastslam.map_estimate(state)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import fastmath, gradients, kalman, memory, resampling, rng, weights
from jaxnav.core import filter as filter_api
from jaxnav.core.particle_filter import PFInfo, at_least_one_slot, extend_info, finish_step, keep_finite
from jaxnav.core.validation import (
    check_choice,
    check_covariances,
    check_finite,
    check_fraction,
    check_magnitude,
    check_nonnegative,
    check_positive_int,
    check_shape,
    check_slots,
)
from jaxnav.models import landmarks as lm
from jaxnav.models.motion import (
    check_motion_model,
    controls_in_domain,
    get_motion_model,
    noise_in_domain,
    validate_controls,
)
from jaxnav.models.motion import validate_noise as validate_motion_noise
from jaxnav.models.observation import (
    HF_FOOTPRINT,
    OBSERVATION_MODELS,
    RANGE_BEARING,
    ObservationModel,
    spread_quantiles,
    unbiased_measurements,
)

__all__ = [
    "ObservationModel",
    "RANGE_BEARING",
    "HF_FOOTPRINT",
    "OBSERVATION_MODELS",
    "FastSLAMConfig",
    "FastSLAMParams",
    "FastSLAMState",
    "FastSLAMInfo",
    "init",
    "kernel",
    "step",
    "run",
    "map_estimate",
    "update_landmarks",
    "update_landmarks_in_order",
    "SlotUpdates",
    "landmark_ekf",
    "landmark_init",
    "slot_valid",
    "write_rows",
    "run_unroll",
]

_POSE_ANGLE_DIMS = (2,)

DEFAULT_PARALLEL_SLOTS = 2
"""Default ``FastSLAMConfig.parallel_slots``, the first observations of a step updated at once."""

IN_PLACE_MIN_FLOATS = 3072
"""Map size per particle (floats, ``M · (D + D²)``) from which resampling copies maps in place.

Below it ``jnp.take`` is faster than the row-copy loop of
``jaxnav.core.resampling.copy_ancestors_in_place`` (benchmark W3)."""


UNROLL_MIN_FLOATS = 256
"""Map size per particle (floats) from which :func:`run` unrolls two steps per scan iteration
when resampling gathers the maps (:func:`run_unroll`)."""


@dataclass(frozen=True)
class FastSLAMConfig:
    """Static configuration.

    Attributes:
        num_particles: N.
        num_landmarks: M, the map capacity (landmark slots ``0 … M−1``).
        version: 1 (proposal = motion model) or 2 (proposal from the observations).
        motion_model: name in :data:`jaxnav.models.motion.MODELS`.
        observation_model: a name in ``OBSERVATION_MODELS`` or an :class:`~jaxnav.models.observation.ObservationModel`.
        resampling: scheme name in :data:`jaxnav.core.resampling.SCHEMES`.
        ess_threshold: resample when ESS < ``ess_threshold · N``; 1.0 (default) every step.
        map_copy: how resampling copies the maps: "gather" (``jnp.take``), "in_place" (the
            row-copy loop of ``jaxnav.core.resampling.copy_ancestors_in_place``, which needs
            the sorted ancestors that every scheme returns) or "auto" (in place for rows of at least
            ``IN_PLACE_MIN_FLOATS`` = 3072 floats). Use "gather" when the filter runs under ``vmap`` (batch Monte
            Carlo): the loop's trip count then differs between runs, and a batched ``while`` selects
            the whole maps on every iteration.
        parallel_slots: how many of a step's first observations of a landmark are updated at
            once, vectorised (the rest, and second observations of a landmark, go through a loop;
            results are the same either way). Each costs ``N`` EKF updates per step whether
            used or not; a loop iteration under ``vmap`` also selects the slot buffer, while an
            unbatched loop iteration is cheap. About the number of landmarks a step usually
            observes is fastest under ``vmap`` (in Table 3.1's settings: 3 lanes at 100 tags/m²,
            where a step observes 2–3; 1 lane at 16 tags/m², where it observes 0–1).
        covariance: where the landmark covariances live: "per_particle" (``[N, M, D, D]``, each
            particle its own, as in Montemerlo et al.), "shared" (``[M, D, D]``, one per landmark,
            for observation models whose covariance update does not depend on the pose,
            ``ObservationModel.pose_free_covariance``: the particles' covariances are then equal,
            and neither updated ``N`` times nor copied at resampling) or "auto" (shared when the
            model allows it). The filter is the same either way; shared covariances cut the map
            that resampling copies from ``D + D²`` to ``D`` floats per landmark.
        gradient: how ``jax.grad`` of the log-likelihood passes resampling: ``"score"`` (default, the
            forward pass unchanged) or ``"naive"`` (:mod:`jaxnav.core.gradients`); ``"soft"`` is
            refused (its draw could make a particle whose map rows are not finite an ancestor).
        soft_mixing: unused (``"soft"`` is refused).
    """

    # the fields that size the state, named when it is too large (jaxnav.core.memory)
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("num_particles", "num_landmarks")
    num_particles: int = 100
    num_landmarks: int = 16
    version: int = 1
    motion_model: str = "velocity"
    observation_model: str | ObservationModel = "range_bearing"
    resampling: str = "systematic"
    ess_threshold: float = 1.0
    map_copy: str = "auto"
    parallel_slots: int = DEFAULT_PARALLEL_SLOTS
    covariance: str = "auto"
    gradient: str = "score"
    soft_mixing: float = 0.5

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_positive_int("num_landmarks", self.num_landmarks)
        check_choice("version", self.version, (1, 2))
        gradients.check_gradient(self.gradient, self.soft_mixing)
        if self.gradient == "soft":  # its draw may pick a particle whose map rows are not finite
            raise ValueError("gradient 'soft' is not available in FastSLAM; choose 'score' or 'naive'")
        check_motion_model("motion_model", self.motion_model)
        if not isinstance(self.observation_model, ObservationModel):
            check_choice("observation_model", self.observation_model, OBSERVATION_MODELS)
        check_choice("resampling", self.resampling, resampling.SCHEMES)
        check_fraction("ess_threshold", self.ess_threshold)
        check_choice("map_copy", self.map_copy, ("auto", "gather", "in_place"))
        check_positive_int("parallel_slots", self.parallel_slots)
        check_choice("covariance", self.covariance, ("auto", "per_particle", "shared"))
        if self.covariance == "shared" and not self.obs_model.pose_free_covariance:
            raise ValueError(
                f"covariance='shared' needs an observation model whose landmark covariance does not depend "
                f"on the pose (pose_free_covariance=True); {self.obs_model.name!r} is not one"
            )
        if self.map_copy == "in_place" and self.resampling not in resampling.SORTED_SCHEMES:
            raise ValueError(
                f"map_copy='in_place' needs sorted ancestors ({', '.join(resampling.SORTED_SCHEMES)}), "
                f"not resampling={self.resampling!r}"
            )

    @property
    def obs_model(self) -> ObservationModel:
        """The resolved :class:`~jaxnav.models.observation.ObservationModel`."""
        om = self.observation_model
        return om if isinstance(om, ObservationModel) else OBSERVATION_MODELS[om]

    @property
    def shared_covariance(self) -> bool:
        """Whether the state holds one covariance per landmark (``covs [M, D, D]``)."""
        return self.covariance == "shared" or (self.covariance == "auto" and self.obs_model.pose_free_covariance)

    @property
    def map_floats(self) -> int:
        """Floats per particle that resampling copies, ``M · D`` plus ``M · D²`` for per-particle covariances."""
        d = self.obs_model.landmark_dim
        return self.num_landmarks * (d if self.shared_covariance else d + d * d)


class FastSLAMParams(NamedTuple):
    """Differentiable parameters.

    Attributes:
        motion: noise of the configured motion model.
        sensor: parameters of the observation model's noise (e.g. ``RangeBearingNoise``).
    """

    motion: Any
    sensor: Any


class FastSLAMState(NamedTuple):
    """Particles and their maps.

    Attributes:
        poses: ``[N, 3]`` (m, m, rad).
        log_weights: ``[N]`` normalised.
        means: ``[N, M, D]`` landmark means per particle (m).
        covs: ``[N, M, D, D]`` landmark covariances per particle (m²), or ``[M, D, D]`` shared by
            the particles (``config.shared_covariance``).
        seen: ``[M]`` bool, the landmark has been initialised (shared by all
            particles: with known association they all see it at the same step).
    """

    poses: jax.Array
    log_weights: jax.Array
    means: jax.Array
    covs: jax.Array
    seen: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class FastSLAMInfo(PFInfo):
    """Per-step diagnostics.

    Attributes:
        estimate: ``[3]`` weighted mean pose (circular θ) before resampling.
        ess: effective sample size before resampling.
        resampled: bool.
        log_likelihood: the step's log marginal-likelihood increment estimate.
        degenerate: bool, all weights were zero and were reset.
        num_ignored: valid slots whose id is outside ``[0, M)``.
        num_new: landmarks initialised this step.
        invalid_inputs: bool, the step's control or parameters were outside the models' domain (a
            negative Δt or noise level, a value that is not finite or exceeds
            :data:`~jaxnav.core.validation.MAX_MAGNITUDE`), refused on the host, so only inside a
            caller's ``jit``: the state was carried over unchanged.
    """

    num_ignored: jax.Array
    num_new: jax.Array
    invalid_inputs: jax.Array = False


# ---------------------------------------------------------------------------
# validation


def _validate_params(config: FastSLAMConfig, params: FastSLAMParams) -> None:
    if not isinstance(params, FastSLAMParams):
        raise ValueError(f"params must be a FastSLAMParams, got {type(params).__name__}")
    validate_motion_noise(config.motion_model, params.motion)
    config.obs_model.validate(params.sensor)


def _validate_state(config: FastSLAMConfig, params: Any, state: FastSLAMState) -> None:
    n, m, d = config.num_particles, config.num_landmarks, config.obs_model.landmark_dim
    check_shape("state.poses", state.poses, (n, 3))
    check_shape("state.log_weights", state.log_weights, (n,))
    check_shape("state.means", state.means, (n, m, d))
    check_shape("state.covs", state.covs, ((m,) if config.shared_covariance else (n, m)) + (d, d))
    check_shape("state.seen", state.seen, (m,))


def _validate_inputs(
    config: FastSLAMConfig, params: FastSLAMParams, controls: jax.Array, obs: Any, time_axis: bool
) -> None:
    name = "controls" if time_axis else "control"
    validate_controls(name, controls, config.motion_model, time_axis)
    for field in ("ids", "z", "mask"):
        if not hasattr(obs, field):
            raise ValueError(f"observations must have fields ids, z and mask (e.g. RangeBearingObs); missing {field!r}")
    lead = (None, None) if time_axis else (None,)
    check_shape("observations.ids", obs.ids, lead)
    check_shape("observations.mask", obs.mask, lead)
    check_shape("observations.z", obs.z, lead + (config.obs_model.obs_dim,))
    if np.shape(obs.ids) != np.shape(obs.mask) or np.shape(obs.z)[:-1] != np.shape(obs.ids):
        raise ValueError(
            f"observations.ids, .mask and .z must agree in leading shape, got "
            f"{np.shape(obs.ids)}, {np.shape(obs.mask)}, {np.shape(obs.z)}"
        )
    check_slots("observations", obs.ids, obs.mask, obs.z, num_ids=config.num_landmarks)
    if time_axis and np.shape(obs.ids)[0] != np.shape(controls)[0]:
        raise ValueError(
            f"controls and observations must have the same number of steps, got "
            f"{np.shape(controls)[0]} and {np.shape(obs.ids)[0]}"
        )


# ---------------------------------------------------------------------------
# init


@memory.guard_init
def init(
    key: jax.Array,
    config: FastSLAMConfig,
    params: FastSLAMParams,
    initial_pose: jax.Array,
    initial_sd: jax.Array | None = None,
    landmark_means: jax.Array | None = None,
    landmark_covs: jax.Array | None = None,
) -> FastSLAMState:
    """Particles at ``N(initial_pose, diag(initial_sd²))`` with empty maps, or a given prior map.

    Args:
        initial_pose: ``[3]``; SLAM fixes the frame by the initial pose, so
            the default ``initial_sd = 0`` starts every particle there.
        landmark_means: optional ``[M, D]`` prior map copied into every
            particle (marks every landmark seen), e.g. for benchmark W3.
        landmark_covs: ``[M, D, D]`` covariances of that prior map (default
            ``1e-2 I`` m²), each symmetric positive definite (else ``ValueError`` naming the
            landmark).
    """
    filter_api.check_key(key)
    _validate_params(config, params)
    n, m, d = config.num_particles, config.num_landmarks, config.obs_model.landmark_dim
    pose = jnp.asarray(initial_pose, jnp.result_type(float))
    check_shape("initial_pose", pose, (3,))
    check_finite("initial_pose", pose)
    sd = jnp.zeros(3, pose.dtype) if initial_sd is None else jnp.asarray(initial_sd, pose.dtype)
    check_shape("initial_sd", sd, (3,))
    check_nonnegative("initial_sd", sd)
    poses = pose + rng.normal(key, (n, 3), pose.dtype) * sd
    poses = poses.at[:, 2].set(weights.wrap_angle(poses[:, 2]))
    cov_shape = ((m,) if config.shared_covariance else (n, m)) + (d, d)
    if landmark_means is None:
        means = jnp.zeros((n, m, d), pose.dtype)
        covs = jnp.broadcast_to(jnp.eye(d, dtype=pose.dtype), cov_shape)
        seen = jnp.zeros((m,), bool)
    else:
        lm_means = jnp.asarray(landmark_means, pose.dtype)
        check_shape("landmark_means", lm_means, (m, d))
        check_magnitude("landmark_means", lm_means)
        lm_covs = (
            1e-2 * jnp.broadcast_to(jnp.eye(d, dtype=pose.dtype), (m, d, d))
            if landmark_covs is None
            else jnp.asarray(landmark_covs, pose.dtype)
        )
        check_shape("landmark_covs", lm_covs, (m, d, d))
        check_covariances("landmark_covs", lm_covs, d)
        means = jnp.broadcast_to(lm_means, (n, m, d))
        covs = jnp.broadcast_to(lm_covs, cov_shape)
        seen = jnp.ones((m,), bool)
    log_w = jnp.full((n,), -np.log(n), pose.dtype)
    # materialise the broadcasts: the state is updated in place from here on
    return FastSLAMState(poses, log_w, jnp.array(means), jnp.array(covs), seen)


# ---------------------------------------------------------------------------
# step


def slot_valid(obs: Any, m: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(valid [K], safe ids [K], num_ignored)``: masked-in slots (nonzero = set) with an id outside
    ``[0, M)`` or a ``z`` that is not finite or exceeds the magnitude limit
    (:func:`jaxnav.models.landmarks.usable_measurements`) are dropped and counted (the host checks
    refuse the latter for concrete inputs; under a caller's ``jit`` it never reaches a landmark's EKF)."""
    mask = obs.mask.astype(bool)
    usable = (obs.ids >= 0) & (obs.ids < m) & lm.usable_measurements(obs.z)
    valid = mask & usable
    return valid, jnp.clip(obs.ids, 0, m - 1), jnp.sum(mask & ~usable).astype(jnp.int32)


def landmark_ekf(
    om: ObservationModel, r: jax.Array, pose: jax.Array, mean: jax.Array, cov: jax.Array, z: jax.Array
) -> kalman.UpdateResult:
    """EKF update of one landmark ``(mean, cov)`` seen from ``pose`` (Tab. 13.1 lines 13–18)."""
    if om.update is not None:
        return om.update(pose, mean, cov, z, r)
    return kalman.ekf_update(mean, cov, z, lambda mu: om.mean(pose, mu), r, obs_angle_dims=om.angle_dims)


def landmark_init(om: ObservationModel, r: jax.Array, pose: jax.Array, z: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``μ = h⁻¹(x, z)``, ``Σ = J R Jᵀ``, ``J = ∂h⁻¹/∂z`` (Tab. 13.1 lines 9–11)."""
    if om.initialise is not None:
        return om.initialise(pose, z, r)
    jac = jax.jacfwd(lambda zz: om.inverse(pose, zz))(z)
    return om.inverse(pose, z), kalman.ensure_pd(fastmath.matmul(fastmath.matmul(jac, r), jac.T))


def _is_shared(means, covs) -> bool:
    """Whether ``covs`` is one per landmark (``[M, D, D]`` beside ``means [N, M, D]``), shared by the particles."""
    return covs.ndim == means.ndim


def _shared_vmap(om: ObservationModel, fn, in_axes, out_axes):
    """``jax.vmap`` over particles whose shared outputs (``out_axes`` None) must not depend on the
    pose; if they do, the model's ``pose_free_covariance`` is wrong, and the error says so."""
    mapped = jax.vmap(fn, in_axes=in_axes, out_axes=out_axes)

    def call(*args):
        try:
            return mapped(*args)
        except ValueError as e:
            if "out_axes" not in str(e):
                raise
            raise ValueError(
                f"observation model {om.name!r} declares pose_free_covariance=True, but its landmark "
                f"covariance depends on the pose; use covariance='per_particle' or fix the model"
            ) from e

    return call


def _particles_ekf(om: ObservationModel, r: jax.Array, poses, mu, cov, z) -> kalman.UpdateResult:
    """:func:`landmark_ekf` of one landmark in every particle: ``mu [N, D]``, ``cov [N, D, D]`` or,
    shared by the particles, ``[D, D]``; a shared covariance comes out shared."""
    axis = None if cov.ndim == mu.ndim else 0
    ekf = _shared_vmap(
        om,
        lambda p, m_, c_: landmark_ekf(om, r, p, m_, c_, z),
        in_axes=(0, 0, axis),
        out_axes=kalman.UpdateResult(0, axis, 0, 0, 0, 0),
    )
    return ekf(poses, mu, cov)


def _particles_init(
    om: ObservationModel, r: jax.Array, poses, z, shared: bool, landmark: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """:func:`landmark_init` of landmark ``landmark`` in every particle: ``(mean [N, D], cov [N, D, D] or,
    shared, [D, D])``; with ``om.initialise_spread``, particle ``n`` takes its own point of the landmark's
    curve (:func:`jaxnav.models.observation.spread_quantiles`)."""
    if om.initialise_spread is not None:
        n = poses.shape[0]
        u = spread_quantiles(n, landmark)
        return jax.vmap(lambda p, q: om.initialise_spread(p, z, r, q, 1.0 / n))(poses, u)
    init = _shared_vmap(om, lambda p: landmark_init(om, r, p, z), in_axes=0, out_axes=(0, None if shared else 0))
    return init(poses)


def _landmark_rows(covs, j, shared: bool):
    """Landmark ``j``'s covariance in every particle: ``covs[:, j]``, or the shared ``covs[j]``."""
    return covs[j] if shared else covs[:, j]


def _slot_order(valid, ids):
    """``(previous, last)``: for each slot the earlier slot of this step that last observed its
    landmark (−1: none), and the landmark's last slot."""
    slots = jnp.arange(ids.shape[0], dtype=jnp.int32)
    same = valid[:, None] & valid[None, :] & (ids[:, None] == ids[None, :])
    previous = jnp.max(jnp.where(same & (slots[None, :] < slots[:, None]), slots[None, :], -1), axis=1)
    last = jnp.max(jnp.where(same, slots[None, :], -1), axis=1)
    return previous, last


def _finish_slots(valid, ids, last, seen, num_landmarks, buf_mu, buf_cov):
    """Each landmark is written once, from its last slot; the other slots write out of range (dropped)."""
    write = jnp.where(valid & (last == jnp.arange(ids.shape[0])), ids, num_landmarks)
    return SlotUpdates(write, buf_mu, buf_cov), seen.at[write].set(True, mode="drop")


def _apply_slot(om, r, poses, means, covs, seen, obs, ids, previous, k, carry):
    """Apply valid slot ``k`` into the slot buffers ``carry = (mu [K, N, D], cov [K, N, D, D],
    loglik [N], num_new)``: its landmark is read from the maps, or from the buffer of the earlier
    slot of this step that updated it (``previous[k]``), initialised if new, else EKF-updated."""
    buf_mu, buf_cov, loglik, num_new = carry
    shared = _is_shared(means, covs)
    j, z, prev = ids[k], obs.z[k], previous[k]
    from_buf = prev >= 0
    mu_k = jnp.where(from_buf, buf_mu[jnp.maximum(prev, 0)], means[:, j])
    cov_k = jnp.where(from_buf, buf_cov[jnp.maximum(prev, 0)], _landmark_rows(covs, j, shared))
    new = ~seen[j] & ~from_buf

    def update():
        u = _particles_ekf(om, r, poses, mu_k, cov_k, z)
        return u.mean, u.cov, u.log_likelihood

    def init():
        mu, cov = _particles_init(om, r, poses, z, shared, j)
        return mu, cov, jnp.zeros_like(loglik)

    # seen is shared by the particles, so one branch serves them all
    mu, cov, ll = jax.lax.cond(new, init, update)
    return buf_mu.at[k].set(mu), buf_cov.at[k].set(cov), loglik + ll, num_new + new.astype(jnp.int32)


def _empty_slot_buffers(num_slots, means, covs, poses):
    n, d = means.shape[0], means.shape[2]
    per_slot_cov = (d, d) if _is_shared(means, covs) else (n, d, d)
    return (
        jnp.zeros((num_slots, n, d), means.dtype),
        jnp.zeros((num_slots,) + per_slot_cov, covs.dtype),
        jnp.zeros(n, poses.dtype),
        jnp.zeros((), jnp.int32),
    )


def update_landmarks_in_order(
    om: ObservationModel,
    r: jax.Array,
    poses: jax.Array,
    means: jax.Array,
    covs: jax.Array,
    seen: jax.Array,
    obs: Any,
    valid: jax.Array,
    ids: jax.Array,
) -> tuple[SlotUpdates, jax.Array, jax.Array, jax.Array]:
    """``update_landmarks`` as a ``scan`` over all ``K`` slots: its derivative.

    The same sequential updates (``_apply_slot``), slot after slot, with a fixed trip
    count: a loop whose trip count depends on the data cannot be differentiated in reverse
    mode. Under ``vmap`` every slot then costs an update and an initialisation, so it only
    serves derivatives.
    """
    previous, last = _slot_order(valid, ids)

    def body(carry, k):
        apply = partial(_apply_slot, om, r, poses, means, covs, seen, obs, ids, previous, k)
        return jax.lax.cond(valid[k], apply, lambda c: c, carry), None

    carry = _empty_slot_buffers(ids.shape[0], means, covs, poses)
    (buf_mu, buf_cov, loglik, num_new), _ = jax.lax.scan(body, carry, jnp.arange(ids.shape[0]))
    updates, seen = _finish_slots(valid, ids, last, seen, means.shape[1], buf_mu, buf_cov)
    return updates, seen, loglik, num_new


@partial(jax.custom_jvp, nondiff_argnums=(0, 9))
def update_landmarks(
    om: ObservationModel,
    r: jax.Array,
    poses: jax.Array,
    means: jax.Array,
    covs: jax.Array,
    seen: jax.Array,
    obs: Any,
    valid: jax.Array,
    ids: jax.Array,
    lanes: int = DEFAULT_PARALLEL_SLOTS,
) -> tuple[SlotUpdates, jax.Array, jax.Array, jax.Array]:
    """Initialise or EKF-update landmark ``ids[k]`` in every particle, as if slot after slot.

    Slots that are the first of the step to observe their landmark read it from the maps
    and do not depend on each other: up to ``lanes`` of them (in slot order) are updated at
    once, vectorised over slots and particles, with no loop. The others (more such slots
    than ``lanes``, and second observations of a landmark) are applied in slot order by a
    loop whose trip count is their number (usually zero); each reads its landmark from the
    maps, or from the result of the earlier slot of this step that updated it, so a second
    observation updates what the first left (sequential EKF updates, as a scan over the
    slots would). Results go to a small slot-major buffer ``[K, N, D]`` and are written into
    the maps once, from the landmark's last slot. The maps are only read, never carried
    through a loop: under ``vmap`` over runs a loop runs as often as the run that needs the
    most iterations, and selects its whole carry at every iteration.

    Returns the :class:`SlotUpdates` (written after resampling, :func:`write_rows`), the new
    ``seen``, per-particle log-likelihood ``[N]`` of the updates (FastSLAM 1.0's weight) and
    the count of new landmarks. Derivatives, forward and reverse, are those of
    :func:`update_landmarks_in_order` (a custom JVP).
    """
    num_slots = ids.shape[0]
    shared = _is_shared(means, covs)
    previous, last = _slot_order(valid, ids)
    first = valid & (previous < 0)

    # 1. up to `lanes` first observations at once (both branches computed, one kept: cheap next to a loop)
    lane = jnp.argsort(~first, stable=True)[: min(lanes, num_slots)].astype(jnp.int32)
    lane_ok, lane_ids = first[lane], ids[lane]
    lane_new = ~seen[lane_ids]
    z = jnp.where(lane_ok[:, None], obs.z[lane], 0.0)  # masked slots' z are never read
    mu0 = jnp.swapaxes(jnp.take(means, lane_ids, axis=1, mode="clip"), 0, 1)  # [L, N, D]
    if shared:
        cov0 = jnp.take(covs, lane_ids, axis=0, mode="clip")  # [L, D, D]
    else:
        cov0 = jnp.swapaxes(jnp.take(covs, lane_ids, axis=1, mode="clip"), 0, 1)  # [L, N, D, D]
    upd = jax.vmap(lambda zz, mu, c: _particles_ekf(om, r, poses, mu, c, zz))(z, mu0, cov0)
    ini_mu, ini_cov = jax.vmap(lambda zz, j: _particles_init(om, r, poses, zz, shared, j))(z, lane_ids)
    lane_mu = jnp.where(lane_new[:, None, None], ini_mu, upd.mean)
    lane_cov = jnp.where(jnp.expand_dims(lane_new, tuple(range(1, ini_cov.ndim))), ini_cov, upd.cov)
    loglik = jnp.sum(jnp.where((lane_ok & ~lane_new)[:, None], upd.log_likelihood, 0.0), axis=0)
    num_new = jnp.sum(lane_ok & lane_new).astype(jnp.int32)
    to = jnp.where(lane_ok, lane, num_slots)
    buf_mu, buf_cov, _, _ = _empty_slot_buffers(num_slots, means, covs, poses)
    buf_mu, buf_cov = buf_mu.at[to].set(lane_mu, mode="drop"), buf_cov.at[to].set(lane_cov, mode="drop")

    # 2. the other valid slots, in slot order
    rest = valid & ~jnp.zeros(num_slots, bool).at[to].set(True, mode="drop")
    order = jnp.argsort(~rest, stable=True).astype(jnp.int32)

    def body(i, carry):
        return _apply_slot(om, r, poses, means, covs, seen, obs, ids, previous, order[i], carry)

    num_rest = jnp.sum(rest).astype(jnp.int32)
    buf_mu, buf_cov, loglik, num_new = jax.lax.fori_loop(0, num_rest, body, (buf_mu, buf_cov, loglik, num_new))
    updates, seen = _finish_slots(valid, ids, last, seen, means.shape[1], buf_mu, buf_cov)
    return updates, seen, loglik, num_new


@update_landmarks.defjvp
def _update_landmarks_jvp(om, lanes, primals, tangents):
    # The loop above has a data-dependent trip count, which reverse mode cannot transpose:
    # derivatives (forward and reverse) come from the same updates as a fixed-length scan.
    return jax.jvp(partial(update_landmarks_in_order, om), primals, tangents)


class SlotUpdates(NamedTuple):
    """The landmarks a step updated: ``rows_*[k]`` of every particle go to landmark ``write[k]``
    (``write[k] = M``, out of range, for slots that write nothing). ``rows_mu [K, N, D]``;
    ``rows_cov [K, N, D, D]``, or ``[K, D, D]`` for shared covariances."""

    write: jax.Array
    rows_mu: jax.Array
    rows_cov: jax.Array


def write_rows(
    means: jax.Array, covs: jax.Array, upd: SlotUpdates, ancestors: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Scatter the updated rows into maps already copied from ``ancestors``: particle ``n``
    gets its ancestor's rows. One scatter per array over all ``K`` slots (a slot that writes
    nothing has ``write[k] = M`` and is dropped). Writing slot by slot would take ``4K`` small
    kernels per step, and as many fusions to compile. Shared covariances are written once per landmark."""
    rows_mu = jnp.swapaxes(jnp.take(upd.rows_mu, ancestors, axis=1, mode="clip"), 0, 1)  # [N, K, D]
    means = means.at[:, upd.write].set(rows_mu, mode="drop")
    if _is_shared(means, covs):
        return means, covs.at[upd.write].set(upd.rows_cov, mode="drop")
    rows_cov = jnp.swapaxes(jnp.take(upd.rows_cov, ancestors, axis=1, mode="clip"), 0, 1)  # [N, K, D, D]
    return means, covs.at[:, upd.write].set(rows_cov, mode="drop")


def _proposal(om, r, prior_mean, prior_cov, means, covs, seen, obs, valid, ids):
    """FastSLAM 2.0 pose proposal of one particle: EKF updates of ``N(g(u, x), Q_t)`` by each
    observation of an already-mapped landmark, noise ``R + H_m Σ_j H_mᵀ``.

    Returns the proposal Gaussian and ``log N(z; ẑ, H_x Q_t H_xᵀ + H_m Σ H_mᵀ + R)`` summed (the weight).
    """

    def body(g, slot):
        j, z, ok = slot
        mu_j, cov_j = means[j], covs[j]
        h_m = jax.jacfwd(lambda mu: om.mean(g.mean, mu))(mu_j)
        q = r + h_m @ cov_j @ h_m.T
        res = kalman.ekf_update(
            g.mean,
            g.cov,
            z,
            lambda x: om.mean(x, mu_j),
            q,
            valid=ok & seen[j],
            state_angle_dims=_POSE_ANGLE_DIMS,
            obs_angle_dims=om.angle_dims,
        )
        return kalman.Gaussian(res.mean, res.cov), res.log_likelihood

    post, ll = jax.lax.scan(body, kalman.Gaussian(prior_mean, prior_cov), (ids, obs.z, valid))
    return post, jnp.sum(ll)


def _sample_gaussian(key, mean, cov):
    chol = jnp.linalg.cholesky(kalman.ensure_pd(cov))
    chol = jnp.where(jnp.all(jnp.isfinite(chol)), chol, jnp.diag(jnp.sqrt(jnp.maximum(jnp.diagonal(cov), 0.0))))
    x = mean + chol @ rng.normal(key, mean.shape, mean.dtype)
    return x.at[2].set(weights.wrap_angle(x[2]))


def _inputs_in_domain(config: FastSLAMConfig, params: FastSLAMParams, control: jax.Array, obs: Any) -> jax.Array:
    """``bool[]``, traceable: the control and the motion noise in the motion model's domain
    (:func:`jaxnav.models.motion.controls_in_domain`, :func:`jaxnav.models.motion.noise_in_domain`),
    and a measurement noise ``R = noise_cov(params.sensor)`` with a positive diagonal (what the
    landmark EKFs need, whatever the observation model; the parameters are finite,
    :func:`jaxnav.core.filter.params_in_domain`): the value checks of the host that matter
    numerically, as ``jnp``. The observations are not part of it: an unusable slot is
    dropped and counted."""
    del obs
    r = config.obs_model.noise_cov(params.sensor)
    return (
        controls_in_domain(control, config.motion_model)
        & noise_in_domain(config.motion_model, params.motion)
        & jnp.all(jnp.diagonal(r) > 0)
    )


def kernel(
    key: jax.Array, state: FastSLAMState, config: FastSLAMConfig, params: FastSLAMParams, control: jax.Array, obs: Any
) -> tuple[FastSLAMState, FastSLAMInfo]:
    """One FastSLAM step, pure and traceable (:func:`step` is it validated and jitted).

    A step whose control or parameters are outside the models' domain (refused on the host, so
    only inside a caller's ``jit``) keeps the state and sets ``info.invalid_inputs``
    (:func:`jaxnav.core.filter.guard_inputs`): its observations update no landmark and its
    ancestors are the particles themselves, so the maps are neither written nor copied (a select
    over the maps would cost a pass over them at every step); the poses and weights are selected."""
    inputs_ok = filter_api.inputs_in_domain(_inputs_in_domain, config, params, control, obs)
    om = config.obs_model
    model = get_motion_model(config.motion_model)
    k_move, k_resample = jax.random.split(key)
    r = om.noise_cov(params.sensor)
    obs = at_least_one_slot(obs)
    if om.bias is not None:  # a biased model (a UWB range): z − b, then as any other
        obs = obs._replace(z=unbiased_measurements(om, obs.z, params.sensor))
    valid, ids, num_ignored = slot_valid(obs, config.num_landmarks)
    valid = valid & inputs_ok

    if config.version == 1:
        poses = model.sample(k_move, state.poses, control, params.motion)
        proposal_ll = jnp.zeros(poses.shape[0], poses.dtype)
    else:

        def propose(k, x, means, covs):
            prior_mean = model.mean(x, control)
            prior_cov = kalman.ensure_pd(model.process_cov(x, control, params.motion))
            g, ll = _proposal(om, r, prior_mean, prior_cov, means, covs, state.seen, obs, valid, ids)
            return _sample_gaussian(k, g.mean, g.cov), ll

        keys = jax.random.split(k_move, config.num_particles)
        cov_axis = None if config.shared_covariance else 0
        poses, proposal_ll = jax.vmap(propose, in_axes=(0, 0, 0, cov_axis))(keys, state.poses, state.means, state.covs)

    updates, seen, update_ll, num_new = update_landmarks(
        om, r, poses, state.means, state.covs, state.seen, obs, valid, ids, config.parallel_slots
    )
    loglik = update_ll if config.version == 1 else proposal_ll
    # the guard of every particle filter, with the particle's map rows: a particle whose pose or updated landmarks are not finite keeps its pose, gets zero
    # weight and is resampled away (this step resamples whatever its ESS, so its rows are never
    # an ancestor's); with none left the step writes nothing and is degenerate
    ok = _finite_particles(poses, updates, config.num_landmarks)
    poses, loglik = keep_finite(state.poses, poses, loglik, ok=ok)
    any_ok, all_ok = jnp.any(ok), jnp.all(ok)
    updates = updates._replace(write=jnp.where(any_ok, updates.write, config.num_landmarks))
    seen = jnp.where(any_ok, seen, state.seen)
    num_new = jnp.where(any_ok, num_new, 0)
    norm = weights.normalize(state.log_weights + loglik)
    res, base = finish_step(
        k_resample,
        poses,
        norm,
        threshold=config.ess_threshold if config.ess_threshold >= 1.0 else jnp.where(all_ok, config.ess_threshold, 1.0),
        scheme=config.resampling,
        angle_dims=_POSE_ANGLE_DIMS,
        gradient=config.gradient,
        soft_mixing=config.soft_mixing,
    )
    # copy the old maps from the ancestors, then write the step's rows (of the ancestors) over them:
    # one pass over the maps, and the old maps are never copied just to be updated
    ancestors = jnp.where(inputs_ok, res.ancestors, jnp.arange(config.num_particles, dtype=res.ancestors.dtype))
    means, covs = _copy_maps(state.means, state.covs, ancestors, config)
    means, covs = write_rows(means, covs, updates, ancestors)
    poses = jnp.where(inputs_ok, res.particles, state.poses)
    log_weights = jnp.where(inputs_ok, res.log_weights, state.log_weights)
    info = extend_info(FastSLAMInfo, base, num_ignored=num_ignored, num_new=num_new)
    return FastSLAMState(poses, log_weights, means, covs, seen), filter_api.flag_invalid_inputs(info, inputs_ok)


def _finite_particles(poses: jax.Array, updates: SlotUpdates, num_landmarks: int) -> jax.Array:
    """``[N]`` bool: the particle's pose and the map rows the step writes for it are finite (a shared
    covariance row that is not finite makes every particle so)."""
    written = updates.write < num_landmarks  # [K]
    ok = jnp.all(jnp.isfinite(poses), axis=-1)
    ok &= jnp.all(jnp.isfinite(updates.rows_mu) | ~written[:, None, None], axis=(0, 2))
    cov_ok = jnp.isfinite(updates.rows_cov) | ~jnp.expand_dims(written, tuple(range(1, updates.rows_cov.ndim)))
    if updates.rows_cov.ndim == 4:  # per particle [K, N, D, D]
        return ok & jnp.all(cov_ok, axis=(0, 2, 3))
    return ok & jnp.all(cov_ok)


def _copies_in_place(config: FastSLAMConfig) -> bool:
    """Whether :func:`_copy_maps` copies in place (else it gathers into new buffers)."""
    large = config.resampling in resampling.SORTED_SCHEMES and config.map_floats >= IN_PLACE_MIN_FLOATS
    return config.map_copy == "in_place" or (config.map_copy == "auto" and large)


def _copy_maps(means, covs, ancestors, config: FastSLAMConfig):
    """Every particle takes its ancestor's map: the O(N·M) copy of [A] Alg. 5's resampling.

    Large maps with sorted ancestors are copied in place
    (``jaxnav.core.resampling.copy_ancestors_in_place``) unless ``config.map_copy`` is
    "gather"; ``ancestors = arange`` (no resampling) copies nothing in place. Shared covariances
    are not copied.
    """
    maps = (means,) if config.shared_covariance else (means, covs)
    if _copies_in_place(config):
        copied = resampling.copy_ancestors_in_place(maps, ancestors)
    else:
        # ancestors are in range: "clip" gathers without the out-of-range select of the default "fill"
        copied = tuple(jnp.take(a, ancestors, axis=0, mode="clip") for a in maps)
    return copied if len(copied) == 2 else (copied[0], covs)


def run_unroll(config: FastSLAMConfig) -> int:
    """Steps per scan iteration in :func:`run`: 2 when resampling gathers maps of at least
    ``UNROLL_MIN_FLOATS`` (256) floats per particle, else 1.

    A gathered map is a new buffer that the scan would copy back into its carry at every step;
    with two steps per iteration the second gather writes straight into the carry. Under ``vmap``
    in Table 3.1's settings this shortens a run with 420 floats per particle (100 tags/m², shared
    covariances) or 1,260 (per-particle covariances), for a somewhat longer compilation, while
    small maps (56 floats at 16 tags/m²) run slower unrolled.
    """
    return 2 if not _copies_in_place(config) and config.map_floats >= UNROLL_MIN_FLOATS else 1


step, run = filter_api.build(
    filter_api.FilterSpec(
        name="FastSLAM",
        kernel=kernel,
        config_type=FastSLAMConfig,
        state_type=FastSLAMState,
        time_inputs=("controls", "observations"),
        check_params=_validate_params,
        check_state=_validate_state,
        check_inputs=_validate_inputs,
        valid_inputs=_inputs_in_domain,
        donate_step=True,
        unroll=run_unroll,
        step_doc="""One FastSLAM step (version from ``config``) with ``control [control_dim]`` and one step's
        observations (fields ``ids``, ``z``, ``mask`` with slots ``[K]``, e.g. a
        :class:`~jaxnav.models.landmarks.RangeBearingObs`).""",
        run_doc="""FastSLAM over a sequence: ``controls [T, control_dim]`` and observations with leading axis
        ``T``; ``state`` from :func:`init`. ``trace.estimate`` is ``[T, 3]``; use :func:`map_estimate` on
        the final state for the map.""",
    ),
    __name__,
)


@jax.jit
def map_estimate(state: FastSLAMState) -> tuple[jax.Array, jax.Array]:
    """Weighted mean landmark positions ``[M, D]`` over particles, and the ``seen`` mask."""
    p = jnp.exp(state.log_weights)
    return jnp.einsum("n,nmd->md", p, state.means), state.seen
