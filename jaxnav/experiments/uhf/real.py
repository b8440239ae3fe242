"""Tag localization ([A] Alg. 6) on the AdaRF real reads: three tags, three weightings, scored against the ground truth.

**Overview**

For each experiment of :mod:`jaxnav.io.adarf` and each of its three target
tags, :func:`localize` runs :func:`jaxnav.localization.rfid_tag.run` in 2D
(the tag height is known: the data are planar) over the 50 aperture points,
with RSSI-only, phase-only and combined weights, and scores the final
estimate against the tag's ground-truth position.

**The choices** (ours; [A] localized no public data)

* **Reads**: :func:`jaxnav.io.adarf.to_uhf_reads` with the 8 channels
  aligned and ``reads_per_channel`` reads of each per aperture point.
* **Search box** ``x ∈ [−0.25, 1.25]``, ``y ∈ [0.25, 1.50]`` m: the 1 m
  track extended by 0.25 m at each end, and depths from 0.25 m to 1.5 m in
  front of the antenna (the tags lie at 0.51–0.88 m). A uniform guess in it
  misses a tag by :func:`prior_rmse` ≈ 0.5 m; that is the spread the
  localization must beat.
* **(k, θ) from an anchor** ([A] §4.3.1): another target tag of the same
  experiment, whose position is known — the middle tag (index 1) for the
  outer tags, tag 0 for the middle one (both 0.2 m away, more than
  ``λ/2 = 0.16`` m, so [A] Fig. 5.3 expects an imperfect fit).
* **Antenna**: :data:`ANTENNA`, a main lobe of ±60° (the tags are seen at up
  to 38° off boresight; [A]'s ±30° default would put the track's ends in a
  side lobe of our stepped model, which the real antenna does not show).
  The power model is otherwise :data:`~jaxnav.models.uhf_channel.DEFAULT_CHANNEL`
  at the channel-0 wavelength; its absolute scale does not matter because
  the anchor's ``θ`` absorbs it.
* ``σ_phase = 0.1 λ`` (:data:`~jaxnav.models.uhf_read_model.DEFAULT_PHASE_SIGMA_FRACTION`,
  [A]'s range 0.05–0.2 λ), not tuned on these data.

What to expect, as the dataset's description says: from a 1 m linear aperture the position along
the track is observable to a few cm, the depth ``Y`` only weakly.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.validation import check_choice, check_positive, check_positive_int
from jaxnav.experiments import report, stats
from jaxnav.io import adarf
from jaxnav.localization import rfid_tag
from jaxnav.models import uhf_calibration
from jaxnav.models import uhf_rfid as U

__all__ = [
    "ANTENNA",
    "BOX_LO",
    "BOX_HI",
    "ANCHOR_OF",
    "RealSetting",
    "TagResult",
    "channel_params",
    "anchor_gamma",
    "prior_rmse",
    "seeded_estimates",
    "memory_estimate",
    "localize",
    "format_results",
    "plot_results",
]

ANTENNA = U.AntennaParams(g0=10.0**0.8, g_sll=10.0**-0.2, g_bll=10.0**-1.2, phi_s=math.pi / 3)
"""DEFAULT_ANTENNA's gains with a ±60° main lobe (module docstring)."""

BOX_LO = (-0.25, 0.25)
"""The lower corner ``(x, y)`` of the 2D search box (m; module docstring)."""
BOX_HI = (1.25, 1.50)
"""The upper corner ``(x, y)`` of the 2D search box (m; module docstring)."""

ANCHOR_OF = (1, 0, 1)
"""The anchor tag whose reads give (k, θ) for each target tag."""


@dataclass(frozen=True)
class RealSetting:
    """How the real reads are localized (defaults: the module docstring's choices).

    Attributes:
        num_particles: M of :class:`~jaxnav.localization.rfid_tag.RFIDTagConfig`.
        reads_per_channel: reads of each of the 8 channels per aperture point.
        phase_sigma_fraction: ``σ_phase / λ``.
        antenna_height: reader and tag height (m); irrelevant in the free-space branch.
    """

    num_particles: int = 5000
    reads_per_channel: int = 1
    phase_sigma_fraction: float = U.DEFAULT_PHASE_SIGMA_FRACTION
    antenna_height: float = 1.0

    def __post_init__(self) -> None:
        check_positive_int("num_particles", self.num_particles)
        check_positive_int("reads_per_channel", self.reads_per_channel)
        check_positive("phase_sigma_fraction", self.phase_sigma_fraction)
        check_positive("antenna_height", self.antenna_height)


class TagResult(NamedTuple):
    """One tag localized with one weighting over ``R`` seeds.

    Attributes:
        experiment, tag, weighting: what was run (``tag`` indexes :data:`jaxnav.io.adarf.TARGET_EPCS`).
        truth: ``[2]`` ground truth (m).
        estimates: ``[R, 50, 2]`` the estimate after each aperture point (m).
        errors: ``[R, 50]`` Euclidean error after each point (m).
        final_error: ``[R]`` error after the last point (m).
        gamma: the anchor's ``(k, θ)`` fit.
    """

    experiment: str
    tag: int
    weighting: str
    truth: np.ndarray
    estimates: np.ndarray
    errors: np.ndarray
    final_error: np.ndarray
    gamma: U.GammaParams


def channel_params() -> U.ChannelParams:
    """:data:`~jaxnav.models.uhf_channel.DEFAULT_CHANNEL` with :data:`ANTENNA` and the channel-0 wavelength."""
    lam0 = U.SPEED_OF_LIGHT / float(adarf.CHANNELS_HZ[0])
    return U.DEFAULT_CHANNEL._replace(wavelength=lam0, antenna=ANTENNA)


def _xyz(xy: np.ndarray, height: float) -> jax.Array:
    return jnp.asarray([xy[0], xy[1], height], jnp.float32)


def anchor_gamma(reads: U.UHFReads, anchor_xy: np.ndarray, setting: RealSetting) -> uhf_calibration.GammaFit:
    """(k, θ) by [A] §4.3.1's anchor fit: the anchor's reads against ``a`` of the model at its known position."""
    a = U.power_scale(
        reads.reader, _xyz(anchor_xy, setting.antenna_height), channel_params(), wavelength=reads.wavelength
    )
    return uhf_calibration.estimate_gamma(reads.rssi.ravel(), a.ravel(), reads.mask.ravel())


def prior_rmse(truth_xy: np.ndarray) -> float:
    """RMS distance (m) from ``truth_xy [2]`` to a point uniform in the search box (closed form)."""
    lo, hi = np.asarray(BOX_LO), np.asarray(BOX_HI)
    mean, var = (lo + hi) / 2, (hi - lo) ** 2 / 12
    return float(np.sqrt(np.sum(var + (np.asarray(truth_xy) - mean) ** 2)))


def memory_estimate(setting: RealSetting, seeds: int = 1) -> int:
    """Bytes :func:`localize` holds at once, estimated from the sizes alone.

    One step scores ``M`` particles against the ``8 · reads_per_channel`` slots of an aperture
    point (about 8 numbers per pair); the reads of the 50 points, and every seed's estimates of
    the 3 tags × 3 weightings; 4 bytes a number, doubled for XLA's temporaries. A rough
    figure (within a few times), to refuse sizes that cannot fit.
    """
    j = len(adarf.CHANNELS_HZ) * setting.reads_per_channel
    m = setting.num_particles
    return 2 * 4 * (8 * m * j + 16 * m + 8 * adarf.NUM_POINTS * j + 9 * 4 * adarf.NUM_POINTS * seeds)


def _params(setting: RealSetting, gamma: U.GammaParams) -> rfid_tag.RFIDTagParams:
    chan = channel_params()
    h = setting.antenna_height
    return rfid_tag.default_params(
        box_lo=(*BOX_LO, h - 0.5),
        box_hi=(*BOX_HI, h + 0.5),
        channel=chan,
        gamma=gamma,
        phase_sigma=setting.phase_sigma_fraction * float(chan.wavelength),
        tag_height=h,
    )


def seeded_estimates(
    params: rfid_tag.RFIDTagParams, config: rfid_tag.RFIDTagConfig, reads: U.UHFReads, seeds: int, seed: int, tag: int
) -> np.ndarray:
    """``[seeds, T, 2]`` the estimates of ``seeds`` runs of the tag filter on ``reads`` (m).

    Run ``r`` of tag ``tag`` uses ``fold_in(fold_in(PRNGKey(seed), tag), r)``, split into the init and
    run keys: the keys of :func:`localize`, so every setting of a tag sees the same draws."""
    est = []
    for r in range(seeds):
        k_init, k_run = jax.random.split(jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), tag), r))
        _, trace = rfid_tag.run(k_run, rfid_tag.init(k_init, config, params), config, params, reads)
        est.append(np.asarray(trace.estimate[:, :2], np.float64))
    return np.stack(est)


def localize(
    experiment: str,
    weightings: Sequence[str] = rfid_tag.WEIGHTINGS,
    setting: RealSetting = RealSetting(),
    seeds: int = 1,
    seed: int = 0,
    root: str | os.PathLike | None = None,
) -> list[TagResult]:
    """Localize the three tags of ``experiment`` with each weighting over ``seeds`` runs (module docstring).

    Run ``r`` of tag ``g`` uses ``fold_in(fold_in(PRNGKey(seed), g), r)`` (split into
    the init and run keys), the same for every weighting. Returns one
    :class:`TagResult` per (tag, weighting), tags first.
    """
    for w in weightings:
        check_choice("weighting", w, rfid_tag.WEIGHTINGS)
    check_positive_int("seeds", seeds)
    exp = adarf.load_experiment(experiment, root)
    reads = [
        adarf.to_uhf_reads(exp, g, setting.reads_per_channel, antenna_height=setting.antenna_height) for g in range(3)
    ]
    out = []
    for g in range(3):
        anchor = ANCHOR_OF[g]
        fit = anchor_gamma(reads[anchor], exp.tags_xy[anchor], setting)
        params = _params(setting, fit.params)
        for w in weightings:
            config = rfid_tag.RFIDTagConfig(num_particles=setting.num_particles, dims=2, weighting=w)
            est = seeded_estimates(params, config, reads[g], seeds, seed, g)
            err = np.linalg.norm(est - exp.tags_xy[g], axis=-1)
            out.append(
                TagResult(
                    experiment,
                    g,
                    w,
                    exp.tags_xy[g].copy(),
                    est,
                    err,
                    err[:, -1],
                    U.GammaParams(float(fit.params.k), float(fit.params.theta)),
                )
            )
    return out


def format_results(results: Sequence[TagResult]) -> str:
    """A table: final error (m, mean and range over seeds) and its x / y parts per tag and weighting.

    A seed whose final estimate is not finite diverged: it is left out of the row's numbers and
    counted in a line under the table ("1 of 5 runs diverged")."""
    columns = [
        report.Column("experiment", 16, "<"),
        report.Column("tag", 4),
        report.Column("weighting", 10),
        report.Column("error m", 9),
        report.Column("(min-max)", 14),
        report.Column("dx m", 8),
        report.Column("dy m", 8),
        report.Column("prior m", 9),
        report.Column("anchor k", 10),
    ]
    rows, notes = [], []
    for r in results:
        d = r.estimates[:, -1] - r.truth
        diverged = stats.diverged_runs(r.final_error, d)
        ok = ~diverged
        err, d = np.asarray(r.final_error)[ok], d[ok]
        rows.append(
            [
                r.experiment,
                str(r.tag),
                r.weighting,
                report.number(err.mean() if err.size else math.nan, 3),
                f"({report.number(err.min() if err.size else math.nan, 3)}-"
                f"{report.number(err.max() if err.size else math.nan, 3)})",
                report.number(d[:, 0].mean() if err.size else math.nan, 3),
                report.number(d[:, 1].mean() if err.size else math.nan, 3),
                report.number(prior_rmse(r.truth), 3),
                report.number(r.gamma.k, 1),
            ]
        )
        notes.append(
            report.diverged_line(f"{r.experiment} tag {r.tag} {r.weighting}", int(diverged.sum()), diverged.size)
        )
    return "\n".join([report.text(columns, rows, rule=False), *(n for n in notes if n)])


_TAG_STYLES = ("-", "--", ":")
"""The line style of each target tag in the error panel (the colour is the weighting's)."""


def _tag_name(tag: int) -> str:
    return f"tag {tag} (EPC …{adarf.TARGET_EPCS[tag][-4:]})"


def _draw_results(results: Sequence[TagResult], aperture_x: np.ndarray | None = None):
    """The figure of :func:`plot_results`."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    colors = {"combined": "C0", "rssi": "C1", "phase": "C2"}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.6), layout="constrained")
    x = np.linspace(0.02, 1.0, adarf.NUM_POINTS) if aperture_x is None else aperture_x
    ax.plot(x, np.zeros_like(x), "k.", ms=3, label=f"antenna track ({len(x)} aperture points)")
    ax.add_patch(
        plt.Rectangle(
            BOX_LO,
            BOX_HI[0] - BOX_LO[0],
            BOX_HI[1] - BOX_LO[1],
            fill=False,
            ls="--",
            color="grey",
            label="search box (the filter's uniform prior)",
        )
    )
    seen = set()
    for r in results:
        if r.tag not in seen:  # each tag's truth once, named
            ax.plot(*r.truth, "k*", ms=12, label=None if seen else "ground truth")
            ax.annotate(f"tag {r.tag}", r.truth, textcoords="offset points", xytext=(0, -14), ha="center", fontsize=8)
            seen.add(r.tag)
        lab = None if r.weighting in seen else f"{r.weighting}: final estimate per seed"
        seen.add(r.weighting)
        e = r.estimates[:, -1]
        ax.plot(e[:, 0], e[:, 1], "o", color=colors[r.weighting], mfc="none", label=lab)
        for p in e:  # which tag each estimate belongs to
            ax.plot([p[0], r.truth[0]], [p[1], r.truth[1]], "-", color=colors[r.weighting], lw=0.6, alpha=0.6)
        bx.plot(
            np.arange(1, adarf.NUM_POINTS + 1),
            r.errors.mean(0),
            _TAG_STYLES[r.tag % len(_TAG_STYLES)],
            color=colors[r.weighting],
            alpha=0.8,
            label=f"{r.weighting}, {_tag_name(r.tag)}",
        )
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"{results[0].experiment}: final estimates", aspect="equal")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    seeds = results[0].errors.shape[0]
    bx.set(
        xlabel="aperture points read",
        ylabel="error (m)",
        title=f"error after each point (mean over {seeds} seed{'s' if seeds > 1 else ''})",
        yscale="log",
    )
    bx.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    bx.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    bx.yaxis.set_minor_formatter(NullFormatter())
    bx.grid(alpha=0.3)
    # nine lines: a colour per weighting, a line style per tag, explained apart rather than one by one
    weightings = list(dict.fromkeys(r.weighting for r in results))
    tags = sorted({r.tag for r in results})
    handles = [Line2D([], [], color=colors[w], label=w) for w in weightings]
    handles += [Line2D([], [], color="k", ls=_TAG_STYLES[t % len(_TAG_STYLES)], label=_tag_name(t)) for t in tags]
    bx.legend(handles=handles, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    return fig


def plot_results(results: Sequence[TagResult], path: str, aperture_x: np.ndarray | None = None) -> None:
    """Two panels: the final estimates of every run beside the truth and the antenna track; error over the aperture."""
    import matplotlib.pyplot as plt

    fig = _draw_results(results, aperture_x)
    fig.savefig(path, dpi=110)
    plt.close(fig)
