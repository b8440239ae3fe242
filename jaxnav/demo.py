"""The ``jaxnav demo``: Monte Carlo localization in a simulated 10 m room.

A robot drives a circle (radius 2.4 m, one lap in 120 steps) inside a 10 m × 10 m room with 8 landmarks on the
walls (corners and mid-walls), measuring range and bearing to each with
σ = (0.1 m, 0.05 rad). MCL ([A] Alg. 3) with 1,000 particles starts from a
Gaussian prior 1 m / 0.5 rad wide around a start guessed 1 m off and tracks the
robot; the demo reports the position error over time and draws the true and
estimated paths.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

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
    """Arrays of one demo run (NumPy, on the host)."""

    true_poses: np.ndarray  # [T, 3]
    estimates: np.ndarray  # [T, 3]
    position_error: np.ndarray  # [T] m
    landmarks: np.ndarray  # [M, 2]
    dt: float  # s per step


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
    _, trace = mcl.run(k_run, state, config, params, sim.controls, sim.observations)
    true_poses = np.asarray(sim.true_poses)
    est = np.asarray(trace.estimate)
    err = np.linalg.norm(est[:, :2] - true_poses[:, :2], axis=1)
    return DemoResult(true_poses, est, err, np.asarray(params.landmarks), float(controls[0, 2]))


def plot_demo(result: DemoResult, path: str) -> str:
    """Write a PNG of the true and estimated paths and the error over time; returns ``path``."""
    import matplotlib.pyplot as plt

    fig, (ax, ax_err) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1, 1.3]})
    ax.plot(result.true_poses[:, 0], result.true_poses[:, 1], "k-", lw=2, label="true path")
    ax.plot(result.estimates[:, 0], result.estimates[:, 1], "C1--", lw=1.5, label="MCL estimate")
    ax.plot(result.landmarks[:, 0], result.landmarks[:, 1], "C0^", ms=9, label="landmarks")
    ax.plot(*result.true_poses[0, :2], "ko", ms=6)
    ax.set(xlim=(-0.5, ROOM_SIZE + 0.5), ylim=(-0.5, ROOM_SIZE + 0.5), xlabel="x [m]", ylabel="y [m]", aspect="equal")
    ax.set_title("Monte Carlo localization, 10 m room")
    ax.legend(loc="center", fontsize=8)
    t = np.arange(1, len(result.position_error) + 1) * result.dt
    ax_err.plot(t, result.position_error * 100.0, "C1-")
    ax_err.set(xlabel="time [s]", ylabel="position error [cm]", title="Position error")
    ax_err.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
