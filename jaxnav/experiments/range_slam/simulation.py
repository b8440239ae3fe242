"""Range-only SLAM among unknown beacons, simulated: what a particle set per beacon buys, measured.

**The world** (:class:`RangeSetting`, :func:`make_world`). An 8 m × 8 m room holds six beacons,
uniform over it and new in every run. A robot starts at a known pose and drives a circle of 2 m radius
(0.3 m/s, 0.15 rad/s, Thrun's velocity model with ``α = (0.1, 0.05, 0.05, 0.1, 0, 0)`` and 2 mm / 2 mrad
of pose noise per 0.1 s step) for 1000 steps, 2.4 laps; at every step it ranges every beacon,
``z = ‖m − p‖ + σε`` with ``σ = 0.1`` m (:mod:`jaxnav.sim.range_world`). So after step ``t`` every
beacon has been ranged ``n = t + 1`` times, and one axis serves the landmark and the robot errors.
The filter knows the start, the commanded controls, the noise levels and that the bias is 0; it does
not know where the beacons are.

**The methods** (:data:`METHODS`):

* ``dead_reckoning``: the commanded controls integrated (the robot only);
* ``fastslam``: FastSLAM 2.0 with :data:`~jaxnav.models.observation.RANGE_ONLY`: a new beacon is one
  Gaussian per particle, straight ahead of the robot at its first range, with the ring's spread;
* ``fastslam_ring``: FastSLAM 2.0 with :data:`~jaxnav.models.observation.RANGE_ONLY_RING`: each particle
  puts the new beacon at its own point of the ring, so the particle set holds the ring;
* ``pf_slam``, ``ps_slam``: a particle set per beacon started along the ring
  (:data:`~jaxnav.models.range_only.RANGE_ONLY_LANDMARK_SENSOR`), the robot weighted against the sets
  (``robot_likelihood="mixture"``); PS-SLAM with lag 10 and 1 cm jitter.

Particles: 200 robot particles and 500 per beacon for PF-SLAM and PS-SLAM; 1000 for FastSLAM, five
times the robot's (a run of FastSLAM then takes about half as long as one of PF-SLAM: 1.0 s against
2.0 s on 2 CPU cores); ESS-triggered resampling at half.

**The errors** (:class:`Errors`, mm): after the step at which each beacon got its ``n``-th range, for
``n`` in :data:`OBSERVATIONS`, the robot's position error and the beacons' mean position error in the
world frame (fixed by the known start), and the beacons' mean error after the rigid transform that
best aligns the map with the true beacons: a SLAM map is only fixed up to the frame it started in, and
the heading error the odometry gathers before the rings collapse turns the whole map.

:data:`EXPERIMENTS` registers ``range-only-slam`` (run with :func:`jaxnav.experiments.registry.run`);
:func:`plot_clouds` draws one run's landmark clouds collapsing from rings to points.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import metrics
from jaxnav.core.validation import check_choice
from jaxnav.experiments import curves
from jaxnav.experiments.experiment import Cell
from jaxnav.models import motion
from jaxnav.models import range_only as ro
from jaxnav.sim import range_world, trajectories
from jaxnav.slam import fastslam, pf_slam, ps_slam

__all__ = [
    "METHODS",
    "METHOD_LABELS",
    "OBSERVATIONS",
    "QUICK",
    "RangeSetting",
    "World",
    "Errors",
    "make_world",
    "run_method",
    "errors_at",
    "error_cell",
    "observations",
    "SLAM_METHODS",
    "dead_reckoning",
    "plot_clouds",
    "EXPERIMENTS",
]

METHODS = ("dead_reckoning", "fastslam", "fastslam_ring", "pf_slam", "ps_slam")
"""The methods of the experiment, in the order of its table."""
METHOD_LABELS = {
    "dead_reckoning": "dead reckoning",
    "fastslam": "FastSLAM 2.0, beacon ahead",
    "fastslam_ring": "FastSLAM 2.0, beacon around the ring",
    "pf_slam": "PF-SLAM",
    "ps_slam": "PS-SLAM",
}
"""The names of :data:`METHODS` in the tables and figures."""
SLAM_METHODS = METHODS[1:]
"""The methods that map the beacons."""
OBSERVATIONS = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)
"""The numbers of ranges per beacon at which the errors are scored (the points of the curves)."""
QUICK = dict(steps=200, robot_particles=100, beacon_particles=200, fastslam_particles=200)
"""The quick variant's changes — 200 steps instead of 1000 (the points up to 200 ranges), fewer particles."""


@dataclass(frozen=True)
class RangeSetting:
    """The simulated range-only world and the filters' sizes (SI units; hashable, static under ``jit``).

    Attributes:
        num_beacons: beacons, uniform over the room in each run.
        room: side of the square room (m).
        steps: steps of the drive (one range to every beacon per step).
        dt: step (s); speed, turn_rate: the circle's commanded speeds (m/s, rad/s).
        start: the known start pose (m, m, rad).
        motion_alpha: ``a`` of the velocity model's ``α = (a, a/2, a/2, a, 0, 0)``; pose_sd: its additive
            pose noise per step (m and rad).
        range_sd: the ranges' standard deviation (m; no bias).
        robot_particles, beacon_particles: PF-SLAM's and PS-SLAM's ``I`` and ``J``.
        fastslam_particles: FastSLAM's particles.
        ps_lag, ps_jitter: PS-SLAM's lag (steps) and beacon jitter (m).
    """

    num_beacons: int = 6
    room: float = 8.0
    steps: int = 1000
    dt: float = 0.1
    speed: float = 0.3
    turn_rate: float = 0.15
    start: tuple[float, float, float] = (4.0, 2.0, 0.0)
    motion_alpha: float = 0.1
    pose_sd: float = 0.002
    range_sd: float = 0.1
    robot_particles: int = 200
    beacon_particles: int = 500
    fastslam_particles: int = 1000
    ps_lag: int = 10
    ps_jitter: float = 0.01

    def motion_noise(self) -> motion.VelocityNoise:
        a = self.motion_alpha
        return motion.VelocityNoise(jnp.asarray([a, a / 2, a / 2, a, 0.0, 0.0]), jnp.full(3, self.pose_sd))

    def range_noise(self) -> ro.RangeNoise:
        return ro.range_noise(self.range_sd, 0.0)

    def controls(self) -> jax.Array:
        return trajectories.loop_controls(self.steps, self.speed, self.turn_rate, self.dt)

    def start_pose(self) -> jax.Array:
        return jnp.asarray(self.start, jnp.result_type(float))


class World(NamedTuple):
    """One run's world: ``beacons [M, 2]`` (m) and the simulated drive (:class:`~jaxnav.sim.range_world.RangeRun`)."""

    beacons: jax.Array
    drive: range_world.RangeRun


class Errors(NamedTuple):
    """One run's errors at the points of :data:`OBSERVATIONS` that its drive reaches (mm).

    Attributes:
        robot_mm: ``[P]`` robot position error after each beacon's ``n``-th range.
        landmark_mm: ``[P]`` mean beacon position error then (NaN for dead reckoning, which maps nothing).
        aligned_mm: ``[P]`` the same after the rigid transform that best aligns the estimated beacons with
            the true ones (:func:`jaxnav.metrics.align_rigid`): the map's shape, without the error of its
            frame.
    """

    robot_mm: jax.Array
    landmark_mm: jax.Array
    aligned_mm: jax.Array


def observations(setting: RangeSetting) -> tuple[int, ...]:
    """The points of :data:`OBSERVATIONS` that ``setting``'s drive reaches."""
    return tuple(n for n in OBSERVATIONS if n <= setting.steps)


def make_world(key: jax.Array, setting: RangeSetting) -> World:
    """Beacons uniform over the room and the drive among them (pure in ``key``; ``vmap`` it over keys)."""
    k_beacons, k_drive = jax.random.split(key)
    dtype = jnp.result_type(float)
    beacons = jax.random.uniform(k_beacons, (setting.num_beacons, 2), dtype, 0.0, setting.room)
    drive = range_world.simulate(
        k_drive,
        beacons,
        setting.start_pose(),
        setting.controls(),
        setting.motion_noise(),
        setting.range_noise(),
        motion_model="velocity",
    )
    return World(beacons, drive)


def dead_reckoning(setting: RangeSetting, controls: jax.Array) -> jax.Array:
    """``[T, 3]`` the commanded controls integrated by the noise-free velocity model."""
    return trajectories.integrate_controls(setting.start_pose().astype(controls.dtype), controls, "velocity")


def _filter(method: str, setting: RangeSetting):
    """``(module, config, params)`` of a SLAM method."""
    noise, drive = setting.range_noise(), setting.motion_noise()
    m = setting.num_beacons
    if method in ("fastslam", "fastslam_ring"):
        config = fastslam.FastSLAMConfig(
            num_particles=setting.fastslam_particles,
            num_landmarks=m,
            version=2,
            motion_model="velocity",
            observation_model="range_only" if method == "fastslam" else "range_only_ring",
            ess_threshold=0.5,
        )
        return fastslam, config, fastslam.FastSLAMParams(drive, noise)
    common = dict(
        num_particles=setting.robot_particles,
        num_tag_particles=setting.beacon_particles,
        max_tags=m,
        motion_model="velocity",
        sensor=ro.RANGE_ONLY_LANDMARK_SENSOR,
        robot_likelihood="mixture",
        ess_threshold=0.5,
    )
    if method == "pf_slam":
        return pf_slam, pf_slam.PFSLAMConfig(**common), pf_slam.PFSLAMParams(drive, noise)
    config = ps_slam.PSSLAMConfig(lag=setting.ps_lag, **common)
    return ps_slam, config, ps_slam.PSSLAMParams(drive, noise, jnp.asarray(setting.ps_jitter, jnp.float32))


def run_method(key: jax.Array, method: str, setting: RangeSetting, world: World) -> tuple[jax.Array, jax.Array]:
    """Run ``method`` on ``world``'s controls and ranges: ``(poses [T, 3], beacons [T, M, 2])``, the robot
    estimate and the map estimate after every step (dead reckoning maps nothing: NaN beacons)."""
    check_choice("method", method, METHODS)
    controls = world.drive.controls
    if method == "dead_reckoning":
        poses = dead_reckoning(setting, controls)
        return poses, jnp.full((controls.shape[0],) + world.beacons.shape, jnp.nan, poses.dtype)
    module, config, params = _filter(method, setting)
    k_init, k_run = jax.random.split(key)
    state = module.init(k_init, config, params, setting.start_pose())

    def body(state, inputs):  # the pure kernel: this runs inside the cell's own jit and vmap
        k, u, obs = inputs
        state, info = module.kernel(k, state, config, params, u, obs)
        return state, (info.estimate, module.map_estimate(state)[0])

    keys = jax.random.split(k_run, controls.shape[0])
    return jax.lax.scan(body, state, (keys, controls, world.drive.observations))[1]


def errors_at(setting: RangeSetting, world: World, poses: jax.Array, beacons: jax.Array) -> Errors:
    """The :class:`Errors` of a run's per-step estimates at :func:`observations`."""
    at = jnp.asarray(observations(setting)) - 1  # the step at which every beacon got its n-th range
    robot = jnp.linalg.norm(poses[at, :2] - world.drive.true_poses[at, :2], axis=-1)
    landmark = jnp.linalg.norm(beacons[at] - world.beacons, axis=-1).mean(axis=-1)

    def aligned(estimate):
        rotation, translation = metrics.align_rigid(estimate, world.beacons)
        return jnp.linalg.norm(estimate @ rotation.T + translation - world.beacons, axis=-1).mean()

    shape = jax.vmap(aligned)(jnp.nan_to_num(beacons[at]))  # dead reckoning's NaN map: NaN below
    return Errors(1000 * robot, 1000 * landmark, jnp.where(jnp.isnan(landmark), jnp.nan, 1000 * shape))


def error_cell(method: str, setting: RangeSetting):
    """A cell's run: ``key -> Errors`` of ``method`` on a fresh world (pure; ``vmap`` it over keys)."""

    def fn(key):
        k_world, k_filter = jax.random.split(key)
        world = make_world(k_world, setting)
        return errors_at(setting, world, *run_method(k_filter, method, setting, world))

    return fn


# ---------------------------------------------------------------------------
# the experiment


def _setting(quick: bool) -> RangeSetting:
    return replace(RangeSetting(), **QUICK) if quick else RangeSetting()


def _cells(quick: bool) -> list[Cell]:
    s = _setting(quick)
    return [Cell(m, m, m, s, error_cell(m, s)) for m in METHODS]


def _summary(raw: dict, cells: list[Cell], quick: bool) -> list[dict]:
    out = []
    for quantity, field, methods in (
        ("robot error (mm)", "robot_mm", METHODS),
        ("beacon error (mm)", "landmark_mm", SLAM_METHODS),
        ("beacon error, map aligned (mm)", "aligned_mm", SLAM_METHODS),
    ):
        for c in cells:
            if c.method not in methods:
                continue
            r = raw[c.id]
            diverged = ~np.all(np.isfinite(r["robot_mm"]), axis=1)
            if c.method in SLAM_METHODS:
                diverged |= ~np.all(np.isfinite(r["landmark_mm"]), axis=1)
            values = np.asarray(r[field], np.float64)
            xs = observations(c.setting)
            out.append(
                {
                    "method": c.method,
                    "quantity": quantity,
                    **curves.summarize_points(xs, [values[:, i] for i in range(len(xs))], [diverged] * len(xs)),
                }
            )
    return out


def _title(result: dict) -> str:
    head = f"{result['experiment']}: {result['title']}"
    if not result.get("quick"):
        return head
    q = QUICK
    return (
        f"{head}\nquick variant ({q['steps']} steps, {q['robot_particles']} robot and {q['beacon_particles']} "
        f"beacon particles, FastSLAM {q['fastslam_particles']}): not the full experiment"
    )


def _plot_options(result: dict) -> dict:
    return {"labels": METHOD_LABELS, "title": _title, "log_y": True}


def _draw_curves(result: dict):
    """The figure of :func:`plot_curves`."""
    return curves.draw(result, **_plot_options(result))


def plot_curves(result: dict, path: str) -> None:
    """The robot and beacon errors against the ranges per beacon, with their 95 % intervals; a PNG at ``path``."""
    curves.plot(result, path, **_plot_options(result))


RANGE_ONLY_SLAM = curves.curve_experiment(
    "range-only-slam",
    "Range-only SLAM among six unknown beacons: errors against the ranges per beacon",
    "ranges per beacon",
    _cells,
    _summary,
    notes=(
        "A particle set per beacon holds the ring a first range leaves; one Gaussian per FastSLAM particle "
        "does not. Every beacon is ranged at every step: n ranges per beacon = n steps."
    ),
    x_log=True,
    labels=METHOD_LABELS,
)
RANGE_ONLY_SLAM = replace(RANGE_ONLY_SLAM, plot=plot_curves)

EXPERIMENTS = (RANGE_ONLY_SLAM,)
"""The study's experiments (listed by :mod:`jaxnav.experiments.catalog`)."""


# ---------------------------------------------------------------------------
# the clouds


def _snapshots(key: jax.Array, method: str, setting: RangeSetting, world: World, at: tuple[int, ...]) -> list[Any]:
    """``(robot estimate [3], landmark particles [M, P, 2])`` after each step ``n − 1`` of ``at``: a beacon's
    particles for PF-SLAM, each FastSLAM particle's beacon means otherwise."""
    module, config, params = _filter(method, setting)
    k_init, k_run = jax.random.split(key)
    state = module.init(k_init, config, params, setting.start_pose())
    controls, obs = world.drive.controls, world.drive.observations
    out, done = [], 0
    for i, n in enumerate(at):
        segment = jax.tree_util.tree_map(lambda a: a[done:n], obs)
        state, trace = module.run(jax.random.fold_in(k_run, i), state, config, params, controls[done:n], segment)
        done = n
        cloud = state.tags.particles if module is not fastslam else jnp.swapaxes(state.means, 0, 1)
        out.append((np.asarray(trace.estimate[-1]), np.asarray(cloud)))
    return out


def _draw_clouds(setting: RangeSetting, world: World, snapshots: dict, at: tuple[int, ...]):
    import matplotlib.pyplot as plt

    rows = list(snapshots)
    fig, axes = plt.subplots(
        len(rows), len(at), figsize=(3.2 * len(at), 3.4 * len(rows)), squeeze=False, layout="constrained"
    )
    beacons = np.asarray(world.beacons)
    truth = np.asarray(world.drive.true_poses)
    colors = plt.get_cmap("tab10")
    for r, method in enumerate(rows):
        for c, n in enumerate(at):
            ax = axes[r][c]
            estimate, cloud = snapshots[method][c]
            ax.plot(truth[:n, 0], truth[:n, 1], "-", color="0.6", lw=0.8)
            for b in range(cloud.shape[0]):
                ax.plot(cloud[b, :, 0], cloud[b, :, 1], ".", ms=1.0, color=colors(b % 10), alpha=0.4)
            ax.plot(beacons[:, 0], beacons[:, 1], "k*", ms=9)
            ax.plot(*estimate[:2], "o", mfc="none", mec="k", ms=6)
            ax.set_xlim(-2.0, setting.room + 2.0)
            ax.set_ylim(-2.0, setting.room + 2.0)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{METHOD_LABELS[method]}\nafter {n} range{'s' * (n != 1)} per beacon", fontsize=8)
    fig.suptitle(
        "Beacon clouds: PF-SLAM's particles per beacon, and each FastSLAM particle's beacon estimate "
        "(★ true beacons, ○ robot estimate, grey: the true path)",
        fontsize=9,
    )
    return fig


def plot_clouds(
    path: str,
    seed: int = 0,
    at: tuple[int, ...] = (1, 10, 30, 100, 1000),
    methods: tuple[str, ...] = ("pf_slam", "fastslam_ring"),
    setting: RangeSetting = RangeSetting(),
) -> None:
    """One run of the ``range-only-slam`` experiment's world (key ``seed``): each method's landmark clouds after
    ``n`` ranges per beacon for each ``n`` of ``at`` (a row per method), as a PNG at ``path``."""
    for m in methods:
        check_choice("methods", m, SLAM_METHODS)
    at = tuple(int(n) for n in at)
    if not at or any(b <= a for a, b in zip(at, at[1:])) or at[0] < 1 or at[-1] > setting.steps:
        raise ValueError(f"at must increase within [1, {setting.steps}], got {at!r}")
    import matplotlib.pyplot as plt

    k_world, k_filter = jax.random.split(jax.random.PRNGKey(seed))
    world = make_world(k_world, setting)
    snapshots = {m: _snapshots(k_filter, m, setting, world, at) for m in methods}
    fig = _draw_clouds(setting, world, snapshots, at)
    fig.savefig(path, dpi=110)
    plt.close(fig)
