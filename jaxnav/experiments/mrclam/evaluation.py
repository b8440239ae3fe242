"""Classical filters on real data: UTIAS MRCLAM dataset 7, robots 1–3.

Runs dead reckoning, EKF and UKF localization, MCL (known map), EKF-SLAM,
FastSLAM 1.0/2.0, PF-SLAM and PS-SLAM (a particle set per landmark, with the range-bearing
landmark sensor) on a robot's log (:mod:`jaxnav.io.mrclam`) and scores them
against the Vicon ground truth (:mod:`jaxnav.metrics`):

* trajectory: position and heading RMSE over every step, starting from the
  known initial pose (every filter starts there, with a small covariance),
  and the ATE (position RMSE after a rigid alignment of the whole path);
* map (SLAM only): landmark RMSE in the world frame — the frame is fixed by
  the known initial pose, the convention of the dataset's notes — and after a
  rigid alignment (the map's shape alone), over the landmarks the filter
  mapped: ``√((1/n) Σ_mapped ‖m̂ − m‖²)``. A run that mapped no landmark has
  nothing to score: its map errors are NaN (printed "n/a (nothing mapped)"),
  not 0.

Settings (:class:`MRCLAMSettings`) were chosen on the first 300 s of robot 1
and used unchanged for robots 2 and 3: the odometry's heading drifts fast
(dead reckoning's heading RMSE is 0.8 rad over 300 s), so the motion noise
is generous; the sensor noise is about twice the residual spread that the
dataset notes report, and the Gaussian filters gate at 99.9 % because
0.5–3.6 % of range residuals exceed 0.5 m. PF-SLAM and PS-SLAM keep 100 robot particles and
100 particles per landmark; PF-SLAM weights the robot against each landmark's particle set
(``robot_likelihood="mixture"``), PS-SLAM against its smoothed estimate, with a lag of 10 and a
1 cm jitter (on robot 1's first 300 s, with seeds 0 and 1, the aligned path error, ATE, was 0.20
and 0.23 m for PF-SLAM and 0.21 and 0.20 m for PS-SLAM with these choices; 0.28 m for PF-SLAM
weighting against the estimate, 0.24 m for PS-SLAM weighting against the particle sets). Measurements of other robots are
kept with out-of-map ids: every filter ignores them and counts them.

Usage::

    from jaxnav.experiments import mrclam as xp
    seq, results = xp.run_robot(1, duration=300.0)
    print(xp.format_table([(1, r) for r in results]))
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import metrics
from jaxnav.experiments import report
from jaxnav.io import mrclam as data
from jaxnav.localization import ekf, mcl, ukf
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.slam import ekf_slam, fastslam, pf_slam, ps_slam

__all__ = [
    "ALGORITHMS",
    "MRCLAMSettings",
    "AlgorithmResult",
    "run_algorithm",
    "run_robot",
    "format_table",
    "plot_robot",
    "NOTHING_MAPPED",
]

ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "ekf_slam", "fastslam1", "fastslam2", "pf_slam", "ps_slam")
"""The algorithms :func:`run_algorithm` runs, in the order of the tables."""
NOTHING_MAPPED = f"{report.NA} (nothing mapped)"
"""How a map error is written when the run mapped no landmark."""


@dataclass(frozen=True)
class MRCLAMSettings:
    """Noise levels and sizes for the MRCLAM runs (SI units).

    Attributes:
        dt: filter step (s); measurements are within ``dt/2`` of their step.
        max_obs: observation slots per step.
        alphas: velocity-model variance coefficients α₁…α₆ (Thrun Tab. 5.3).
        pose_sd: additive pose noise per step (m, m, rad).
        sensor_sd: range-bearing noise (m, rad).
        gate_probability: χ² gate of the Gaussian filters.
        initial_sd: spread of the initial belief around the true initial pose (m, m, rad).
        mcl_particles, fastslam_particles: particle counts.
        tag_slam_particles: robot particles of PF-SLAM and PS-SLAM.
        landmark_particles: particles per landmark of PF-SLAM and PS-SLAM.
        pf_slam_robot_likelihood, ps_slam_robot_likelihood: how each weights the robot
            (:class:`jaxnav.slam.tag_slam.TagSLAMConfig` ``robot_likelihood``).
        ps_slam_lag: PS-SLAM's lag ``L``.
        ps_slam_jitter: PS-SLAM's landmark jitter (m).
    """

    dt: float = 0.1
    max_obs: int = 16
    alphas: tuple[float, ...] = (0.2, 0.02, 0.02, 0.2, 0.0, 0.0)
    pose_sd: tuple[float, float, float] = (0.01, 0.01, 0.02)
    sensor_sd: tuple[float, float] = (0.2, 0.05)
    gate_probability: float = 0.999
    initial_sd: tuple[float, float, float] = (0.01, 0.01, 0.01)
    mcl_particles: int = 500
    fastslam_particles: int = 100
    tag_slam_particles: int = 100
    landmark_particles: int = 100
    pf_slam_robot_likelihood: str = "mixture"
    ps_slam_robot_likelihood: str = "estimate"
    ps_slam_lag: int = 10
    ps_slam_jitter: float = 0.01

    def motion_noise(self) -> motion.VelocityNoise:
        return motion.VelocityNoise(jnp.asarray(self.alphas, jnp.float32), jnp.asarray(self.pose_sd, jnp.float32))

    def sensor_noise(self) -> lm.RangeBearingNoise:
        return lm.RangeBearingNoise(jnp.asarray(self.sensor_sd, jnp.float32))

    def initial_cov(self) -> jax.Array:
        return jnp.diag(jnp.asarray(self.initial_sd, jnp.float32) ** 2)


class AlgorithmResult(NamedTuple):
    """One algorithm on one sequence.

    Attributes:
        name: algorithm name (one of :data:`~jaxnav.experiments.mrclam.evaluation.ALGORITHMS`).
        estimates: ``[T, 3]`` pose estimates.
        landmarks: ``[M, 2]`` map estimate (SLAM) or None.
        seen: ``[M]`` bool, mapped landmarks (SLAM) or None.
        seconds: wall time of the run, compilation included (s).
        trajectory: :class:`jaxnav.metrics.TrajectoryError`.
        ate: position RMSE after rigid alignment of the path (m).
        map: :class:`jaxnav.metrics.MapError` over the seen landmarks (SLAM) or None; its
            RMSEs are NaN when no landmark was seen (nothing to score).
    """

    name: str
    estimates: np.ndarray
    landmarks: np.ndarray | None
    seen: np.ndarray | None
    seconds: float
    trajectory: metrics.TrajectoryError
    ate: float
    map: metrics.MapError | None


def _dead_reckoning(key, seq, s):
    return data.dead_reckoning(seq), None, None


def _gaussian(module, config):
    def run(key, seq, s):
        params = ekf.KalmanParams(s.motion_noise(), s.sensor_noise(), seq.landmarks)
        state = module.init(None, config(s), params, seq.initial_pose, s.initial_cov())
        _, trace = module.run(None, state, config(s), params, seq.controls, seq.observations)
        return trace.estimate, None, None

    return run


def _mcl(key, seq, s):
    cfg = mcl.MCLConfig(num_particles=s.mcl_particles, ess_threshold=0.5)
    params = mcl.MCLParams(s.motion_noise(), s.sensor_noise(), seq.landmarks)
    k_init, k_run = jax.random.split(key)
    state = mcl.init(k_init, cfg, params, seq.initial_pose, jnp.asarray(s.initial_sd))
    _, trace = mcl.run(k_run, state, cfg, params, seq.controls, seq.observations)
    return trace.estimate, None, None


def _ekf_slam(key, seq, s):
    cfg = ekf_slam.EKFSLAMConfig(num_landmarks=seq.landmarks.shape[0], gate_probability=s.gate_probability)
    params = ekf_slam.EKFSLAMParams(s.motion_noise(), s.sensor_noise())
    state = ekf_slam.init(None, cfg, params, seq.initial_pose, s.initial_cov())
    final, trace = ekf_slam.run(None, state, cfg, params, seq.controls, seq.observations)
    return trace.estimate, trace.landmarks[-1], trace.seen[-1]


def _fastslam(version):
    def run(key, seq, s):
        cfg = fastslam.FastSLAMConfig(
            num_particles=s.fastslam_particles, num_landmarks=seq.landmarks.shape[0], version=version, ess_threshold=0.5
        )
        params = fastslam.FastSLAMParams(s.motion_noise(), s.sensor_noise())
        k_init, k_run = jax.random.split(key)
        state = fastslam.init(k_init, cfg, params, seq.initial_pose, jnp.asarray(s.initial_sd))
        final, trace = fastslam.run(k_run, state, cfg, params, seq.controls, seq.observations)
        landmarks, seen = fastslam.map_estimate(final)
        return trace.estimate, landmarks, seen

    return run


def _landmark_slam(module):
    def run(key, seq, s):
        common = dict(
            num_particles=s.tag_slam_particles,
            num_tag_particles=s.landmark_particles,
            max_tags=seq.landmarks.shape[0],  # other robots' ids lie outside the table: dropped and counted
            motion_model="velocity",
            sensor=lm.RANGE_BEARING_LANDMARK_SENSOR,
            ess_threshold=0.5,
        )
        if module is pf_slam:
            cfg = pf_slam.PFSLAMConfig(robot_likelihood=s.pf_slam_robot_likelihood, **common)
            params = pf_slam.PFSLAMParams(s.motion_noise(), s.sensor_noise())
        else:
            cfg = ps_slam.PSSLAMConfig(robot_likelihood=s.ps_slam_robot_likelihood, lag=s.ps_slam_lag, **common)
            jitter = jnp.asarray(s.ps_slam_jitter, jnp.float32)
            params = ps_slam.PSSLAMParams(s.motion_noise(), s.sensor_noise(), jitter)
        k_init, k_run = jax.random.split(key)
        state = module.init(k_init, cfg, params, seq.initial_pose, jnp.asarray(s.initial_sd))
        final, trace = module.run(k_run, state, cfg, params, seq.controls, seq.observations, donate_state=True)
        landmarks, seen = module.map_estimate(final)
        return trace.estimate, landmarks, seen

    return run


_RUNNERS: dict[str, Callable] = {
    "dead_reckoning": _dead_reckoning,
    "ekf": _gaussian(ekf, lambda s: ekf.EKFConfig(gate_probability=s.gate_probability)),
    "ukf": _gaussian(ukf, lambda s: ukf.UKFConfig(gate_probability=s.gate_probability)),
    "mcl": _mcl,
    "ekf_slam": _ekf_slam,
    "fastslam1": _fastslam(1),
    "fastslam2": _fastslam(2),
    "pf_slam": _landmark_slam(pf_slam),
    "ps_slam": _landmark_slam(ps_slam),
}


def run_algorithm(
    name: str, seq: data.MRCLAMSequence, key: jax.Array, settings: MRCLAMSettings = MRCLAMSettings()
) -> AlgorithmResult:
    """Run one algorithm on a sequence and score it against the ground truth."""
    if name not in _RUNNERS:
        raise ValueError(f"algorithm must be one of {list(ALGORITHMS)}, got {name!r}")
    start = time.perf_counter()
    est, landmarks, seen = jax.block_until_ready(_RUNNERS[name](key, seq, settings))
    seconds = time.perf_counter() - start
    traj = metrics.trajectory_rmse(est, seq.true_poses)
    ate = float(metrics.absolute_trajectory_error(est, seq.true_poses))
    map_err = None
    if landmarks is not None:
        map_err = metrics.map_errors(landmarks, seq.landmarks, seen)
        landmarks, seen = np.asarray(landmarks), np.asarray(seen)
        if not seen.any():  # nothing mapped: nothing to score
            map_err = map_err._replace(rmse=jnp.asarray(jnp.nan), aligned_rmse=jnp.asarray(jnp.nan))
    return AlgorithmResult(name, np.asarray(est), landmarks, seen, seconds, traj, ate, map_err)


def run_robot(
    robot: int,
    algorithms: Sequence[str] = ALGORITHMS,
    duration: float | None = None,
    t_start: float | None = None,
    settings: MRCLAMSettings = MRCLAMSettings(),
    seed: int = 0,
    root: str | None = None,
) -> tuple[data.MRCLAMSequence, list[AlgorithmResult]]:
    """Load robot ``robot`` (1–3), run ``algorithms`` on it and score them.

    Args:
        duration, t_start: the segment (s; default the whole 900 s log).
        seed: PRNG seed of the particle filters.
        root: data folder (default ``$JAXNAV_DATA``, else ``../shared/data`` relative to the repository;
            :func:`jaxnav.io.mrclam.data_dir`).
    """
    for name in algorithms:
        if name not in _RUNNERS:
            raise ValueError(f"algorithm must be one of {list(ALGORITHMS)}, got {name!r}")
    seq = data.to_filter_steps(
        data.load_robot(robot, root),
        dt=settings.dt,
        t_start=t_start,
        duration=duration,
        max_obs=settings.max_obs,
        keep_outliers=True,
    )
    key = jax.random.PRNGKey(seed)
    results = [run_algorithm(name, seq, jax.random.fold_in(key, i), settings) for i, name in enumerate(algorithms)]
    return seq, results


def format_table(rows: Sequence[tuple[int, AlgorithmResult]]) -> str:
    """Markdown table of ``(robot, result)`` rows: RMSEs in mm and mrad as [W]'s tables print them.

    Localization filters have no map (:data:`jaxnav.experiments.report.NONE`); a SLAM run that
    mapped no landmark has nothing to score (:data:`~jaxnav.experiments.mrclam.evaluation.NOTHING_MAPPED`).
    """
    heads = [
        "robot",
        "algorithm",
        "position RMSE (mm)",
        "heading RMSE (mrad)",
        "ATE, aligned path (mm)",
        "landmark RMSE (mm)",
        "aligned landmark RMSE (mm)",
        "time (s)",
    ]
    cells = []
    for robot, r in rows:
        lm_raw = None if r.map is None else 1e3 * float(r.map.rmse)
        lm_al = None if r.map is None else 1e3 * float(r.map.aligned_rmse)
        cells.append(
            [
                str(robot),
                r.name,
                report.number(1e3 * float(r.trajectory.position_rmse), 0),
                report.number(1e3 * float(r.trajectory.heading_rmse), 0),
                report.number(1e3 * r.ate, 0),
                report.number(lm_raw, 0, nan=NOTHING_MAPPED),
                report.number(lm_al, 0, nan=NOTHING_MAPPED),
                report.number(r.seconds, 1),
            ]
        )
    return report.markdown(heads, cells)


_COLORS = {
    "dead_reckoning": "tab:gray",
    "ekf": "tab:orange",
    "ukf": "tab:green",
    "mcl": "tab:red",
    "ekf_slam": "tab:purple",
    "fastslam1": "tab:brown",
    "fastslam2": "tab:blue",
    "pf_slam": "tab:olive",
    "ps_slam": "tab:cyan",
}
"""One colour per algorithm, in both panels and for a SLAM map's landmarks."""
_MAP_MARKERS = {"ekf_slam": "o", "fastslam1": "s", "fastslam2": "^", "pf_slam": "D", "ps_slam": "v"}
DISPLAY_NAMES = {
    "dead_reckoning": "dead reckoning",
    "ekf": "EKF",
    "ukf": "UKF",
    "mcl": "MCL",
    "ekf_slam": "EKF-SLAM",
    "fastslam1": "FastSLAM 1.0",
    "fastslam2": "FastSLAM 2.0",
    "pf_slam": "PF-SLAM",
    "ps_slam": "PS-SLAM",
}
"""The algorithms' names in figures."""


def display_name(name: str) -> str:
    """An algorithm's name as a figure shows it (the name itself when it has none)."""
    return DISPLAY_NAMES.get(name, name)


def _draw_robot(seq: data.MRCLAMSequence, results: Sequence[AlgorithmResult]):
    """The figure of :func:`plot_robot`."""
    import matplotlib.pyplot as plt

    fig, (ax_path, ax_err) = plt.subplots(1, 2, figsize=(14, 6.2), layout="constrained")
    truth = np.asarray(seq.true_poses)
    lms = np.asarray(seq.landmarks)
    ax_path.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="Vicon ground truth")
    ax_path.plot(lms[:, 0], lms[:, 1], "k*", ms=12, label="landmarks (surveyed)")
    times = np.arange(truth.shape[0]) * seq.dt
    for i, r in enumerate(results):
        color = _COLORS.get(r.name, f"C{i}")
        style = "--" if r.name == "dead_reckoning" else "-"  # grey and brown are close: dashed apart
        ax_path.plot(r.estimates[:, 0], r.estimates[:, 1], style, color=color, lw=1, label=display_name(r.name))
        if r.landmarks is not None:
            seen = r.seen.astype(bool)
            ax_path.plot(
                r.landmarks[seen, 0],
                r.landmarks[seen, 1],
                _MAP_MARKERS.get(r.name, "x"),
                color=color,
                mfc="none",
                mew=1.5,
                ms=8,
                label=f"{display_name(r.name)} map ({int(seen.sum())} of {lms.shape[0]} landmarks, own frame)",
            )
        ax_err.plot(
            times,
            np.asarray(metrics.position_errors(r.estimates, truth)),
            style,
            color=color,
            lw=1,
            label=display_name(r.name),
        )
    ax_path.set_aspect("equal")
    ax_path.set_xlabel("x (m)")
    ax_path.set_ylabel("y (m)")
    ax_path.set_title(f"MRCLAM dataset 7, robot {seq.robot}: paths and maps")
    ax_err.set_yscale("log")
    ax_err.set_xlabel("time (s)")
    ax_err.set_ylabel("position error (m)")
    ax_err.set_title("position error against Vicon")
    ax_err.grid(alpha=0.3)
    # one legend for both panels (an algorithm has one colour in both), beside them (inside, it would hide the map)
    fig.legend(*ax_path.get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    return fig


def plot_robot(seq: data.MRCLAMSequence, results: Sequence[AlgorithmResult], path: str) -> None:
    """Paths and SLAM maps (left) against the ground truth, and the position error over time (right).

    The maps are drawn as each SLAM filter estimated them, in its own frame, without aligning them to
    the surveyed landmarks. Writes a PNG to ``path``."""
    import matplotlib.pyplot as plt

    fig = _draw_robot(seq, results)
    fig.savefig(path, dpi=110)
    plt.close(fig)
