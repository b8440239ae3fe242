"""The read model's noise learned from AdaRF reads: ``σ_phase`` and the RSSI model's ``(k, θ)`` by maximum likelihood.

**Overview**

[A] sets ``σ_phase`` by hand (0.05–0.2 λ) and fits the RSSI model's Gamma ``(k, θ)`` on an anchor
tag by the closed form of App. D–E (:func:`jaxnav.experiments.uhf.real.anchor_gamma`). Here all
three are learned by :func:`jaxnav.calibration.fit` from the likelihood of reads, in two ways:

* **anchor** (:func:`anchor_objective`): the anchor tag's reads at its known position, the
  unknown phase offset ``θ_off`` integrated out on a grid of ``num_offsets`` values (a
  quadrature of ``∫ p(reads | X, θ_off) dθ_off / 2π``):

      ℓ(k, θ, σ) = Σ_j log W_RSSI(y_j) + log (1/K) Σ_i Π_j W_PHASE(φ_j | θ_off,i)

  per valid read. Deterministic, so L-BFGS. The RSSI term does not depend on ``θ_off``: its
  maximum in ``(k, θ)`` is the exact ML of App. D, which the closed form approximates to
  ``≲ 1/(60 k³)`` (:mod:`jaxnav.models.uhf_calibration`); what the anchor adds is ``σ_phase``.
* **filter** (:func:`filter_objective`): the log marginal likelihood that
  :func:`jaxnav.localization.rfid_tag.run` estimates from the **target tag's own reads**, its
  position unknown (no anchor), averaged over ``num_seeds`` filters, fitted by Adam. The filter
  refreshes its particles from a Gaussian (:class:`~jaxnav.localization.rfid_tag.RFIDTagConfig`),
  so its gradient is pathwise through the redrawn particles with constant weights after a
  refresh: a biased estimate of the score (:mod:`jaxnav.core.gradients`).

:func:`run_study` localizes each target tag of each experiment with the combined weighting
under the three settings (closed form with ``σ_phase = 0.1 λ``, anchor-learned, filter-learned)
and reports the final errors: :func:`format_table`, ``jaxnav uhf-real --calibrate``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import calibration
from jaxnav.core.validation import check_positive_int
from jaxnav.experiments import report
from jaxnav.experiments.uhf import real
from jaxnav.io import adarf
from jaxnav.localization import rfid_tag
from jaxnav.models import uhf_rfid as U
from jaxnav.models import uhf_sensor as US

__all__ = [
    "METHODS",
    "trainable",
    "closed_form_params",
    "anchor_objective",
    "filter_objective",
    "fit_anchor",
    "fit_filter",
    "final_errors",
    "StudyRow",
    "run_study",
    "format_table",
]

METHODS = ("closed-form", "anchor", "filter")
"""The settings :func:`run_study` compares (module docstring)."""


def trainable(params: rfid_tag.RFIDTagParams) -> rfid_tag.RFIDTagParams:
    """The :func:`jaxnav.calibration.fit` mask of ``params`` that trains ``gamma.k``, ``gamma.theta`` and ``phase_sigma``."""
    off = jax.tree_util.tree_map(lambda _: False, params)
    return off._replace(gamma=U.GammaParams(True, True), phase_sigma=True)


def closed_form_params(
    reads: U.UHFReads, anchor_xy: Sequence[float], setting: real.RealSetting | None = None
) -> rfid_tag.RFIDTagParams:
    """The filter's parameters of :func:`jaxnav.experiments.uhf.real.localize`: (k, θ) by [A]'s closed-form anchor
    fit on ``reads`` at ``anchor_xy [2]`` (m), ``σ_phase`` from ``setting`` (default :class:`~jaxnav.experiments.uhf.real.RealSetting`)."""
    setting = real.RealSetting() if setting is None else setting
    return real._params(setting, real.anchor_gamma(reads, np.asarray(anchor_xy), setting).params)


def anchor_objective(
    reads: U.UHFReads,
    anchor_xyz: Sequence[float],
    weighting: str = "combined",
    num_offsets: int = 360,
):
    """``(key, params) -> ℓ / n``: the mean log-likelihood per valid read of an anchor's reads (module docstring).

    Args:
        reads: the anchor's reads, mask shape ``[T, J]``.
        anchor_xyz: ``[3]`` the anchor's known position (m).
        weighting: which terms, as :data:`jaxnav.localization.rfid_tag.WEIGHTINGS`.
        num_offsets: grid points of ``θ_off`` on ``[−π, π)``. The product of ``n`` phase terms is
            a peak in ``θ_off`` about ``(4πσ_phase/λ)/√n`` rad wide; the sum over a periodic grid
            whose spacing is at most 1.65 such widths is within 1e-3 (relative) of the integral. 360 points (1°)
            suffice for σ_phase ≥ 0.017 λ with 400 reads (AdaRF's 50 points × 8 channels); raise it
            for sharper phases or more reads.

    The key is unused (the objective is deterministic).
    """
    check_positive_int("num_offsets", num_offsets)
    U.validate_reads(reads)
    if np.ndim(reads.mask) != 2:
        raise ValueError(f"reads must have mask shape [T, J], got {np.shape(reads.mask)}")
    count = int(np.sum(np.asarray(reads.mask)))
    if count == 0:
        raise ValueError("the anchor has no valid read: nothing to fit")
    offsets = jnp.linspace(-math.pi, math.pi, num_offsets, endpoint=False, dtype=jnp.float32)
    xyz = jnp.broadcast_to(jnp.asarray(anchor_xyz, jnp.float32), (num_offsets, 3))
    hypotheses = jnp.concatenate([xyz, offsets[:, None]], axis=1)  # [K, 4]: the filter's particle layout
    reads = US.as_tag_reads(reads)

    def objective(key: jax.Array, params: rfid_tag.RFIDTagParams) -> jax.Array:
        del key
        per_step = jax.vmap(lambda r: US.tag_reads_log_likelihood(hypotheses, r, params, weighting, None))(reads)
        return (jax.nn.logsumexp(per_step.sum(0)) - math.log(num_offsets)) / count

    return objective


def filter_objective(
    reads: U.UHFReads,
    params: rfid_tag.RFIDTagParams,
    num_particles: int = 2000,
    num_seeds: int = 4,
    weighting: str = "combined",
    seed: int = 0,
):
    """``(key, params) -> mean log-likelihood per step`` of :func:`jaxnav.localization.rfid_tag.run` in 2D on ``reads``
    (a tag of unknown position), averaged over ``num_seeds`` filters: :func:`jaxnav.calibration.log_likelihood_objective`.

    The particles start uniform in ``params``' box (from ``PRNGKey(seed)``) and stay the same for every step of the fit."""
    config = rfid_tag.RFIDTagConfig(num_particles=num_particles, dims=2, weighting=weighting)
    state = rfid_tag.init(jax.random.PRNGKey(seed), config, params)
    return calibration.log_likelihood_objective(rfid_tag.kernel, config, state, (reads,), num_seeds=num_seeds)


def fit_anchor(
    reads: U.UHFReads, anchor_xyz: Sequence[float], start: rfid_tag.RFIDTagParams, steps: int = 30
) -> calibration.FitResult:
    """``(k, θ, σ_phase)`` maximising :func:`anchor_objective` from ``start``, by L-BFGS."""
    objective = anchor_objective(reads, anchor_xyz)
    return calibration.fit(
        objective, jax.random.PRNGKey(0), start, trainable=trainable(start), steps=steps, optimizer="lbfgs"
    )


def fit_filter(
    key: jax.Array,
    reads: U.UHFReads,
    start: rfid_tag.RFIDTagParams,
    steps: int = 60,
    num_particles: int = 2000,
    num_seeds: int = 4,
    learning_rate: float = 0.05,
) -> calibration.FitResult:
    """``(k, θ, σ_phase)`` maximising :func:`filter_objective` on a tag's own reads from ``start``, by Adam."""
    objective = filter_objective(reads, start, num_particles, num_seeds)
    return calibration.fit(objective, key, start, trainable=trainable(start), steps=steps, learning_rate=learning_rate)


class StudyRow(NamedTuple):
    """One target tag under :data:`METHODS`.

    Attributes:
        experiment, tag: which tag (``tag`` indexes :data:`jaxnav.io.adarf.TARGET_EPCS`).
        gamma: ``{method: (k, θ)}``.
        phase_sigma: ``{method: σ_phase / λ}``.
        errors: ``{method: [R]}`` final errors (m) of the combined weighting over ``R`` seeds.
    """

    experiment: str
    tag: int
    gamma: dict
    phase_sigma: dict
    errors: dict


def final_errors(params, reads, truth, seeds: int, seed: int, tag: int, num_particles: int) -> np.ndarray:
    """``[seeds]`` final errors (m) of the combined filter on ``reads`` against ``truth [2]``, with the keys
    of :func:`jaxnav.experiments.uhf.real.localize` for tag ``tag`` from ``seed``
    (:func:`~jaxnav.experiments.uhf.real.seeded_estimates`)."""
    config = rfid_tag.RFIDTagConfig(num_particles=num_particles, dims=2, weighting="combined")
    est = real.seeded_estimates(params, config, reads, seeds, seed, tag)
    return np.linalg.norm(est[:, -1] - truth, axis=-1)


def run_study(
    experiments: Sequence[str] | None = None,
    seeds: int = 5,
    seed: int = 0,
    root: str | os.PathLike | None = None,
    setting: real.RealSetting | None = None,
    filter_steps: int = 60,
) -> list[StudyRow]:
    """Learn ``(k, θ, σ_phase)`` per target tag both ways and localize it under each of :data:`METHODS`.

    The anchor of tag ``g`` is :data:`jaxnav.experiments.uhf.real.ANCHOR_OF` ``[g]``, as for the closed
    form; the filter is fitted on tag ``g``'s own reads with key ``fold_in(PRNGKey(1), g)``, from the
    closed-form setting. The localization runs use the keys of :func:`jaxnav.experiments.uhf.real.localize`
    from ``seed``, the same for every method. ``experiments`` default to every one found; ``setting``
    to :class:`~jaxnav.experiments.uhf.real.RealSetting` (its ``phase_sigma_fraction`` is the closed-form row's).
    """
    check_positive_int("seeds", seeds)
    setting = real.RealSetting() if setting is None else setting
    names = list(adarf.available_experiments(root) if experiments is None else experiments)
    lam = float(real.channel_params().wavelength)
    h = setting.antenna_height
    rows = []
    for name in names:
        exp = adarf.load_experiment(name, root)
        reads = [adarf.to_uhf_reads(exp, g, setting.reads_per_channel, antenna_height=h) for g in range(3)]
        by_anchor = {}  # an anchor serves two tags: its fits are made once
        for a in sorted(set(real.ANCHOR_OF)):
            closed = closed_form_params(reads[a], exp.tags_xy[a], setting)
            by_anchor[a] = (closed, fit_anchor(reads[a], (*exp.tags_xy[a], h), closed).params)
        for g in range(3):
            closed, anchored = by_anchor[real.ANCHOR_OF[g]]
            fitted = {
                "closed-form": closed,
                "anchor": anchored,
                "filter": fit_filter(
                    jax.random.fold_in(jax.random.PRNGKey(1), g), reads[g], closed, steps=filter_steps
                ).params,
            }
            rows.append(
                StudyRow(
                    name,
                    g,
                    {m: (float(p.gamma.k), float(p.gamma.theta)) for m, p in fitted.items()},
                    {m: float(p.phase_sigma) / lam for m, p in fitted.items()},
                    {
                        m: final_errors(p, reads[g], exp.tags_xy[g], seeds, seed, g, setting.num_particles)
                        for m, p in fitted.items()
                    },
                )
            )
    return rows


def format_table(rows: Sequence[StudyRow]) -> str:
    """Per tag: each method's ``k`` and ``σ_phase / λ`` and its mean final error (m); then the mean over tags."""
    columns = [report.Column("experiment", 16, "<"), report.Column("tag", 4)]
    for m in METHODS:
        columns += [report.Column(f"{m} k", 15), report.Column("σ/λ", 7), report.Column("error m", 8)]
    body = []
    for r in rows:
        line = [r.experiment, str(r.tag)]
        for m in METHODS:
            line += [
                report.number(r.gamma[m][0], 1),
                report.number(r.phase_sigma[m], 3),
                report.number(float(np.mean(r.errors[m])), 3),
            ]
        body.append(line)
    means = ["mean of tags", ""]
    for m in METHODS:
        means += ["", "", report.number(float(np.mean([np.mean(r.errors[m]) for r in rows])), 3)]
    body.append(means)
    return report.text(columns, body, rule=False)
