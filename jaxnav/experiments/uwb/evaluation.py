"""Range-only localization and SLAM on the TU Chemnitz "Labyrinth" UWB log (:mod:`jaxnav.io.uwb`).

**The study.** A differential-drive robot drives 9.3 m in 30 s among four UWB anchors; at each of
233 steps it ranges one anchor. Algorithms (:data:`ALGORITHMS`):

* ``dead_reckoning``: the wheel speeds alone (:func:`jaxnav.io.uwb.dead_reckoning`);
* ``ekf``, ``ukf``: EKF and UKF localization with the surveyed anchors and the biased range model
  (:data:`~jaxnav.models.observation.RANGE_ONLY`; deterministic, one run);
* ``mcl``, ``mcl_t``: MCL with the surveyed anchors and the range-only pose sensor, Gaussian
  (:data:`~jaxnav.models.range_only.RANGE_ONLY_SENSOR`) or Student-t
  (:data:`~jaxnav.models.range_only.RANGE_ONLY_T_SENSOR`) noise;
* ``pf_slam``, ``ps_slam``: range-only SLAM, the anchors unknown
  (:data:`~jaxnav.models.range_only.RANGE_ONLY_LANDMARK_SENSOR`): a particle set per anchor that
  starts on the ring of its first range, the robot weighted against the sets
  (``robot_likelihood="mixture"``);
* ``fastslam``: FastSLAM 2.0 with the same range model and the anchors unknown, each anchor one
  Gaussian per particle, started straight ahead of the robot at its first range with the ring's spread
  (:data:`~jaxnav.models.observation.RANGE_ONLY`): the comparator without a particle set per anchor;
* ``fastslam_ring``: the same FastSLAM with each particle starting the anchor at its own point of the
  ring (:data:`~jaxnav.models.observation.RANGE_ONLY_RING`): the particle set holds the ring jointly.

Every filter starts from the known initial pose (ground truth, heading from the first 0.1 m of path).
Each particle filter runs ``runs`` times with different keys (one compiled program); the table gives
the mean and standard deviation over the runs of the mean position error against the ground truth
(m) and, for SLAM, of the anchors' mean error (m) in the world frame (fixed by the known start; no
alignment).

**Settings** (:class:`UWBSettings`), set once: wheel-speed noise 0.05 m/s per wheel (the file
states 0.01; with 0.02 SLAM's robot error is 20 % larger), the range model ``σ = 0.15`` m, bias ``b = 0.1`` m and ``ν = 4`` (near
the dataset's residual statistics: mean +0.12 m, standard deviation 0.11 m, a tail to 0.66 m),
1000 MCL particles, 300 robot particles and 1000 per anchor for PF-SLAM and PS-SLAM (a ring of 1–3 m
radius needs them; with 300 the anchors are two to three times farther off), 1000 particles for
FastSLAM (about 60 % of PF-SLAM's time; with 300 the ring start's errors are two to three times as
large), PS-SLAM's lag 10 and jitter 1 cm. The
bias is given, not learned: with ``b = 0`` MCL's error doubles (0.12–0.14 m against 0.06 m).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.experiments import report
from jaxnav.io import uwb as data
from jaxnav.localization import ekf, mcl, ukf
from jaxnav.models import landmarks as lm
from jaxnav.models import motion
from jaxnav.models import range_only as ro
from jaxnav.slam import fastslam, pf_slam, ps_slam

__all__ = ["ALGORITHMS", "SLAM", "UWBSettings", "UWBResult", "run_algorithm", "run_study", "format_table", "plot_study"]

ALGORITHMS = ("dead_reckoning", "ekf", "ukf", "mcl", "mcl_t", "fastslam", "fastslam_ring", "pf_slam", "ps_slam")
"""The algorithms :func:`run_algorithm` runs, in the order of the table."""
SLAM = ("fastslam", "fastslam_ring", "pf_slam", "ps_slam")
"""The algorithms that map the anchors."""
DETERMINISTIC = ("dead_reckoning", "ekf", "ukf")
"""The algorithms that use no key (run once)."""


@dataclass(frozen=True)
class UWBSettings:
    """Noise levels and sizes of the UWB study (SI units; module docstring).

    Attributes:
        wheel_sd: standard deviation of each wheel's speed (m/s).
        pose_sd: additive pose noise per step (m, m, rad).
        range_sd, range_bias, range_dof: the range model (m, m, degrees of freedom).
        initial_sd: spread of MCL's initial particles around the known start (m, m, rad).
        mcl_particles: MCL's particles.
        slam_particles, anchor_particles: PF-SLAM's and PS-SLAM's robot particles and particles per anchor.
        fastslam_particles: FastSLAM's particles.
        ps_lag, ps_jitter: PS-SLAM's lag and anchor jitter (m).
    """

    wheel_sd: float = 0.05
    pose_sd: tuple[float, float, float] = (0.005, 0.005, 0.02)
    range_sd: float = 0.15
    range_bias: float = 0.1
    range_dof: float = 4.0
    initial_sd: tuple[float, float, float] = (0.05, 0.05, 0.1)
    mcl_particles: int = 1000
    slam_particles: int = 300
    anchor_particles: int = 1000
    fastslam_particles: int = 1000
    ps_lag: int = 10
    ps_jitter: float = 0.01

    def motion_noise(self) -> motion.WheelNoise:
        return motion.WheelNoise(jnp.full(2, self.wheel_sd, jnp.float32), jnp.asarray(self.pose_sd, jnp.float32))

    def range_noise(self) -> ro.RangeNoise:
        return ro.range_noise(self.range_sd, self.range_bias, self.range_dof)


class UWBResult(NamedTuple):
    """One algorithm over ``R`` runs.

    Attributes:
        name: one of :data:`ALGORITHMS`.
        estimates: ``[R, T, 3]`` pose estimates of each run.
        anchors: ``[R, 4, 2]`` anchor estimates (SLAM) or None.
        position_error: ``[R]`` mean position error of each run against the ground truth (m).
        anchor_error: ``[R]`` mean anchor error of each run (m; SLAM) or None.
        seconds: wall time of all runs, compilation included (s).
    """

    name: str
    estimates: np.ndarray
    anchors: np.ndarray | None
    position_error: np.ndarray
    anchor_error: np.ndarray | None
    seconds: float


def _inputs(seq: data.UWBSequence):
    dtype = jnp.result_type(float)
    controls = jnp.asarray(seq.controls, dtype)
    obs = ro.RangeObs(*(jnp.asarray(a) for a in seq.observations))
    obs = obs._replace(z=obs.z.astype(dtype))
    return controls, obs, jnp.asarray(seq.initial_pose, dtype)


def _dead_reckoning(key, seq, s):
    return data.dead_reckoning(seq), None


def _kalman(module, config_type):
    def run(key, seq, s):
        controls, obs, start = _inputs(seq)
        params = ekf.KalmanParams(s.motion_noise(), s.range_noise(), jnp.asarray(seq.anchors, start.dtype))
        config = config_type(motion_model=seq.motion_model, observation_model="range_only")
        cov = jnp.diag(jnp.asarray(s.initial_sd, start.dtype) ** 2)
        state = module.init(None, config, params, start, cov)
        _, trace = module.run(None, state, config, params, controls, obs)
        return trace.estimate, None

    return run


def _fastslam(observation_model):
    def run(key, seq, s):
        controls, obs, start = _inputs(seq)
        config = fastslam.FastSLAMConfig(
            num_particles=s.fastslam_particles,
            num_landmarks=seq.anchors.shape[0],
            version=2,
            motion_model=seq.motion_model,
            observation_model=observation_model,
            ess_threshold=0.5,
        )
        params = fastslam.FastSLAMParams(s.motion_noise(), s.range_noise())
        k_init, k_run = jax.random.split(key)
        state = fastslam.init(k_init, config, params, start)
        final, trace = fastslam.run(k_run, state, config, params, controls, obs)
        return trace.estimate, fastslam.map_estimate(final)[0]

    return run


def _mcl(sensor):
    def run(key, seq, s):
        controls, obs, start = _inputs(seq)
        params = lm.LandmarkMapParams(s.motion_noise(), s.range_noise(), jnp.asarray(seq.anchors, start.dtype))
        cfg = mcl.MCLConfig(
            num_particles=s.mcl_particles, motion_model=seq.motion_model, sensor=sensor, ess_threshold=0.5
        )
        k_init, k_run = jax.random.split(key)
        state = mcl.init(k_init, cfg, params, start, jnp.asarray(s.initial_sd))
        _, trace = mcl.run(k_run, state, cfg, params, controls, obs)
        return trace.estimate, None

    return run


def _slam(module):
    def run(key, seq, s):
        controls, obs, start = _inputs(seq)
        common = dict(
            num_particles=s.slam_particles,
            num_tag_particles=s.anchor_particles,
            max_tags=seq.anchors.shape[0],
            motion_model=seq.motion_model,
            sensor=ro.RANGE_ONLY_LANDMARK_SENSOR,
            robot_likelihood="mixture",
            ess_threshold=0.5,
        )
        if module is pf_slam:
            cfg = pf_slam.PFSLAMConfig(**common)
            params = pf_slam.PFSLAMParams(s.motion_noise(), s.range_noise())
        else:
            cfg = ps_slam.PSSLAMConfig(lag=s.ps_lag, **common)
            params = ps_slam.PSSLAMParams(s.motion_noise(), s.range_noise(), jnp.asarray(s.ps_jitter, jnp.float32))
        k_init, k_run = jax.random.split(key)
        state = module.init(k_init, cfg, params, start)
        final, trace = module.run(k_run, state, cfg, params, controls, obs, donate_state=True)
        return trace.estimate, module.map_estimate(final)[0]

    return run


_RUNNERS: dict[str, Callable] = {
    "dead_reckoning": _dead_reckoning,
    "ekf": _kalman(ekf, ekf.EKFConfig),
    "ukf": _kalman(ukf, ukf.UKFConfig),
    "mcl": _mcl(ro.RANGE_ONLY_SENSOR),
    "mcl_t": _mcl(ro.RANGE_ONLY_T_SENSOR),
    "fastslam": _fastslam("range_only"),
    "fastslam_ring": _fastslam("range_only_ring"),
    "pf_slam": _slam(pf_slam),
    "ps_slam": _slam(ps_slam),
}


def _check_names(algorithms: Sequence[str]) -> None:
    for name in algorithms:
        if name not in _RUNNERS:
            raise ValueError(f"algorithm must be one of {list(ALGORITHMS)}, got {name!r}")


def run_algorithm(
    name: str, seq: data.UWBSequence, key: jax.Array, runs: int = 10, settings: UWBSettings = UWBSettings()
) -> UWBResult:
    """Run one algorithm ``runs`` times (keys ``fold_in(key, r)``; the deterministic ones, dead
    reckoning, EKF and UKF, once) and score it."""
    _check_names([name])
    if not isinstance(runs, int) or isinstance(runs, bool) or runs < 1:
        raise ValueError(f"runs must be a positive int, got {runs!r}")
    start = time.perf_counter()
    repeats = 1 if name in DETERMINISTIC else runs
    outputs = [jax.block_until_ready(_RUNNERS[name](jax.random.fold_in(key, r), seq, settings)) for r in range(repeats)]
    seconds = time.perf_counter() - start
    estimates = np.stack([np.asarray(est) for est, _ in outputs])
    truth = np.asarray(seq.true_positions)
    position_error = np.linalg.norm(estimates[:, :, :2] - truth, axis=-1).mean(axis=1)
    anchors = anchor_error = None
    if outputs[0][1] is not None:
        anchors = np.stack([np.asarray(a) for _, a in outputs])
        anchor_error = np.linalg.norm(anchors - np.asarray(seq.anchors), axis=-1).mean(axis=1)
    return UWBResult(name, estimates, anchors, position_error, anchor_error, seconds)


def run_study(
    algorithms: Sequence[str] = ALGORITHMS,
    runs: int = 10,
    seed: int = 0,
    settings: UWBSettings = UWBSettings(),
    root: str | None = None,
) -> tuple[data.UWBSequence, list[UWBResult]]:
    """Load the log (``root`` as :func:`jaxnav.io.uwb.data_dir`) and run ``algorithms`` on it."""
    _check_names(algorithms)
    seq = data.load_labyrinth(root)
    key = jax.random.PRNGKey(seed)
    return seq, [
        run_algorithm(name, seq, jax.random.fold_in(key, i), runs, settings) for i, name in enumerate(algorithms)
    ]


def _mean_sd(values: np.ndarray | None) -> str:
    if values is None:
        return report.NONE
    if values.size == 1:
        return report.number(1e3 * float(values[0]), 0)
    return f"{report.number(1e3 * float(values.mean()), 0)} ± {report.number(1e3 * float(values.std(ddof=1)), 0)}"


def format_table(results: Sequence[UWBResult]) -> str:
    """Markdown table: per algorithm, the runs, the mean position error and the anchors' mean error
    (mm, mean ± standard deviation over the runs), and the time."""
    heads = ["algorithm", "runs", "position error (mm)", "anchor error (mm)", "time (s)"]
    cells = [
        [
            r.name,
            str(r.estimates.shape[0]),
            _mean_sd(r.position_error),
            _mean_sd(r.anchor_error),
            report.number(r.seconds, 1),
        ]
        for r in results
    ]
    return report.markdown(heads, cells)


_COLORS = {
    "dead_reckoning": "tab:gray",
    "ekf": "tab:green",
    "ukf": "tab:purple",
    "mcl": "tab:red",
    "mcl_t": "tab:orange",
    "fastslam": "tab:blue",
    "fastslam_ring": "tab:brown",
    "pf_slam": "tab:olive",
    "ps_slam": "tab:cyan",
}
_MARKERS = {"fastslam": "s", "fastslam_ring": "P", "pf_slam": "D", "ps_slam": "v"}


def _draw(seq: data.UWBSequence, results: Sequence[UWBResult]):
    import matplotlib.pyplot as plt

    fig, (ax_path, ax_err) = plt.subplots(1, 2, figsize=(12, 5.4), layout="constrained")
    truth = np.asarray(seq.true_positions)
    ax_path.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="ground truth")
    ax_path.plot(seq.anchors[:, 0], seq.anchors[:, 1], "k*", ms=14, label="anchors (surveyed)")
    times = seq.times - seq.times[0]
    for r in results:
        color = _COLORS.get(r.name, None)
        style = "--" if r.name == "dead_reckoning" else "-"
        ax_path.plot(
            r.estimates[0, :, 0],
            r.estimates[0, :, 1],
            style,
            color=color,
            lw=1,
            label=r.name if r.name in DETERMINISTIC else f"{r.name} (run 1)",
        )
        if r.anchors is not None:
            a = r.anchors.reshape(-1, 2)
            ax_path.plot(
                a[:, 0],
                a[:, 1],
                _MARKERS.get(r.name, "x"),
                color=color,
                mfc="none",
                ms=6,
                label=f"{r.name} anchors ({r.anchors.shape[0]} runs)",
            )
        error = np.linalg.norm(r.estimates[:, :, :2] - truth, axis=-1).mean(axis=0)
        ax_err.plot(times, error, style, color=color, lw=1, label=r.name)
    ax_path.set_aspect("equal")
    ax_path.set_xlabel("x (m)")
    ax_path.set_ylabel("y (m)")
    ax_path.set_title("TU Chemnitz Labyrinth UWB: paths and anchors")
    ax_err.set_xlabel("time (s)")
    ax_err.set_ylabel("position error, mean over runs (m)")
    ax_err.set_title("position error against the ground truth")
    ax_err.grid(alpha=0.3)
    fig.legend(*ax_path.get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    return fig


def plot_study(seq: data.UWBSequence, results: Sequence[UWBResult], path: str) -> None:
    """Paths (the first run of each algorithm) and SLAM anchor estimates (every run) against the ground
    truth, and the position error over time (mean over the runs). Writes a PNG to ``path``."""
    import matplotlib.pyplot as plt

    fig = _draw(seq, results)
    fig.savefig(path, dpi=110)
    plt.close(fig)
