"""What every particle filter's step ends with: normalise → estimate → ESS → resample.

A particle filter's step moves its particles, scores them (a log-likelihood per particle),
and then runs the same tail, written here once ([A] Alg. 3 lines 4–11, [W] Alg. 1 lines
17–24):

1. the normalised posterior weights ``w̄_t ∝ w̄_{t−1} · p(z_t | x_t)`` (the caller's
   :func:`jaxnav.core.weights.normalize`; its normaliser is the log marginal-likelihood
   increment ``log p(z_t | z_{1:t−1})``, and a step where every weight is zero is reset to
   uniform and flagged);
2. the estimate, the weighted mean with circular mean on the angle dimensions, taken
   *before* resampling (which adds noise and no information);
3. the effective sample size ``1 / Σ w̄²`` (:func:`jaxnav.core.weights.step_ess`: 0 on a
   degenerate step);
4. resampling when the ESS falls below ``threshold · N``
   (:func:`jaxnav.core.resampling.conditional_resample`).

:class:`PFInfo` holds the diagnostics every particle filter reports; each filter's info
extends it with its own fields (``MCLInfo(PFInfo)`` adds ``num_ignored``, …), so code that
reads ``info.estimate``, ``info.ess``, ``info.resampled``, ``info.log_likelihood`` and
``info.degenerate`` works with any of them.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

from jaxnav.core import resampling, weights

__all__ = ["InfoT", "PFInfo", "extend_info", "finish_step", "keep_finite", "materialize", "at_least_one_slot"]

InfoT = TypeVar("InfoT", bound="PFInfo")
"""A filter's info type, :class:`PFInfo` or a subclass of it (what :meth:`PFInfo.replace` and
:func:`extend_info` return)."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PFInfo:
    """Per-step diagnostics shared by every particle filter (stacked over time by ``run``).

    Attributes:
        estimate: the weighted mean state after the update, before resampling (circular on angles).
        ess: effective sample size ``1 / Σ w̄²`` after the update (0 on a degenerate step).
        resampled: bool, whether this step resampled.
        log_likelihood: ``log p(z_t | z_{1:t−1})``, the log marginal-likelihood increment.
        degenerate: bool, every particle had zero likelihood; the weights were reset to uniform.
    """

    estimate: jax.Array
    ess: jax.Array
    resampled: jax.Array
    log_likelihood: jax.Array
    degenerate: jax.Array

    def replace(self: InfoT, **changes: Any) -> InfoT:
        """A copy with ``changes`` (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)


def extend_info(info_type: type[InfoT], base: PFInfo, **fields: Any) -> InfoT:
    """``info_type`` (a subclass of :class:`PFInfo`) with the fields of ``base`` and ``fields``."""
    shared = {f.name: getattr(base, f.name) for f in dataclasses.fields(PFInfo)}
    return info_type(**shared, **fields)


def at_least_one_slot(observation: Any) -> Any:
    """A step's slotted observation (every leaf ``[K, ...]``, a ``mask`` among them) with one
    empty slot (zeros, mask False) when it has none (``K = 0``), else the observation itself.

    Zero slots are valid input (a step with nothing observed); this keeps the slot code, whose
    reductions over slots (first slot of a landmark, last writer) have no empty form, to one
    shape rule. The added slot is masked out, so the step is a motion update alone.
    """
    leaves = jax.tree_util.tree_leaves(observation)
    if not leaves or leaves[0].shape[0] > 0:
        return observation
    return jax.tree_util.tree_map(lambda x: jnp.zeros((1, *x.shape[1:]), x.dtype), observation)


def materialize(particles: jax.Array) -> jax.Array:
    """``particles`` unchanged, written to memory once before a likelihood reads them.

    Without it XLA:CPU fuses the motion (noise draw, arc, wrap) into each of the likelihood's
    ``[N, K]`` loops and evaluates it again for every observation slot; in benchmarks W2
    (N = 10⁴, K = 8) and W2b (100 runs of 10³, vmapped) a step takes markedly longer without it.
    An ``optimization_barrier``: the identity for values, gradients and ``vmap``.
    """
    return jax.lax.optimization_barrier(particles)


def keep_finite(
    previous: jax.Array, moved: jax.Array, log_likelihood: jax.Array, ok: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """The guard every particle filter's step applies after its move and its scores.

    A particle whose move is not finite (an overflow under a caller's ``jit``, where the host
    checks cannot see the values) keeps its ``previous [N, D]`` value and gets zero weight
    (log-likelihood ``-inf``), so it is resampled away and never reaches the estimate; a NaN or
    ``+inf`` score is zero weight too (:func:`jaxnav.core.weights.normalize`). When no particle is
    left the step is degenerate: the previous particles are kept with uniform weights, and the
    step is flagged. On finite input both selects keep every value: results are unchanged.
    ``ok [N]`` replaces the test "the move is finite" where a particle carries more than its
    move (FastSLAM: its map rows too).

    Returns ``(particles [N, D], log_likelihood [N])``.
    """
    if ok is None:
        ok = jnp.all(jnp.isfinite(moved), axis=-1)
    return jnp.where(ok[:, None], moved, previous), jnp.where(ok, log_likelihood, -jnp.inf)


def finish_step(
    key: jax.Array,
    particles: jax.Array,
    norm: weights.Normalized,
    *,
    threshold: Any = 1.0,
    scheme: str = "systematic",
    refresh: bool = False,
    angle_dims: tuple[int, ...] = (),
    gradient: str = "score",
    soft_mixing: float = 0.5,
) -> tuple[resampling.ResampleResult, PFInfo]:
    """Estimate, ESS and conditional resampling of ``particles [N, D]`` with the normalised weights ``norm``.

    Args:
        key: PRNG key of the resampling.
        particles: ``[N, D]`` particles after the move.
        norm: :func:`jaxnav.core.weights.normalize` of ``log w̄_{t−1} + log p(z_t | x_t)``.
        threshold: resample when ESS < ``threshold · N`` (1.0: every step; may be traced, e.g.
            0 at a step without measurement).
        scheme: a name in :data:`jaxnav.core.resampling.SCHEMES`.
        refresh: redraw the resampled set from its fitted Gaussian ([A] §4.3.3).
        angle_dims: dimensions that are angles (circular mean, wrapped refresh).
        gradient, soft_mixing: how derivatives pass the resampling (:mod:`jaxnav.core.gradients`).

    Returns:
        ``(ResampleResult, PFInfo)``: the particles and log-weights to carry on (with the
        ancestors), and the step's diagnostics. With ``gradient="soft"``, ``info.degenerate`` is
        also set at a step whose draw kept no particle of positive weight (its carried weights
        were reset to uniform, :func:`jaxnav.core.gradients.soft_carried_log_weights`).
    """
    probs = jnp.exp(norm.log_weights)
    estimate = weights.mean_from_probabilities(particles, probs, angle_dims)
    ess = weights.step_ess(probs, norm.degenerate)
    res = resampling.conditional_resample(
        key,
        particles,
        norm.log_weights,
        threshold=threshold,
        scheme=scheme,
        refresh=refresh,
        angle_dims=angle_dims,
        normalized=True,
        gradient=gradient,
        soft_mixing=soft_mixing,
    )
    degenerate = norm.degenerate
    if gradient == "soft":  # every ancestor drawn had zero weight: the carried weights were reset to uniform
        picked = jnp.take(norm.log_weights, res.ancestors, axis=0, mode="clip")
        degenerate = degenerate | (res.resampled & ~jnp.any(jnp.isfinite(picked)))
    return res, PFInfo(estimate, ess, res.resampled, norm.log_norm, degenerate)
