"""The MRCLAM filters' noise levels learned from the data (:mod:`jaxnav.calibration`).

The hand-chosen :class:`~jaxnav.experiments.mrclam.evaluation.MRCLAMSettings` were set by eye on
the first 300 s of robot 1. Here the same segment fits them by maximum likelihood: the velocity
model's ``α₁…α₄`` and additive pose noise, and the range-bearing noise (``α₅ = α₆ = 0`` stay), by

* ``"mcl"``: MCL's log-likelihood estimate with stop-gradient resampling (the default
  ``gradient="score"``), Adam, a fresh filter at every step;
* ``"ekf"``: the EKF's log-likelihood, deterministic, L-BFGS. *Without* its χ² gate: a gated
  filter leaves the gated observations out of its likelihood, so the smaller the noise it is given
  the more it gates and the larger that sum grows (on this segment, gated at 99.9 %, it drove the
  range noise to 0.033 m and the bearing noise to 0.0042 rad). Ungated, the EKF counts every
  residual, the outliers among them (0.5–3.6 % of ranges are off by more than 0.5 m), which the
  Gaussian model can only explain with a larger noise.

:func:`compare` then runs the known-map filters on robots 1–3 with each set of settings and
scores them: position and heading RMSE, and for the EKF and UKF their consistency, the mean NEES
(``eᵀ P⁻¹ e`` of the pose error, 3 for a consistent filter) and the mean NIS per fused observation
(2 for a consistent filter).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import calibration, metrics
from jaxnav.core import weights
from jaxnav.experiments.mrclam import evaluation as ev
from jaxnav.io import mrclam as data
from jaxnav.localization import ekf, mcl, ukf
from jaxnav.models import motion

__all__ = [
    "METHODS",
    "TRAINABLE",
    "NoiseFit",
    "ComparisonRow",
    "fit_noise",
    "consistency",
    "compare",
    "format_comparison",
]

METHODS = ("mcl", "ekf")
"""How :func:`fit_noise` learns the noise: by MCL's estimated likelihood, or the ungated EKF's."""

TRAINABLE = mcl.MCLParams(
    motion=motion.VelocityNoise(alphas=np.array([True, True, True, True, False, False]), pose_sd=True),
    sensor=True,
    landmarks=False,
)
"""The fields learned (``α₁…α₄``, the pose noise and the range-bearing noise); ``α₅, α₆`` (zero) and
the map are kept."""

_DEFAULT_STEPS = {"mcl": 60, "ekf": 20}


class NoiseFit(NamedTuple):
    """Output of :func:`fit_noise`.

    Attributes:
        settings: the starting settings with the learned noise.
        result: the :class:`jaxnav.calibration.FitResult` (losses: minus the mean log-likelihood per step).
        seconds: wall time of the fit, compilation included.
    """

    settings: ev.MRCLAMSettings
    result: calibration.FitResult
    seconds: float


def _params(settings: ev.MRCLAMSettings, seq: data.MRCLAMSequence) -> mcl.MCLParams:
    return mcl.MCLParams(settings.motion_noise(), settings.sensor_noise(), seq.landmarks)


def fit_noise(
    seq: data.MRCLAMSequence,
    settings: ev.MRCLAMSettings | None = None,
    method: str = "mcl",
    steps: int | None = None,
    seed: int = 0,
    num_particles: int = 200,
    progress: bool = False,
) -> NoiseFit:
    """Learn the motion and sensor noise of ``settings`` from ``seq`` by maximum likelihood.

    Args:
        seq: the training segment (:func:`jaxnav.io.mrclam.to_filter_steps`).
        settings: the starting point (and every setting not learned); default the hand-chosen ones.
        method: ``"mcl"`` or ``"ekf"`` (module docstring).
        steps: optimiser steps (default 60 for MCL, Adam with a learning rate of 0.05; 20 for the
            EKF, L-BFGS).
        seed: the fit's key (MCL's particles).
        num_particles: MCL's particles during the fit.
        progress: show a progress bar.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {list(METHODS)}, got {method!r}")
    settings = ev.MRCLAMSettings() if settings is None else settings
    steps = _DEFAULT_STEPS[method] if steps is None else steps
    params = _params(settings, seq)
    inputs = (seq.controls, seq.observations)
    key = jax.random.PRNGKey(seed)
    start = time.perf_counter()
    if method == "mcl":
        config = mcl.MCLConfig(num_particles=num_particles, ess_threshold=0.5)
        state = mcl.init(jax.random.fold_in(key, 1), config, params, seq.initial_pose, jnp.asarray(settings.initial_sd))
        objective = calibration.log_likelihood_objective(mcl.kernel, config, state, inputs)
        result = calibration.fit(objective, key, params, trainable=TRAINABLE, steps=steps, progress=progress)
    else:
        config = ekf.EKFConfig()  # ungated: the likelihood of every observation
        state = ekf.init(None, config, params, seq.initial_pose, settings.initial_cov())
        objective = calibration.log_likelihood_objective(ekf.kernel, config, state, inputs)
        result = calibration.fit(
            objective, key, params, trainable=TRAINABLE, steps=steps, optimizer="lbfgs", progress=progress
        )
    seconds = time.perf_counter() - start
    learned = result.params
    fitted = dataclasses.replace(
        settings,
        alphas=tuple(float(a) for a in np.asarray(learned.motion.alphas)),
        pose_sd=tuple(float(s) for s in np.asarray(learned.motion.pose_sd)),
        sensor_sd=tuple(float(s) for s in np.asarray(learned.sensor.sd)),
    )
    return NoiseFit(fitted, result, seconds)


def consistency(
    algorithm: str, seq: data.MRCLAMSequence, settings: ev.MRCLAMSettings
) -> tuple[np.ndarray, float, float, float]:
    """The EKF's or UKF's estimates on ``seq`` with ``settings`` (gated as in the evaluation), and their
    consistency: ``(estimates [T, 3], mean NEES, mean NIS per fused observation, fraction gated)``."""
    module = {"ekf": ekf, "ukf": ukf}[algorithm]
    config = (ekf.EKFConfig if algorithm == "ekf" else ukf.UKFConfig)(gate_probability=settings.gate_probability)
    params = ekf.KalmanParams(settings.motion_noise(), settings.sensor_noise(), seq.landmarks)
    state = module.init(None, config, params, seq.initial_pose, settings.initial_cov())
    _, trace = module.run(None, state, config, params, seq.controls, seq.observations)
    error = np.asarray(trace.estimate - seq.true_poses, np.float64)
    error[:, 2] = np.asarray(weights.wrap_angle(jnp.asarray(error[:, 2])))
    cov = np.asarray(trace.cov, np.float64)
    nees = np.einsum("ti,ti->t", error, np.linalg.solve(cov, error[..., None])[..., 0])
    accepted = np.asarray(trace.accepted)
    fused = max(int(accepted.sum()), 1)
    valid = int(accepted.sum() + np.asarray(trace.num_gated).sum())
    gated = float(np.asarray(trace.num_gated).sum() / valid) if valid else 0.0
    return np.asarray(trace.estimate), float(nees.mean()), float(np.asarray(trace.nis).sum() / fused), gated


class ComparisonRow(NamedTuple):
    """One filter on one robot with one set of settings (:func:`compare`).

    Attributes:
        label: the settings' name.
        robot: the robot (1–5).
        algorithm: ``"ekf"``, ``"ukf"`` or ``"mcl"``.
        position_rmse: m.
        heading_rmse: rad.
        nees: mean NEES (EKF, UKF; NaN for MCL).
        nis: mean NIS per fused observation (EKF, UKF; NaN for MCL).
        gated: fraction of the valid observations the gate rejected (EKF, UKF; NaN for MCL).
    """

    label: str
    robot: int
    algorithm: str
    position_rmse: float
    heading_rmse: float
    nees: float
    nis: float
    gated: float


def compare(
    settings: Mapping[str, ev.MRCLAMSettings],
    robots: Sequence[int] = (1, 2, 3),
    algorithms: Sequence[str] = ("ekf", "ukf", "mcl"),
    duration: float | None = None,
    seed: int = 0,
    root: str | None = None,
) -> list[ComparisonRow]:
    """Run the known-map ``algorithms`` on each robot's log with each of ``settings`` and score them."""
    for name in algorithms:
        if name not in ("ekf", "ukf", "mcl"):
            raise ValueError(f"algorithm must be one of ['ekf', 'ukf', 'mcl'], got {name!r}")
    rows = []
    for robot in robots:
        for label, s in settings.items():
            seq = data.to_filter_steps(
                data.load_robot(robot, root), dt=s.dt, duration=duration, max_obs=s.max_obs, keep_outliers=True
            )
            for i, name in enumerate(algorithms):
                nees = nis = gated = float("nan")
                if name == "mcl":
                    est = ev.run_algorithm("mcl", seq, jax.random.fold_in(jax.random.PRNGKey(seed), i), s).estimates
                else:
                    est, nees, nis, gated = consistency(name, seq, s)
                error = metrics.trajectory_rmse(jnp.asarray(est), seq.true_poses)
                rows.append(
                    ComparisonRow(
                        label,
                        robot,
                        name,
                        float(error.position_rmse),
                        float(error.heading_rmse),
                        nees,
                        nis,
                        gated,
                    )
                )
    return rows


def format_comparison(rows: Sequence[ComparisonRow]) -> str:
    """Markdown table of :func:`compare`'s rows: RMSE in mm and mrad; NEES (3 when consistent) and
    NIS per observation (2 when consistent) for the Gaussian filters."""

    def number(x: float, fmt: str) -> str:
        return "–" if not np.isfinite(x) else format(x, fmt)

    lines = [
        "| robot | filter | settings | position RMSE (mm) | heading RMSE (mrad) | NEES (3) | NIS (2) | gated |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r.robot, r.algorithm)):
        lines.append(
            f"| {r.robot} | {ev.display_name(r.algorithm)} | {r.label} | {r.position_rmse * 1e3:.0f} | "
            f"{r.heading_rmse * 1e3:.0f} | {number(r.nees, '.1f')} | {number(r.nis, '.2f')} | "
            f"{number(100 * r.gated, '.1f')}{'' if not np.isfinite(r.gated) else ' %'} |"
        )
    return "\n".join(lines)
