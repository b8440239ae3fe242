"""Particles spread over devices: exact global resampling inside ``jax.shard_map``.

When one filter's ``N`` particles are split over the ``D`` devices of a mesh axis (each device
holding a block of ``N / D`` consecutive particles), resampling needs the whole weight vector's
CDF. These functions run inside ``jax.shard_map`` on one device's block and give that device's
part of what :mod:`jaxnav.core.resampling` gives on the whole vector, **bit for bit**:

1. the integer weights (:mod:`jaxnav.core.integer_cdf`) use the whole vector's largest weight and
   float total (a maximum over devices, and the same rows of 1024 summed in the same order);
2. each device's integer CDF is offset by the exact 64-bit totals of the blocks before it (a
   gather of ``D`` totals and their exclusive prefix);
3. each device decides the cumulative offspring counts of its own particles against the global
   strata (the same uniforms on every device, drawn from the same key);
4. the ancestors of each device's block of ``M / D`` output slots come from the counts' histogram,
   summed over devices and scattered (``psum_scatter``), plus the exclusive prefix of the blocks'
   totals;
5. :func:`take` fetches each slot's ancestor from whichever device holds it: the blocks travel
   round the ring of devices (``ppermute``), ``D − 1`` steps, one block in flight per device.

So from the same weights and key the ancestors equal those of the unsharded scheme exactly, at
any ``D`` dividing ``N`` and ``M`` (:func:`resample_weights`). From log-weights (:func:`resample`)
one step is not integer arithmetic: ``exp(ℓ − max ℓ)``, which two programs may round differently.
XLA:CPU computes the unsharded one in an XNNPACK fusion together with the maximum, the sharded one
(whose maximum is a collective) in its own loop: measured on 4 × 25,000 lognormal log-weights, 2 %
of the weights differ in their last bit and 1–4 of 100,000 ancestors moved in 13 of 144 draws.
Where every ``exp`` is exact (log-weights 0 or −∞) the ancestors are the same. Memory per device: its particles, one visiting block, and ``M`` integers
for the histogram (and the stratified scheme's ``M`` uniforms). Systematic and stratified
resampling are supported; the multinomial and residual schemes are not.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import batch, fastmath
from jaxnav.core import filter as filter_api
from jaxnav.core import weights as _w
from jaxnav.core.integer_cdf import integer_cdf, scale
from jaxnav.core.particle_filter import PFInfo
from jaxnav.core.resampling import _COUNTS, ResampleResult

__all__ = [
    "PARTICLE_AXIS",
    "SCHEMES",
    "finish_step",
    "resample",
    "resample_weights",
    "take",
    "spread_devices",
    "scan_program",
]

PARTICLE_AXIS = "particles"
"""The mesh axis over which the filters' ``run_sharded`` spread their particles."""

SCHEMES = ("systematic", "stratified")
"""The schemes :func:`resample` spreads over devices."""


def resample(
    key: jax.Array, log_weights: jax.Array, num_samples: int, axis_name: str, scheme: str = "systematic"
) -> jax.Array:
    """This device's ``num_samples / D`` ancestors (global indices in ``[0, N)``, int32, non-decreasing)
    of the particles whose log-weights are spread over the ``D`` devices of mesh axis ``axis_name``.

    Inside ``jax.shard_map``: ``log_weights [N / D]`` is this device's block (unnormalised; the
    blocks in device order make the whole vector), ``num_samples`` the global ``M`` (a multiple of
    ``D``), ``key`` the same on every device. Concatenated over the devices, the ancestors are
    bit for bit those of :func:`jaxnav.core.resampling.systematic` (or ``stratified``) on the
    whole vector with the same key (module docstring).
    """
    lw = _w.sanitize_log_weights(jax.lax.stop_gradient(log_weights))
    probabilities = jnp.exp(lw - jax.lax.pmax(jnp.max(lw), axis_name))  # the whole vector's largest, exactly
    return resample_weights(key, probabilities, num_samples, axis_name, scheme)


def resample_weights(
    key: jax.Array, weights: jax.Array, num_samples: int, axis_name: str, scheme: str = "systematic"
) -> jax.Array:
    """:func:`resample` from non-negative ``weights [N / D]`` (not logs; need not be normalised): bit for
    bit the blocks of :func:`jaxnav.core.resampling.resample_weights` on the whole vector."""
    if scheme not in SCHEMES:
        raise ValueError(f"resampling scheme {scheme!r} cannot be spread over devices; choose one of {SCHEMES}")
    size = jax.lax.axis_size(axis_name)
    if num_samples % size:
        raise ValueError(f"num_samples ({num_samples}) must be a multiple of the {size} devices of {axis_name!r}")
    cdf = integer_cdf(weights, axis_name)
    counts = _COUNTS[scheme](key, cdf, scale(cdf.total, num_samples, num_samples))  # C_i of this block
    return _ancestors(counts, num_samples, weights.shape[0] * size, axis_name)


def _ancestors(cumulative: jax.Array, num_samples: int, num_particles: int, axis_name: str) -> jax.Array:
    """:func:`jaxnav.core.integer_cdf.ancestors_from_counts` of the whole count vector, this device's slots:
    ``a_m = #{i : C_i ≤ m}``, the histogram of every device's counts summed and scattered in slot blocks."""
    at = jnp.clip(cumulative, 0, num_samples)
    hist = jnp.zeros((num_samples + 1,), jnp.int32).at[at].add((at >= 0).astype(jnp.int32), indices_are_sorted=True)
    mine = jax.lax.psum_scatter(hist[:num_samples], axis_name, scatter_dimension=0, tiled=True)
    totals = jax.lax.all_gather(jnp.sum(mine), axis_name)  # [D]: slots at or below each block, per block
    me = jax.lax.axis_index(axis_name)
    before = jnp.sum(jnp.where(jnp.arange(totals.shape[0]) < me, totals, 0))
    return jnp.minimum(before + fastmath.int_cumsum(mine), num_particles - 1)


def take(particles: Any, ancestors: jax.Array, axis_name: str) -> Any:
    """The particles at global indices ``ancestors [m]`` (from :func:`resample`) for this device, from
    the blocks ``particles`` (a pytree of ``[N / D, ...]`` leaves) spread over mesh axis ``axis_name``.

    Each device's block travels once round the ring of devices (``D − 1`` ``ppermute`` steps), and
    every device keeps the rows its ancestors name as the block passes: one block in flight per
    device, never the whole set.
    """
    size = jax.lax.axis_size(axis_name)
    block = jax.tree_util.tree_leaves(particles)[0].shape[0]
    source, row = ancestors // block, ancestors % block  # the device holding each ancestor, its row there
    ring = [(i, (i + 1) % size) for i in range(size)]
    owner = jax.lax.axis_index(axis_name)  # the device whose block is visiting
    visiting = particles
    out = jax.tree_util.tree_map(lambda x: jnp.take(x, row, axis=0), visiting)
    for _ in range(size - 1):
        visiting = jax.lax.ppermute(visiting, axis_name, ring)
        owner = (owner - 1) % size
        here = source == owner
        out = jax.tree_util.tree_map(
            lambda x, kept: jnp.where(here.reshape(here.shape + (1,) * (x.ndim - 1)), jnp.take(x, row, axis=0), kept),
            visiting,
            out,
        )
    return out


def finish_step(
    key: jax.Array,
    particles: jax.Array,
    norm: _w.Normalized,
    axis_name: str,
    *,
    threshold: Any = 1.0,
    scheme: str = "systematic",
    angle_dims: tuple[int, ...] = (),
    gradient: str = "score",
) -> tuple[ResampleResult, PFInfo]:
    """:func:`jaxnav.core.particle_filter.finish_step` for particles spread over the devices of mesh
    axis ``axis_name`` (inside ``jax.shard_map``): ``particles [N / D, D_x]`` and ``norm`` (from
    :func:`jaxnav.core.weights.normalize` with the same ``axis_name``) are this device's block.

    The estimate and the ESS are sums over devices (``psum``), the unsharded values up to the order
    of the additions; from the same weights and key the ancestors are the unsharded ones exactly
    (:func:`resample_weights`, the particles fetched by :func:`take`). The returned ancestors are
    this device's slots' global indices. ``gradient``: ``"score"`` (stop-gradient resampling,
    :func:`jaxnav.core.gradients.selection_score`; its derivative reaches each ancestor's device in
    the backward pass, reverse mode only) or ``"naive"``, with the same forward pass; ``"soft"``
    changes the draw and is not available here.
    """
    if gradient not in ("score", "naive"):
        raise ValueError(f"gradient {gradient!r} is not available with the particles spread over devices")
    probs = jnp.exp(norm.log_weights)
    estimate = _w.mean_from_probabilities(particles, probs, angle_dims, axis_name)
    ess_value = _w.ess_from_probabilities(probs, axis_name)  # one sum over devices: reported and decided on
    ess = jnp.where(norm.degenerate, jnp.zeros((), probs.dtype), ess_value)  # weights.step_ess
    rows = probs.shape[0]
    n = rows * jax.lax.axis_size(axis_name)
    k_resample, _ = jax.random.split(key)  # as resampling.conditional_resample splits it
    uniform = jnp.full_like(norm.log_weights, -jnp.log(jnp.asarray(n, norm.log_weights.dtype)))

    def resampled():
        ancestors = resample_weights(k_resample, probs, n, axis_name, scheme)
        new = take(particles, ancestors, axis_name)
        if gradient == "naive":
            return new, uniform, ancestors
        return new, uniform + _selection_score(norm.log_weights, ancestors, axis_name), ancestors

    if isinstance(threshold, (int, float)) and threshold >= 1.0:
        new, log_weights, ancestors = resampled()
        decided = jnp.asarray(True)
    else:
        decided = (ess_value < threshold * n) | (jnp.asarray(threshold) >= 1.0)
        mine = jax.lax.axis_index(axis_name) * rows + jnp.arange(rows, dtype=jnp.int32)
        new, log_weights, ancestors = jax.lax.cond(decided, resampled, lambda: (particles, norm.log_weights, mine))
    return ResampleResult(new, log_weights, ancestors, decided), PFInfo(
        estimate, ess, decided, norm.log_norm, norm.degenerate
    )


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _selection_score(log_weights: jax.Array, ancestors: jax.Array, axis_name: str) -> jax.Array:
    """:func:`jaxnav.core.gradients.selection_score` of this device's slots, for log-weights spread over
    ``axis_name``: zeros in value, written with a custom VJP so that the forward pass is the one of
    ``"naive"`` (no ancestor's log-weight travels; another program could round the sums otherwise)
    and the backward pass sends each slot's cotangent to the device that holds its ancestor."""
    return jnp.zeros(ancestors.shape, log_weights.dtype)


def _selection_score_fwd(log_weights, ancestors, axis_name):
    return _selection_score(log_weights, ancestors, axis_name), (ancestors, log_weights.shape[0])


def _selection_score_bwd(axis_name, residuals, cotangent):
    ancestors, rows = residuals
    whole = jnp.zeros((rows * jax.lax.axis_size(axis_name),), cotangent.dtype).at[ancestors].add(cotangent)
    return jax.lax.psum_scatter(whole, axis_name, scatter_dimension=0, tiled=True), None


_selection_score.defvjp(_selection_score_fwd, _selection_score_bwd)


def spread_devices(num_particles: int, scheme: str, devices: Any = None) -> tuple:
    """The local devices a filter's ``run_sharded`` spreads its ``num_particles`` over (``devices`` as in
    :func:`jaxnav.core.batch.run_devices`; ``None``: every local device), after the checks every spread
    filter needs: the devices are this process's, they divide the particles, and the resampling
    ``scheme`` is one of :data:`SCHEMES`. ``ValueError`` naming what is wrong otherwise."""
    chosen = batch.run_devices(jax.local_devices() if devices is None else devices)
    if any(d.process_index != jax.process_index() for d in chosen):
        raise ValueError("run_sharded spreads particles over this process's devices; devices must be local")
    if num_particles % len(chosen):
        raise ValueError(f"config.num_particles ({num_particles}) must be a multiple of the {len(chosen)} devices")
    if scheme not in SCHEMES:
        raise ValueError(f"config.resampling {scheme!r} cannot be spread over devices; choose one of {SCHEMES}")
    return chosen


@functools.lru_cache(maxsize=32)
def scan_program(kernel: Any, config: Any, devices: tuple, state_specs: Any) -> Any:
    """The compiled ``run`` of a filter whose particles are spread over ``devices``: a ``lax.scan`` of
    ``kernel`` (:func:`jaxnav.core.filter.scan`) inside ``jax.shard_map`` over a one-axis mesh
    :data:`PARTICLE_AXIS`, called as ``(key, state, params, *inputs)``. ``state_specs`` is the state's
    ``PartitionSpec`` pytree (the particles' leaves in blocks, ``P(PARTICLE_AXIS)``; the rest ``P()``);
    the key, the parameters, the inputs and the trace are the same on every device."""
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as P

    mesh = Mesh(np.asarray(devices, dtype=object), (PARTICLE_AXIS,))

    def body(key: jax.Array, state: Any, params: Any, *inputs: Any) -> tuple[Any, Any]:
        return filter_api.scan(kernel, key, state, config, params, *inputs)

    spread = jax.shard_map(
        body, mesh=mesh, in_specs=(P(), state_specs, P(), P(), P()), out_specs=(state_specs, P()), check_vma=False
    )
    return jax.jit(spread)
