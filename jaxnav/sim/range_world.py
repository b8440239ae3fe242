"""Simulated range-only worlds: a robot among beacons that it measures by distance alone.

A robot moves with a motion model of :mod:`jaxnav.models.motion` under commanded controls (its
true path a noisy draw of the model, as in :mod:`jaxnav.sim.landmark_world`) and at every step
measures its range to every beacon within ``max_range``,

    z = ‖m − (x, y)‖ + b + σ·ε,   ε ~ N(0, 1), or Student-t with ν degrees of freedom,

the model of :mod:`jaxnav.models.range_only`. The filter gets the commanded controls and the
ranges. A pure function of a key: a Monte Carlo study vmaps :func:`simulate` over keys.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.models import range_only as ro
from jaxnav.models.motion import get_motion_model
from jaxnav.sim.landmark_world import check_drive, in_one_dtype

__all__ = ["RangeRun", "simulate"]


class RangeRun(NamedTuple):
    """A simulated sequence of ``T`` steps.

    Attributes:
        true_poses: ``[T, 3]`` pose after each step's motion (m, m, rad).
        controls: ``[T, control_dim]`` commanded controls given to the filter.
        observations: :class:`~jaxnav.models.range_only.RangeObs` with leading axis ``T`` and one
            slot per beacon (``K = M``), masked where the beacon is out of range.
    """

    true_poses: jax.Array
    controls: jax.Array
    observations: ro.RangeObs


def simulate(
    key: jax.Array,
    beacons: Any,
    initial_pose: Any,
    controls: Any,
    motion_noise: Any,
    noise: ro.RangeNoise,
    motion_model: str = "velocity",
    max_range: float = math.inf,
    heavy_tailed: bool = False,
) -> RangeRun:
    """Simulate a robot driving ``controls`` among ``beacons [M, 2]`` and measuring ranges.

    Args:
        key: PRNG key.
        beacons: ``[M, 2]`` beacon positions (m).
        initial_pose: ``[3]`` pose before the first control.
        controls: ``[T, control_dim]`` commanded controls of ``motion_model``.
        motion_noise: the motion model's noise (the *true* process noise).
        noise: the *true* range model (:class:`~jaxnav.models.range_only.RangeNoise`).
        motion_model: a name in :data:`jaxnav.models.motion.MODELS` or a motion model.
        max_range: beacons farther than this (m) are not measured (their slots masked).
        heavy_tailed: Student-t noise of ``noise.dof`` degrees of freedom instead of Gaussian.

    Checked on the host as a filter's inputs are (``ValueError`` naming the argument). The
    floating-point inputs are promoted to one dtype, which the run's arrays come out in.
    """
    check_key(key)
    beacons, initial_pose, controls = check_drive(
        "beacons", beacons, initial_pose, controls, motion_model, motion_noise, max_range
    )
    ro.validate_noise(noise, "noise")
    if not isinstance(heavy_tailed, bool):
        raise ValueError(f"heavy_tailed must be True or False, got {heavy_tailed!r}")
    beacons, initial_pose, controls, motion_noise, noise = in_one_dtype(
        beacons, initial_pose, controls, motion_noise, noise
    )
    return _simulate(key, beacons, initial_pose, controls, motion_noise, noise, motion_model, max_range, heavy_tailed)


@partial(jax.jit, static_argnames=("motion_model", "heavy_tailed"))
def _simulate(key, beacons, initial_pose, controls, motion_noise, noise, motion_model, max_range, heavy_tailed):
    model = get_motion_model(motion_model)
    m = beacons.shape[0]

    def body(pose, inputs):
        k, u = inputs
        k_move, k_obs = jax.random.split(k)
        pose = model.sample(k_move, pose, u, motion_noise)
        distance = ro.expected_range(pose[None, :2], beacons, 0.0)
        if heavy_tailed:
            eps = jax.random.t(k_obs, noise.dof, (m,), distance.dtype)
        else:
            eps = rng.normal(k_obs, (m,), distance.dtype)
        z = distance + noise.bias + noise.sd * eps
        obs = ro.RangeObs(jnp.arange(m, dtype=jnp.int32), z[:, None], distance <= max_range)
        return pose, (pose, obs)

    keys = jax.random.split(key, controls.shape[0])
    _, (poses, obs) = jax.lax.scan(body, initial_pose, (keys, controls))
    return RangeRun(poses, controls, obs)
