"""[W]'s HF-RFID SLAM figures with a curve to reproduce: Figs. 3.5, 3.7, 4.4 and the kidnapping of Fig. 3.12.

Each is an experiment (:data:`EXPERIMENTS`, run by name with
:func:`jaxnav.experiments.registry.run`). A curve is a list of points, each
the mean over ``R`` seeded runs with its 95 % interval
(:func:`jaxnav.experiments.stats.mean_ci`); a run with nothing to score at a
point (no tag mapped, no tag detected that often) is NaN there, left out of
the point's mean and counted in the curve's ``unscored_runs`` (present only
when some point has such runs). A run that diverged (robot errors, tag-error
sums or an error over time that are not finite) is left out of every point
it belongs to and counted in the curve's ``diverged_runs`` (one count per
point, always present; ``runs`` holds the runs per point), and the tables
say "k of R runs diverged" at those points. [W] prints these figures as images only, so the result carries no
thesis numbers; the claim each figure supports is in ``notes`` and is what
the tests check:

* ``fig-3.5``: PF-SLAM's tag error falls with the number of times the tag was
  detected (random trajectory, 16 tags/m², 60 mm readers).
* ``fig-3.7``: robot and tag errors against the number of robot particles,
  PF-SLAM against FastSLAM (Table 3.1 rectangle, 16 tags/m²): PF-SLAM is
  accurate from few particles, FastSLAM needs many.
* ``fig-4.4``: errors against the reader footprint, 100–500 mm (4 tags/m²,
  the first rectangle of Table 4.1): PS ≈ PF below ~180 mm, PS better above, FastSLAM worst.
* ``kidnapping``: the robot error over time around a kidnapping ([W]
  §3.4.3, Fig. 3.12b), PF-SLAM and PS-SLAM.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.experiments import curves as curve_results
from jaxnav.experiments import report, stats
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.experiment import Cell, Experiment
from jaxnav.experiments.hf_slam import simulation as hf
from jaxnav.experiments.hf_slam.simulation import NOTHING_MAPPED
from jaxnav.experiments.hf_slam.tables import (
    CELLS_BY_NAME,
    FIVE_RECTANGLES,
    METHOD_LABELS,
    QUICK,
    diverged_in,
    plot_title,
    quick_setting,
    wrap_title,
)
from jaxnav.sim import tag_carpet as tc

__all__ = [
    "curve_experiment",
    "DETECTION_BINS",
    "PARTICLES",
    "LIMITS",
    "LIMIT_PARTICLES",
    "READER_SIDES",
    "EXPERIMENTS",
]

DETECTION_BINS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)
"""Bin edges of Fig. 3.5 — the n-th detection of a tag, grouped in bins ``[b_k, b_{k+1})``."""
PARTICLES = (100, 250, 500, 1000, 2000, 4000)
"""Robot particle counts of Fig. 3.7."""
READER_SIDES = (0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5)
"""Reader footprint sides (m) of Fig. 4.4."""


_NAN_TEXT = {
    "tag error dt (mm)": NOTHING_MAPPED,
    "tag error after the n-th detection (mm)": f"{report.NA} (no tag detected n times)",
}
"""How a curve point no run could score is written, per quantity (default :data:`jaxnav.experiments.report.NA`)."""


def render_curves(result: dict) -> str:
    """Terminal: per curve, its points as ``x = value: mean [lo, hi]`` (long curves thinned)."""
    return curve_results.render(result, METHOD_LABELS, _NAN_TEXT)


def markdown_curves(result: dict) -> str:
    """Markdown: one line per curve, one column per point."""
    return curve_results.markdown(result, METHOD_LABELS, _NAN_TEXT)


def _plot_options(result: dict) -> dict:
    marker = (0.0, "kidnapping") if result["experiment"] == "kidnapping" else None
    return {"labels": METHOD_LABELS, "title": plot_title, "wrap": wrap_title, "marker": marker}


def _draw_curves(result: dict):
    """The figure of :func:`plot_curves`."""
    return curve_results.draw(result, **_plot_options(result))


def plot_curves(result: dict, path: str) -> None:
    """The curves, one panel per quantity, with their 95 % intervals; a PNG at ``path``."""
    curve_results.plot(result, path, **_plot_options(result))


def curve_experiment(
    name: str,
    title: str,
    x_label: str,
    cells: Any,
    summarize: Any,
    notes: str = "",
    x_log: bool = False,
) -> Experiment:
    """A figure experiment: ``summarize(raw, cells, quick)`` gives its curves (:mod:`jaxnav.experiments.curves`)."""
    CELLS_BY_NAME[name] = cells
    exp = curve_results.curve_experiment(
        name,
        title,
        x_label,
        cells,
        summarize,
        notes,
        x_log,
        METHOD_LABELS,
        _NAN_TEXT,
        compiler_options=sw.LIGHT_COMPILE,
    )
    return replace(exp, render=render_curves, markdown=markdown_curves, plot=plot_curves)


# ---------------------------------------------------------------------------
# Fig. 3.5: tag error against detections


class TagErrorBins(NamedTuple):
    sums: jax.Array  # [bins] summed tag error (mm) of the estimates after the n-th detection, n in the bin
    counts: jax.Array  # [bins]


def _fig35_setting(quick: bool) -> hf.HFSetting:
    s = hf.HFSetting(density=16.0, reader_side=0.06, trajectory="random", carpet=(1.5, 1.5), random_steps=2000)
    return replace(s, **{**QUICK, "carpet": (1.2, 1.2), "random_steps": 600}) if quick else s


def _fig35_fn(setting: hf.HFSetting):
    edges = jnp.asarray(DETECTION_BINS + (1 << 30,))

    def fn(key):
        k_world, k_filter = jax.random.split(key)
        world = hf.make_world(k_world, setting)
        _, trace = hf.filter_world(k_filter, "pf_slam", setting, world)
        tags = tc.tag_positions(world.carpet)
        valid = trace.slot_ids >= 0
        err = 1000 * jnp.linalg.norm(trace.slot_estimates - tags[jnp.clip(trace.slot_ids, 0)], axis=-1)
        b = jnp.searchsorted(edges, trace.slot_counts, side="right") - 1  # bin of each (step, slot)
        one_hot = (b[..., None] == jnp.arange(len(DETECTION_BINS))) & valid[..., None]
        return TagErrorBins(
            jnp.sum(jnp.where(one_hot, err[..., None], 0.0), axis=(0, 1)), jnp.sum(one_hot, axis=(0, 1))
        )

    return fn


def _fig35_cells(quick):
    s = _fig35_setting(quick)
    return [Cell("pf_slam", "pf_slam", "pf_slam", s, _fig35_fn(s))]


def _fig35_summary(raw, cells, quick):
    r = raw["pf_slam"]
    diverged = stats.diverged_runs(r["sums"], r["counts"])  # the sums are 0, never NaN, where nothing was detected
    per_run = np.where(r["counts"] > 0, r["sums"] / np.maximum(r["counts"], 1), np.nan)  # [R, bins]
    bins = range(per_run.shape[1])
    curve = curve_results.summarize_points(DETECTION_BINS, [per_run[:, k] for k in bins], [diverged] * len(bins))
    curve["samples"] = np.asarray(r["counts"])[~diverged].sum(axis=0).astype(int).tolist()
    return [{"method": "pf_slam", "quantity": "tag error after the n-th detection (mm)", **curve}]


FIG_3_5 = curve_experiment(
    "fig-3.5",
    "PF-SLAM tag error against the number of detections ([W] Fig. 3.5)",
    "detections n",
    _fig35_cells,
    _fig35_summary,
    x_log=True,
    notes="[W]: the error falls as a tag is detected from more places; it converges slowly after ~65 detections.",
)


# ---------------------------------------------------------------------------
# Fig. 3.7: errors against robot particles


def _fig37_cells(quick):
    base = hf.HFSetting(density=16.0, reader_side=0.06, trajectory="rectangle")
    counts = (QUICK["robot_particles"], 200) if quick else PARTICLES  # the first shares Table 3.1's quick cells
    out = []
    for method in ("pf_slam", "fastslam"):
        for n in counts:
            s = replace(quick_setting(base) if quick else base, robot_particles=n)
            out.append(Cell(f"{method}|{n}", str(n), method, s, hf.error_cell(method, s)))
    return out


def _fig37_summary(raw, cells, quick):
    curves = []
    for method in ("pf_slam", "fastslam"):
        members = [c for c in cells if c.method == method]
        xs = [c.setting.robot_particles for c in members]
        diverged = [diverged_in(raw[c.id]) for c in members]
        for col, label in (("dr_mm", "robot error dr (mm)"), ("dt_mm", "tag error dt (mm)")):
            per_point = [raw[c.id][col] for c in members]
            curves.append(
                {"method": method, "quantity": label, **curve_results.summarize_points(xs, per_point, diverged)}
            )
    return curves


FIG_3_7 = curve_experiment(
    "fig-3.7",
    "Errors against robot particles, PF-SLAM vs FastSLAM, 16 tags/m² rectangle ([W] Fig. 3.7)",
    "robot particles",
    _fig37_cells,
    _fig37_summary,
    x_log=True,
    notes="[W]: PF-SLAM is accurate and stable from few particles; FastSLAM's errors are large with few and settle with many.",
)


# ---------------------------------------------------------------------------
# Fig. 3.7 again: what holds PF-SLAM's error flat as robot particles grow

LIMITS = (
    ("PF-SLAM, J = 100", {}),
    ("PF-SLAM, J = 1000", {"tag_particles": 1000}),
    ("PF-SLAM, map known", {"map_known": True}),
)
"""The curves of ``fig-3.7-limits``: Fig. 3.7's PF-SLAM (J = 100 tag particles), ten times the tag
particles, and the tags surveyed (``HFSetting.map_known``: no mapping error at all)."""
LIMIT_PARTICLES = (100, 500, 2000, 4000)
"""Robot particle counts of ``fig-3.7-limits``."""


def _limits_cells(quick):
    base = hf.HFSetting(density=16.0, reader_side=0.06, trajectory="rectangle")
    counts = (QUICK["robot_particles"], 200) if quick else LIMIT_PARTICLES
    out = []
    for label, change in LIMITS:
        for n in counts:
            s = replace(quick_setting(base) if quick else base, robot_particles=n, **change)
            if quick and "tag_particles" in change:
                s = replace(s, tag_particles=10 * QUICK["tag_particles"])
            out.append(Cell(f"{label}|{n}", label, "pf_slam", s, hf.error_cell("pf_slam", s)))
    return out


def _limits_summary(raw, cells, quick):
    curves = []
    for label, _ in LIMITS:
        members = [c for c in cells if c.row == label]
        xs = [c.setting.robot_particles for c in members]
        diverged = [diverged_in(raw[c.id]) for c in members]
        columns = (("dr_mm", "robot error dr (mm)"), ("dt_mm", "tag error dt (mm)"))
        for col, quantity in columns if "map known" not in label else columns[:1]:
            per_point = [raw[c.id][col] for c in members]
            curves.append(
                {"method": label, "quantity": quantity, **curve_results.summarize_points(xs, per_point, diverged)}
            )
    return curves


FIG_3_7_LIMITS = curve_experiment(
    "fig-3.7-limits",
    "What holds PF-SLAM's error flat in robot particles: tag particles and a known map, 16 tags/m² rectangle ([W] Fig. 3.7)",
    "robot particles",
    _limits_cells,
    _limits_summary,
    x_log=True,
    notes=(
        "[W] Fig. 3.7 has PF-SLAM's error fall as robot particles grow; ours is flat. Each curve lifts one "
        "limit: ten times the tag particles (a finer tag posterior), and the tags surveyed at their true "
        "positions (PF-SLAM as localization on a known carpet through the same eq. 3.7: what the readers' "
        "60 mm resolution and the odometry leave). A curve that stays flat where its limit is lifted "
        "rules that limit out."
    ),
)


# ---------------------------------------------------------------------------
# Fig. 4.4: errors against reader footprint


def _fig44_cells(quick):
    sides = (0.1, 0.3) if quick else READER_SIDES
    out = []
    for method in ("ps_slam", "pf_slam", "fastslam"):
        for side in sides:
            # one rectangle, the first of Table 4.1's: every (side, rectangle) pair is its own compilation
            for i, rect in enumerate(FIVE_RECTANGLES[:1]):
                s = hf.HFSetting(
                    density=4.0, reader_side=side, trajectory="rectangle", carpet=(4.0, 3.5), rectangle=rect
                )
                s = quick_setting(s) if quick else s
                out.append(Cell(f"{method}|{side:g}|{i}", f"{side:g}", method, s, hf.error_cell(method, s)))
    return out


def _fig44_summary(raw, cells, quick):
    curves = []
    for method in ("ps_slam", "pf_slam", "fastslam"):
        sides = sorted({c.setting.reader_side for c in cells if c.method == method})
        at = [[c for c in cells if c.method == method and c.setting.reader_side == s] for s in sides]
        diverged = [np.concatenate([diverged_in(raw[c.id]) for c in members]) for members in at]
        for col, label in (("dr_mm", "robot error dr (mm)"), ("dt_mm", "tag error dt (mm)")):
            per_point = [np.concatenate([raw[c.id][col] for c in members]) for members in at]
            curves.append(
                {
                    "method": method,
                    "quantity": label,
                    **curve_results.summarize_points([1000 * s for s in sides], per_point, diverged),
                }
            )
    return curves


FIG_4_4 = curve_experiment(
    "fig-4.4",
    "Errors against the reader footprint, 4 tags/m², one rectangle ([W] Fig. 4.4)",
    "reader side (mm)",
    _fig44_cells,
    _fig44_summary,
    notes="[W]: PS ≈ PF below ~180 mm, PS better above; FastSLAM worst throughout. Rectangle: the first of Table 4.1's five.",
)


# ---------------------------------------------------------------------------
# kidnapping ([W] §3.4.3, Fig. 3.12)


class KidnapCurve(NamedTuple):
    error_mm: jax.Array  # [T] robot position error per step
    kidnap_step: jax.Array


def _kidnap_setting(quick):
    s = hf.HFSetting(density=16.0, reader_side=0.06, trajectory="kidnapping", laps=1)
    return replace(s, robot_particles=200, tag_particles=30) if quick else s


def _kidnap_fn(method, setting):
    def fn(key):
        k_world, k_filter = jax.random.split(key)
        world = hf.make_world(k_world, setting)
        result = hf.run_method(k_filter, method, setting, world)
        err = 1000 * jnp.linalg.norm(result.estimates[:, :2] - world.run.true_poses[:, :2], axis=1)
        return KidnapCurve(err, jnp.argmax(world.run.kidnapped))

    return fn


def _kidnap_cells(quick):
    s = _kidnap_setting(quick)
    return [Cell(m, m, m, s, _kidnap_fn(m, s)) for m in ("pf_slam", "ps_slam")]


def _kidnap_summary(raw, cells, quick):
    curves = []
    for c in cells:
        err = np.asarray(raw[c.id]["error_mm"], np.float64)  # [R, T]
        diverged = stats.diverged_runs(err)
        k = int(raw[c.id]["kidnap_step"][0])
        steps = err.shape[1]
        window = range(max(0, k - 100), min(steps, k + 300), 5)
        dt = c.setting.dt
        curves.append(
            {
                "method": c.method,
                "quantity": "robot error (mm)",
                **curve_results.summarize_points(
                    [(i - k) * dt for i in window], [err[:, i] for i in window], [diverged] * len(window)
                ),
                "before_mm": stats.summarize(err[:, max(0, k - 50) : k].mean(axis=1), diverged=diverged).mean,
                "after_mm": stats.summarize(err[:, k + 50 : k + 150].mean(axis=1), diverged=diverged).mean,
            }
        )
    return curves


KIDNAPPING = curve_experiment(
    "kidnapping",
    "Robot error around a kidnapping, 16 tags/m², 60 mm readers ([W] §3.4.3, Fig. 3.12)",
    "time since the kidnapping (s)",
    _kidnap_cells,
    _kidnap_summary,
    notes="[W]: the error jumps when the robot is kidnapped and returns to its level before within a short time.",
)

EXPERIMENTS = (FIG_3_5, FIG_3_7, FIG_3_7_LIMITS, FIG_4_4, KIDNAPPING)
"""The figures (listed by :mod:`jaxnav.experiments.catalog`)."""
