"""The ``jaxnav demo``: Monte Carlo localization in a simulated 10 m room.

A robot drives a circle (radius 2.4 m, one lap in 120 steps) inside a 10 m × 10 m room with 8 landmarks on the
walls (corners and mid-walls), measuring range and bearing to each with
σ = (0.1 m, 0.05 rad). MCL ([A] Alg. 3) with 1,000 particles starts from a
Gaussian prior 1 m / 0.5 rad wide around a start guessed 1 m off and tracks the
robot; the demo reports the position error over time and draws the true and
estimated paths with the particle cloud at a few steps.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import filter as filter_api
from jaxnav.localization import mcl
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.sim import landmark_world as world
from jaxnav.sim import trajectories

__all__ = ["DemoResult", "demo_setting", "run_demo", "plot_demo"]

ROOM_SIZE = 10.0  # m
START = (5.0, 1.5, 0.0)  # true start pose (m, m, rad)
PRIOR_OFFSET = (0.8, -0.6, 0.3)  # the filter's guess is off by this much
PRIOR_SD = (1.0, 1.0, 0.5)


class DemoResult(NamedTuple):
    """Arrays of one demo run (NumPy, on the host).

    ``cloud_steps [K]`` and ``clouds [K, N, 2]``: the particles' positions at a few steps
    (0: the prior, before the first update; ``t``: after update ``t`` and its resampling).
    """

    true_poses: np.ndarray  # [T, 3]
    estimates: np.ndarray  # [T, 3]
    position_error: np.ndarray  # [T] m
    landmarks: np.ndarray  # [M, 2]
    dt: float  # s per step
    cloud_steps: np.ndarray | None = None  # [K]
    clouds: np.ndarray | None = None  # [K, N, 2] m


def cloud_steps(num_steps: int) -> tuple[int, ...]:
    """The steps whose particles the demo keeps: the prior, the middle and the end."""
    return tuple(sorted({0, (num_steps + 1) // 2, num_steps}))


@partial(jax.jit, static_argnums=(2,))
def _run_keeping_clouds(key, state, config, params, controls, observations, slots, clouds):
    """:func:`jaxnav.localization.mcl.run` (same kernel, same per-step keys) that also writes the particles'
    positions after step ``t`` into ``clouds[slots[t]]`` (a slot past the end keeps nothing): a handful of
    ``[N, 2]`` copies instead of the ``[T, N, 3]`` a trace of every step's particles would hold."""

    def kernel(k, carry, config, params, control, obs, slot):
        st, kept = carry
        st, info = mcl.kernel(k, st, config, params, control, obs)
        return (st, kept.at[slot].set(st.particles[:, :2], mode="drop")), info

    (_, clouds), trace = filter_api.scan(kernel, key, (state, clouds), config, params, controls, observations, slots)
    return clouds, trace


def demo_setting(num_particles: int = 1000) -> tuple[mcl.MCLConfig, mcl.MCLParams]:
    """Configuration and parameters of the demo filter (the simulator uses the same noise)."""
    config = mcl.MCLConfig(num_particles=num_particles, motion_model="velocity")
    params = mcl.MCLParams(
        motion=motion.VelocityNoise(
            alphas=jnp.asarray([0.02, 0.005, 0.005, 0.02, 0.0, 0.0]),
            pose_sd=jnp.asarray([0.01, 0.01, 0.005]),
        ),
        sensor=lm.RangeBearingNoise(jnp.asarray([0.1, 0.05])),
        landmarks=world.square_room_landmarks(ROOM_SIZE, 8),
    )
    return config, params


def run_demo(seed: int = 0, num_steps: int = 120, num_particles: int = 1000) -> DemoResult:
    """Simulate the room and run MCL; deterministic for a given ``seed``."""
    config, params = demo_setting(num_particles)
    key = jax.random.PRNGKey(seed)
    k_sim, k_init, k_run = jax.random.split(key, 3)
    controls = trajectories.loop_controls(num_steps, speed=0.5, turn_rate=0.21, dt=0.25)
    sim = world.simulate(k_sim, params.landmarks, jnp.asarray(START), controls, params.motion, params.sensor)
    guess = jnp.asarray(START) + jnp.asarray(PRIOR_OFFSET)
    state = mcl.init(k_init, config, params, guess, jnp.asarray(PRIOR_SD))
    steps = cloud_steps(num_steps)
    after = [t for t in steps if t > 0]  # step t's particles are those after update t (scan index t - 1)
    slots = np.full(num_steps, len(after), np.int32)
    slots[np.asarray(after) - 1] = np.arange(len(after))
    clouds = jnp.zeros((len(after), num_particles, 2), state.particles.dtype)
    clouds, trace = _run_keeping_clouds(
        k_run, state, config, params, sim.controls, sim.observations, jnp.asarray(slots), clouds
    )
    clouds = np.concatenate([np.asarray(state.particles[None, :, :2]), np.asarray(clouds)])
    true_poses = np.asarray(sim.true_poses)
    est = np.asarray(trace.estimate)
    err = np.linalg.norm(est[:, :2] - true_poses[:, :2], axis=1)
    return DemoResult(
        true_poses, est, err, np.asarray(params.landmarks), float(controls[0, 2]), np.asarray(steps), clouds
    )


_CLOUD_COLORS = ("tab:purple", "tab:green", "tab:cyan", "tab:olive", "tab:pink")


def _cloud_label(t: int, dt: float) -> str:
    return "prior (t = 0 s)" if t == 0 else f"step {t} (t = {t * dt:g} s)"


def _draw_demo(result: DemoResult):
    """The figure of :func:`plot_demo`: the room (left), the error (top right) and, under it, each kept
    cloud after the prior in a window around the true pose (in the room they are a few cm wide: dots)."""
    import matplotlib.pyplot as plt

    steps = [] if result.cloud_steps is None else [int(t) for t in result.cloud_steps]
    zooms = [k for k, t in enumerate(steps) if t > 0]
    top = ["map", *(["err"] * max(1, len(zooms)))]
    mosaic = [top, ["map", *(f"z{k}" for k in zooms)]] if zooms else [top]
    fig, axd = plt.subplot_mosaic(
        mosaic, figsize=(13, 6.4), width_ratios=[2.2, *([1] * max(1, len(zooms)))], layout="constrained"
    )
    ax, ax_err = axd["map"], axd["err"]
    for k, t in enumerate(steps):
        c = _CLOUD_COLORS[k % len(_CLOUD_COLORS)]
        ax.plot(
            *result.clouds[k].T,
            ".",
            color=c,
            ms=1.5,
            alpha=0.4,
            zorder=1,
            label=f"particles, {_cloud_label(t, result.dt)}",
        )
    ax.plot(result.true_poses[:, 0], result.true_poses[:, 1], "k-", lw=2, zorder=2, label="true path")
    ax.plot(result.estimates[:, 0], result.estimates[:, 1], "C1--", lw=1.5, zorder=3, label="MCL estimate")
    ax.plot(result.landmarks[:, 0], result.landmarks[:, 1], "C0^", ms=9, label="landmarks")
    ax.plot(*result.true_poses[0, :2], "ko", ms=7, zorder=4, label="start (true)")
    ax.annotate("start", result.true_poses[0, :2], textcoords="offset points", xytext=(8, -14), fontsize=9)
    ax.set(xlim=(-0.5, ROOM_SIZE + 0.5), ylim=(-0.5, ROOM_SIZE + 0.5), xlabel="x [m]", ylabel="y [m]", aspect="equal")
    ax.set_title("Monte Carlo localization, 10 m room")
    # the legend in the room's empty upper half, between the path (y ≤ 6.3 m) and the wall's
    # landmarks: at the room's centre it would sit on the path
    legend = ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.93), ncol=2, framealpha=0.9)
    for h in legend.legend_handles[: len(steps)]:  # the clouds' dots, legible
        h.set_markersize(8)
        h.set_alpha(1.0)

    t = np.arange(1, len(result.position_error) + 1) * result.dt
    ax_err.plot(t, result.position_error * 100.0, "C1-")
    for k in zooms:
        ax_err.axvline(steps[k] * result.dt, color=_CLOUD_COLORS[k % len(_CLOUD_COLORS)], ls=":", lw=1.5)
    ax_err.set(xlabel="time [s]", ylabel="position error [cm]", title="MCL position error (dotted: the clouds below)")
    ax_err.set_ylim(bottom=0)
    ax_err.grid(alpha=0.3)

    for k in zooms:
        z, step = axd[f"z{k}"], steps[k]
        c = _CLOUD_COLORS[k % len(_CLOUD_COLORS)]
        truth = result.true_poses[step - 1, :2]  # the pose after step `step`
        d = 100.0 * (result.clouds[k] - truth)
        e = 100.0 * (result.estimates[step - 1, :2] - truth)
        z.plot(*d.T, ".", color=c, ms=2, alpha=0.4)
        z.plot(0, 0, "k+", ms=12, mew=2, label="true pose")
        z.plot(*e, "x", color="C1", ms=9, mew=2, label="estimate")
        half = 1.15 * max(1.0, float(np.max(np.abs(np.vstack([d, e[None]])))))
        z.set(xlim=(-half, half), ylim=(-half, half), aspect="equal", xlabel="Δx [cm]")
        z.set_title(_cloud_label(step, result.dt), fontsize=9, color=c)
        z.tick_params(labelsize=7)
        z.grid(alpha=0.3)
    if zooms:
        first = axd[f"z{zooms[0]}"]
        first.set_ylabel("Δy [cm] from the true pose")
        first.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
    return fig


def plot_demo(result: DemoResult, path: str) -> str:
    """Write a PNG of the true and estimated paths, the particles at a few steps and the error over time;
    returns ``path``."""
    import matplotlib.pyplot as plt

    fig = _draw_demo(result)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
