"""The UWB range model's bias and spread learned from the data (:mod:`jaxnav.calibration`).

The study's range model (:class:`~jaxnav.experiments.uwb.evaluation.UWBSettings`) has a bias of
0.1 m and a spread of 0.15 m, set from the residuals against the ground truth. Here they are learned
without the ground truth, from the ranges and wheel speeds of the log's first half, by maximising
a filter's log-likelihood (the bias through the identity, the spread through a log), and the
filters localise the robot on the second half, which the fit never saw, with

* ``"learned"``: the learned bias and spread;
* ``"given"``: the study's hand-set bias and spread;
* ``"no bias"``: the given spread without a bias.

``"ekf"`` fits by the EKF's exact likelihood (L-BFGS), ``"mcl"`` by MCL's estimate with the score
gradient (Adam). The error is the mean position error over the second half (m), against the
ground truth; MCL's is the mean over ``runs`` keys.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import calibration
from jaxnav.experiments.uwb import evaluation as ev
from jaxnav.io import uwb as data
from jaxnav.localization import ekf, mcl
from jaxnav.models import landmarks as lm
from jaxnav.models import range_only as ro

__all__ = ["METHODS", "RangeFit", "StudyRow", "halves", "fit_range_noise", "run_study", "format_table"]

METHODS = ("ekf", "mcl")
"""How :func:`fit_range_noise` learns: by the EKF's likelihood or by MCL's."""

_DEFAULT_STEPS = {"ekf": 20, "mcl": 100}


class RangeFit(NamedTuple):
    """Output of :func:`fit_range_noise`: the settings with the learned bias and spread, the
    :class:`jaxnav.calibration.FitResult`, and the fit's wall time (s, compilation included)."""

    settings: ev.UWBSettings
    result: calibration.FitResult
    seconds: float


def halves(seq: data.UWBSequence) -> tuple[data.UWBSequence, data.UWBSequence]:
    """The log's first and second halves (:func:`jaxnav.io.uwb.segment`)."""
    middle = seq.times.size // 2
    return data.segment(seq, 0, middle), data.segment(seq, middle)


def _inputs(seq: data.UWBSequence) -> tuple:
    controls = jnp.asarray(seq.controls, jnp.float32)
    obs = ro.RangeObs(*(jnp.asarray(a) for a in seq.observations))
    return controls, obs._replace(z=obs.z.astype(jnp.float32))


def fit_range_noise(
    seq: data.UWBSequence,
    settings: ev.UWBSettings | None = None,
    method: str = "ekf",
    steps: int | None = None,
    seed: int = 0,
) -> RangeFit:
    """Learn the range model's bias and spread from ``seq`` (the other settings kept).

    Starts from no bias and the given spread. ``method`` ``"ekf"`` (20 L-BFGS steps by default) or
    ``"mcl"`` (MCL with ``settings.mcl_particles`` particles, 100 Adam steps of learning rate 0.05).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {list(METHODS)}, got {method!r}")
    settings = ev.UWBSettings() if settings is None else settings
    steps = _DEFAULT_STEPS[method] if steps is None else steps
    start_noise = ro.range_noise(settings.range_sd, 0.0, settings.range_dof)
    anchors = jnp.asarray(seq.anchors, jnp.float32)
    params = lm.LandmarkMapParams(settings.motion_noise(), start_noise, anchors)
    trainable = lm.LandmarkMapParams(motion=False, sensor=ro.RangeNoise(sd=True, bias=True, dof=False), landmarks=False)
    transform = lm.LandmarkMapParams(
        motion="log", sensor=ro.RangeNoise(sd="log", bias="identity", dof="log"), landmarks="identity"
    )
    pose = jnp.asarray(seq.initial_pose, jnp.float32)
    key = jax.random.PRNGKey(seed)
    begin = time.perf_counter()
    if method == "ekf":
        config = ekf.EKFConfig(motion_model=seq.motion_model, observation_model="range_only")
        state = ekf.init(None, config, params, pose, jnp.diag(jnp.asarray(settings.initial_sd, jnp.float32) ** 2))
        objective = calibration.log_likelihood_objective(ekf.kernel, config, state, _inputs(seq))
        optimizer = "lbfgs"
    else:
        config = mcl.MCLConfig(
            num_particles=settings.mcl_particles,
            motion_model=seq.motion_model,
            sensor=ro.RANGE_ONLY_SENSOR,
            ess_threshold=0.5,
        )
        state = mcl.init(jax.random.fold_in(key, 1), config, params, pose, jnp.asarray(settings.initial_sd))
        objective = calibration.log_likelihood_objective(mcl.kernel, config, state, _inputs(seq), num_seeds=2)
        optimizer = "adam"
    result = calibration.fit(
        objective, key, params, trainable=trainable, transform=transform, steps=steps, optimizer=optimizer
    )
    learned = result.params.sensor
    fitted = dataclasses.replace(settings, range_sd=float(learned.sd), range_bias=float(learned.bias))
    return RangeFit(fitted, result, time.perf_counter() - begin)


class StudyRow(NamedTuple):
    """One filter with one range model on the second half: its settings' label, the algorithm, the
    bias and spread it used (m), and the mean position error (m) of each run."""

    label: str
    algorithm: str
    range_bias: float
    range_sd: float
    position_error: np.ndarray


def run_study(
    method: str = "ekf",
    algorithms: Sequence[str] = ("ekf", "mcl"),
    runs: int = 10,
    seed: int = 0,
    settings: ev.UWBSettings | None = None,
    root: str | None = None,
) -> tuple[RangeFit, list[StudyRow]]:
    """Fit on the first half (:func:`fit_range_noise`), then run ``algorithms`` on the second half with the
    learned, the given and the unbiased range models."""
    settings = ev.UWBSettings() if settings is None else settings
    first, second = halves(data.load_labyrinth(root))
    fit = fit_range_noise(first, settings, method, seed=seed)
    models = {
        "learned": fit.settings,
        "given": settings,
        "no bias": dataclasses.replace(settings, range_bias=0.0),
    }
    rows = []
    key = jax.random.PRNGKey(seed)
    for name in algorithms:
        for label, s in models.items():
            result = ev.run_algorithm(name, second, key, runs, s)
            rows.append(StudyRow(label, name, s.range_bias, s.range_sd, result.position_error))
    return fit, rows


def format_table(rows: Sequence[StudyRow]) -> str:
    """Markdown table of :func:`run_study`'s rows: the mean position error over the runs, ± their spread."""
    lines = ["| filter | range model | bias (m) | spread (m) | position error (m) |", "|---|---|---|---|---|"]
    for r in rows:
        spread = f" ± {np.std(r.position_error):.3f}" if r.position_error.size > 1 else ""
        lines.append(
            f"| {r.algorithm.upper()} | {r.label} | {r.range_bias:.3f} | {r.range_sd:.3f} | "
            f"{np.mean(r.position_error):.3f}{spread} |"
        )
    return "\n".join(lines)
