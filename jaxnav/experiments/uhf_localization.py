"""[A] §5.2 reproduced: UHF-RFID tag localization from RSSI and phase ([A] Alg. 6) as registered experiments.

Three experiments of [A] (:mod:`jaxnav.experiments.registry`), each a set of
curves of the position RMSE over time with its 95 % interval over ``R``
seeded runs, and [A]'s value beside ours where [A] gives one:

* ``fig-5.3`` ([A] Fig. 5.3): RSSI-only, 3D, strong multipath, the anchor tag
  at 0.25, 0.5, 1, 2 and 4 λ from the tag (λ = 0.173 m, [A] §5.2). [A] prints
  no numbers, only the claim: the RMSE grows with the anchor-to-tag distance,
  sharply beyond λ/2.
* ``fig-5.5`` ([A] §5.2.1, Fig. 5.5): 3D (the 2 × 3 × 2 m box of [A]),
  light and strong multipath, the three weightings of Alg. 6 (RSSI only,
  phase only, combined), the anchor 0.05 m from the tag.
* ``fig-5.6`` ([A] §5.2.2, Fig. 5.6): the same in 2D (a 2 × 3 m search at
  the known tag height).

One run (:func:`run_once`; all choices ours, [A] gives no geometry)
-------------------------------------------------------------------
* The tag is drawn uniformly from the run key inside :data:`~jaxnav.sim.uhf_reader.SEARCH_BOX_A`
  shrunk by :data:`MARGIN` = 0.3 m on every side (not at the box centre: the
  uniform prior's mean sits there, which would flatter every method); its
  phase offset is uniform on ``[−π, π)``.
* The anchor tag is at the setting's distance from the tag in a direction
  drawn from the run key, inside the search box (:func:`anchor_position`:
  the rule of :func:`jaxnav.sim.uhf_reader.anchor_position`, written in
  ``jnp`` because that one is host-side and a run is traced; the tests check
  that both give the same point for the same key). Phase offset 0.
* One reader antenna (boresight +y) drives a lawnmower
  (:func:`jaxnav.sim.uhf_reader.lawnmower_path`) of passes along x over the
  box's full width, 0.5 and 0.2 m in front of its ``y = 0`` face, at heights
  0.5 and 1.5 m (two depths × two heights: the 3D-observable pattern of
  :mod:`jaxnav.sim.uhf_reader`, "Paths"). One read slot per step; the reader
  moves at :data:`SPEED` = 0.2 m/s along the passes (connector moves are
  sampled no coarser), so step ``t`` is at ``time_s = t · Δt`` with
  ``Δt = pass spacing / speed`` (0.2 s in the full variant: 242 steps, 48.2 s).
* Reads of the tag and of the anchor: :func:`jaxnav.sim.uhf_reader.simulate_reads`
  with the ``"light"`` or ``"strong"`` preset. ``(k, θ)`` is fitted from all
  the anchor's reads with :func:`jaxnav.models.uhf_rfid.estimate_gamma`
  (closed form, [A] App. D–E; the defaults below 30 valid reads) using the
  anchor's known ``a`` (:func:`jaxnav.models.uhf_rfid.power_scale`).
* [A] Alg. 6 (:mod:`jaxnav.localization.rfid_tag`, 2,000 particles in the
  full variant, ``σ_phase = 0.1 λ`` in both environments, ESS threshold 0.1,
  Gaussian refresh) runs on the tag's reads; in 2D ``tag_height`` is the
  tag's true height. The three weightings of a setting run on the **same**
  draws (tag, anchor, reads, filter keys): common random numbers, so their
  differences are not sampling noise between different scenes.
* The per-run result is the position error ``‖p̂_t − p‖`` over time (m; in
  2D over x, y only: the height is known, its error is 0).

Summaries (:func:`rmse_summary`)
--------------------------------
``RMSE(t) = √(mean over runs of err_r(t)²)``. Its 95 % interval is the
Student-t interval of the mean squared error over the runs
(:func:`jaxnav.experiments.sweep.mean_ci`'s ``mean ± t_{0.975, R−1}·s/√R``, on
``err²``) mapped through the square root, its lower end clipped at 0 (a
monotone map keeps the interval's coverage). ``final_rmse_m`` is the same over
the last :data:`FINAL_FRACTION` = 10 % of the steps: each run's mean squared
error over those steps, then the root of their mean. The uniform prior's RMSE
(the box centre as estimate, :func:`prior_rmse`) is the reference a method
must beat: 0.90 m in 3D, 0.80 m in 2D.

The RMSE is what [A] plots, but it is ruled by the few runs in which Alg. 6
locks onto a wrong mode and never leaves it. One mechanism, traced in a
light-multipath run: with the stepped antenna pattern a tag in a side lobe
(10 dB down) reads like one about 3× farther in the main lobe, the first
reads make the weights collapse, and the Gaussian refresh of the resampled
set then keeps the particles in the wrong place for good (under strong
multipath the mis-specified RSSI model adds more). So the
result's ``diagnostics`` also give, per curve, the median over runs of the
final error and the number of *lost* runs (final error above
:data:`FAILED_M` = 0.5 m); the tables print both beside the RMSE.

Compilation: a cell runs :func:`run_once` ``(weightings, dims, M)`` with the
setting's arrays (:class:`UHFInputs`: path, multipath preset, anchor distance,
filter parameters) as shared arguments, so cells that differ only in data
(light against strong multipath, the anchor distances of fig-5.3) share one
compilation; the three weightings of a fig-5.5/5.6 setting are one function.
The quick variant of fig-5.3 (anchor at λ/2 and 4λ only) runs that
three-weighting function too (and reports its RSSI curves: the same runs,
same keys) so that the test suite compiles one 3D function, not two.
"""

from __future__ import annotations

import functools
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.resampling import REFRESHES
from jaxnav.core.validation import check_choice, check_nonnegative, check_positive, check_positive_int
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.registry import Cell, Experiment, register
from jaxnav.localization import rfid_tag as rt
from jaxnav.models import uhf_rfid as U
from jaxnav.sim import uhf_reader as S

__all__ = [
    "WAVELENGTH",
    "MARGIN",
    "SPEED",
    "PASS_DEPTHS",
    "PASS_HEIGHTS",
    "CLOSE_ANCHOR",
    "ANCHOR_LAMBDAS",
    "METHODS",
    "FINAL_FRACTION",
    "FAILED_M",
    "QUICK",
    "UHFSetting",
    "UHFInputs",
    "Scene",
    "run_inputs",
    "anchor_position",
    "draw_scene",
    "run_once",
    "prior_rmse",
    "rmse_summary",
    "PAPER",
]

WAVELENGTH = U.A_WAVELENGTH
"""λ = 0.173 m, as [A] §5.2 states (SPEC §4: probably λ/2 of an 866 MHz reader; we use [A]'s number)."""
MARGIN = 0.3
"""The tag is drawn uniformly in the search box shrunk by this much (m) on every side."""
SPEED = 0.2
"""Reader speed along the passes (m/s); one read per step of ``pass spacing / SPEED`` seconds."""
PASS_DEPTHS = (-0.5, -0.2)
"""y of the lawnmower passes (m), in front of the box's y = 0 face (boresight +y)."""
PASS_HEIGHTS = (0.5, 1.5)
"""z of the lawnmower passes (m)."""
CLOSE_ANCHOR = 0.05
"""Anchor-to-tag distance (m) of fig-5.5/5.6 ("located close to the unknown tags", [A] §5.2.1; 0.29 λ)."""
ANCHOR_LAMBDAS = (0.25, 0.5, 1.0, 2.0, 4.0)
"""fig-5.3's anchor-to-tag distances in wavelengths."""
METHODS = ("rssi", "phase", "combined")
"""The weightings of [A] Alg. 6 (:data:`jaxnav.localization.rfid_tag.WEIGHTINGS`), in the order of the tables."""
FINAL_FRACTION = 0.1
"""``final_rmse_m`` is over the last 10 % of the steps."""
MULTIPATHS = ("light", "strong")


@dataclass(frozen=True)
class UHFSetting:
    """One simulated tag-localization setting (hashable).

    Attributes:
        multipath: ``"light"`` or ``"strong"`` (:data:`jaxnav.sim.uhf_reader.MULTIPATH_NAMES`).
        dims: 3 (search x, y, z) or 2 (z known).
        anchor_distance: anchor-to-tag distance (m).
        num_particles: M of [A] Alg. 6.
        steps_per_pass: reader poses per lawnmower pass (the pass spacing is
            ``2 m / (steps_per_pass − 1)``).
        speed: reader speed (m/s): the step period is spacing / speed.
        margin: the tag is drawn this far (m) inside the search box.
        refresh: Alg. 6's redraw after resampling: ``"gaussian"`` ([A] §4.3.3) or
            ``"kernel"`` (the regularised filter, ours; see ``uhf-refresh``).
    """

    multipath: str = "light"
    dims: int = 3
    anchor_distance: float = CLOSE_ANCHOR
    num_particles: int = 2000
    steps_per_pass: int = 51
    speed: float = SPEED
    margin: float = MARGIN
    refresh: str = "gaussian"

    def __post_init__(self) -> None:
        check_choice("multipath", self.multipath, MULTIPATHS)
        check_choice("refresh", self.refresh, REFRESHES)
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {self.dims!r}")
        check_nonnegative("anchor_distance", self.anchor_distance)
        check_positive_int("num_particles", self.num_particles)
        if check_positive_int("steps_per_pass", self.steps_per_pass) < 2:
            raise ValueError(f"steps_per_pass must be ≥ 2, got {self.steps_per_pass}")
        check_positive("speed", self.speed)
        check_nonnegative("margin", self.margin)
        lo, hi = S.SEARCH_BOX_A
        if not np.all(hi - lo > 2 * self.margin):
            raise ValueError(
                f"margin {self.margin} m leaves no room for the tag in the search box {lo.tolist()}–{hi.tolist()}"
            )

    @property
    def step_period(self) -> float:
        """Seconds per step: the pass spacing over the speed."""
        lo, hi = S.SEARCH_BOX_A
        return float(hi[0] - lo[0]) / (self.steps_per_pass - 1) / self.speed


QUICK = dict(num_particles=300, steps_per_pass=21)
"""What the quick variants change: 300 particles, a pass spacing of 0.1 m (97 steps of 0.5 s)."""


class UHFInputs(NamedTuple):
    """The arrays of one setting, given whole to every run of a cell (cells of equal shapes share a compilation).

    Attributes:
        path: ``[T, 4]`` reader poses (m, m, m, rad).
        multipath: the :class:`~jaxnav.sim.uhf_reader.Multipath` preset (float32 arrays).
        anchor_distance: m.
        margin: m.
        filter: :class:`~jaxnav.localization.rfid_tag.RFIDTagParams` (search box, channel,
            ``σ_phase``; ``gamma`` and ``tag_height`` are replaced in each run).
    """

    path: jax.Array
    multipath: S.Multipath
    anchor_distance: jax.Array
    margin: jax.Array
    filter: rt.RFIDTagParams


def _path(s: UHFSetting) -> np.ndarray:
    lo, hi = S.SEARCH_BOX_A
    return S.lawnmower_path((float(lo[0]), float(hi[0])), PASS_DEPTHS, PASS_HEIGHTS, s.steps_per_pass)


def run_inputs(s: UHFSetting) -> UHFInputs:
    """The arrays of setting ``s`` (host-side, validated)."""
    lo, hi = S.SEARCH_BOX_A
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return UHFInputs(
        path=f32(_path(s)),
        multipath=jax.tree_util.tree_map(f32, S.get_multipath(s.multipath)),
        anchor_distance=f32(s.anchor_distance),
        margin=f32(s.margin),
        filter=rt.default_params(box_lo=lo, box_hi=hi),
    )


def anchor_position(
    key: jax.Array, tag: jax.Array, distance: jax.Array, box_lo: jax.Array, box_hi: jax.Array, tries: int = 256
) -> jax.Array:
    """A point at ``distance`` (m) from ``tag [3]`` in a random direction, inside the box: jittable.

    The rule and the draws of :func:`jaxnav.sim.uhf_reader.anchor_position` with
    ``key`` and ``box``: ``tries`` directions ``normal(key, (tries, 3))``
    normalised, the first candidate inside the box (and above the ground) is
    taken. Unlike that host-side function it cannot raise when no candidate is
    inside; it then returns the first candidate (impossible here: the tag is
    0.3 m inside the box and the distance at most 0.69 m, so more than a third
    of the sphere is inside).
    """
    u = jax.random.normal(key, (tries, 3), jnp.float32)
    u = u / jnp.maximum(jnp.linalg.norm(u, axis=1, keepdims=True), 1e-30)
    q = tag + distance * u
    lo = jnp.maximum(box_lo, jnp.array([-jnp.inf, -jnp.inf, 0.0], jnp.float32))
    inside = jnp.all(q >= lo - 1e-9, axis=1) & jnp.all(q <= box_hi + 1e-9, axis=1)
    return q[jnp.argmax(inside)]


class Scene(NamedTuple):
    """What a run draws before the reads: the tag ``[3]`` (m), its phase offset (rad), the anchor ``[3]`` (m)."""

    tag: jax.Array
    offset: jax.Array
    anchor: jax.Array


def _keys(key):
    return jax.random.split(key, 6)  # tag, offset, anchor, reads, filter init, filter run


def draw_scene(key: jax.Array, inputs: UHFInputs) -> Scene:
    """The tag, its offset and the anchor of the run with key ``key`` (the draws of :func:`run_once`)."""
    k_tag, k_off, k_anc = _keys(key)[:3]
    box_lo, box_hi = inputs.filter.box_lo, inputs.filter.box_hi
    lo, hi = box_lo + inputs.margin, box_hi - inputs.margin
    tag = lo + jax.random.uniform(k_tag, (3,)) * (hi - lo)
    offset = jax.random.uniform(k_off, (), minval=-math.pi, maxval=math.pi)
    return Scene(tag, offset, anchor_position(k_anc, tag, inputs.anchor_distance, box_lo, box_hi))


def _simulate_and_filter(key, inputs: UHFInputs, configs: Sequence[rt.RFIDTagConfig]):
    """``(scene, fit, reads of the tag, [trace per config])`` of one run (keys: :func:`_keys`)."""
    _, _, _, k_sim, k_init, k_run = _keys(key)
    scene = draw_scene(key, inputs)
    reads = S.simulate_reads(
        k_sim,
        inputs.path,
        jnp.stack([scene.tag, scene.anchor]),
        jnp.stack([scene.offset, jnp.zeros_like(scene.offset)]),
        multipath=inputs.multipath,
    )
    tag_reads = jax.tree_util.tree_map(lambda x: x[0], reads)
    anchor_reads = jax.tree_util.tree_map(lambda x: x[1], reads)
    a = S.anchor_power_scale(anchor_reads, scene.anchor)
    fit = U.estimate_gamma(anchor_reads.rssi.ravel(), a.ravel(), anchor_reads.mask.ravel())
    params = inputs.filter._replace(gamma=fit.params, tag_height=scene.tag[2])
    traces = []
    for cfg in configs:
        state0 = rt.init(k_init, cfg, params)
        traces.append(rt.run(k_run, cfg, params, tag_reads, state0)[1])
    return scene, fit, tag_reads, traces


def _error(estimate: jax.Array, tag: jax.Array, dims: int) -> jax.Array:
    d = estimate[..., :dims] - tag[:dims]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


@functools.cache
def run_once(weightings: tuple[str, ...], dims: int, num_particles: int, refresh: str = "gaussian"):
    """``(key, inputs: UHFInputs) -> {field: array}`` of one seeded run (cached: one function per arguments).

    Fields: ``err_<weighting>`` ``[T]`` position error over time (m) for each of
    ``weightings``; ``gamma_k``, ``gamma_theta`` the anchor's fit and
    ``gamma_default`` whether it fell back to the defaults; ``tag_reads``,
    ``anchor_reads`` the numbers of valid reads.
    """
    weightings = tuple(weightings)
    for w in weightings:
        check_choice("weighting", w, METHODS)
    check_choice("refresh", refresh, REFRESHES)
    configs = [
        rt.RFIDTagConfig(
            num_particles=int(num_particles),
            dims=int(dims),
            weighting=w,
            refresh=True if refresh == "gaussian" else refresh,
        )
        for w in weightings
    ]

    def fn(key: jax.Array, inputs: UHFInputs) -> dict:
        scene, fit, tag_reads, traces = _simulate_and_filter(key, inputs, configs)
        out = {f"err_{w}": _error(tr.estimate, scene.tag, dims) for w, tr in zip(weightings, traces)}
        out.update(
            gamma_k=fit.params.k,
            gamma_theta=fit.params.theta,
            gamma_default=fit.used_default,
            tag_reads=jnp.sum(tag_reads.mask, dtype=jnp.int32),
            anchor_reads=fit.n_valid.astype(jnp.int32),
        )
        return out

    return fn


# ---------------------------------------------------------------------------
# summaries


def prior_rmse(dims: int, margin: float = MARGIN) -> float:
    """RMSE (m) of the uniform prior's mean (the box centre) for a tag uniform in the shrunk box: √(Σ wᵢ²/12)."""
    lo, hi = S.SEARCH_BOX_A
    w = (hi - lo - 2 * margin)[:dims]
    return float(np.sqrt(np.sum(w**2) / 12.0))


@functools.cache
def _t975(dof: int) -> float:
    return sw.student_t_quantile(0.975, dof)


def _mean_ci_columns(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`jaxnav.experiments.sweep.mean_ci` of every column of ``values [R, n]`` (finite values), vectorised."""
    v = np.asarray(values, np.float64)
    r = v.shape[0]
    m = v.mean(axis=0)
    if r < 2:
        return m, m.copy(), m.copy()
    half = _t975(r - 1) * v.std(axis=0, ddof=1) / math.sqrt(r)
    return m, m - half, m + half


def rmse_summary(err: np.ndarray, final_fraction: float = FINAL_FRACTION) -> tuple[dict, dict]:
    """RMSE over time and over the last steps, with 95 % intervals (module docstring, "Summaries").

    Args:
        err: ``[R, T]`` per-run errors (m).
        final_fraction: share of the last steps for the final RMSE.

    Returns:
        ``({"mean": [T], "ci95": [[lo, hi]] * T}, {"mean", "ci95": [lo, hi]})``.
    """
    e2 = np.square(np.asarray(err, np.float64))
    if e2.ndim != 2:
        raise ValueError(f"err must have shape [R, T], got {e2.shape}")
    m, lo, hi = _mean_ci_columns(e2)
    curve = {
        "mean": np.sqrt(m).tolist(),
        "ci95": np.stack([np.sqrt(np.maximum(lo, 0.0)), np.sqrt(hi)], axis=1).tolist(),
    }
    fm, flo, fhi = _mean_ci_columns(_final_mse(e2, final_fraction)[:, None])
    final = {"mean": float(np.sqrt(fm[0])), "ci95": [float(np.sqrt(max(flo[0], 0.0))), float(np.sqrt(fhi[0]))]}
    return curve, final


def _final_mse(e2: np.ndarray, final_fraction: float = FINAL_FRACTION) -> np.ndarray:
    """``[R]`` each run's mean squared error over the last ``final_fraction`` of the steps of ``e2 [R, T]``."""
    n_final = max(1, int(math.ceil(final_fraction * e2.shape[1] - 1e-9)))
    return e2[:, -n_final:].mean(axis=1)


FAILED_M = 0.5
"""A run whose final error (RMS over the last 10 % of steps) exceeds 0.5 m is counted as lost in the tables."""


# ---------------------------------------------------------------------------
# [A]'s values

_LIGHT = "< 0.20 m for all three weightings ([A] abstract, §5.2.1)"
_NO_2D = "[A] §5.2.2 gives no numbers: lower than the corresponding 3D curve"
PAPER: dict[tuple[str, int, str], tuple[float | None, str]] = {
    ("light", 3, "rssi"): (0.20, _LIGHT + "; about the same as phase-only"),
    ("light", 3, "phase"): (0.20, _LIGHT + "; phase-only 0.10–0.20 m, above 0.40 m for some time after the start"),
    ("light", 3, "combined"): (0.20, _LIGHT + "; the combination neither improves nor worsens it"),
    ("strong", 3, "rssi"): (0.60, "≈ 0.60 m ([A] abstract)"),
    ("strong", 3, "phase"): (0.20, "≈ 0.20 m ([A] abstract, §5.2.1); above 1.5 m before it converged"),
    ("strong", 3, "combined"): (0.40, "≈ 0.40 m ([A] abstract): below RSSI-only"),
    ("light", 2, "rssi"): (None, _NO_2D),
    ("light", 2, "phase"): (None, _NO_2D),
    ("light", 2, "combined"): (None, _NO_2D + "; below RSSI-only, not essentially below phase-only"),
    ("strong", 2, "rssi"): (None, _NO_2D),
    ("strong", 2, "phase"): (None, _NO_2D),
    ("strong", 2, "combined"): (None, _NO_2D + "; below RSSI-only, not essentially below phase-only"),
}
"""[A]'s final RMSE (m) per ``(multipath, dims, method)``, or None, with where it comes from."""

FIG_5_3_NOTE = (
    f"[A] Fig. 5.3 gives no numbers: the RMSE grows with the anchor-to-tag distance, sharply beyond "
    f"λ/2 = {WAVELENGTH / 2:.4f} m"
)


def _setting_json(s: UHFSetting) -> dict:
    return {
        "multipath": s.multipath,
        "dims": s.dims,
        "anchor_distance_m": round(s.anchor_distance, 6),
        "anchor_distance_lambda": round(s.anchor_distance / WAVELENGTH, 4),
        "refresh": s.refresh,
    }


def _label(setting: dict) -> str:
    refresh = setting.get("refresh", "gaussian")
    return (
        f"{setting['multipath']}, {setting['dims']}D, anchor {setting['anchor_distance_m']:.3g} m "
        f"({setting['anchor_distance_lambda']:.2g} λ)" + ("" if refresh == "gaussian" else f", {refresh} refresh")
    )


# ---------------------------------------------------------------------------
# rendering


def _curve_at(row: dict, frac: float) -> float:
    rm = row["rmse_m"]["mean"]
    return rm[min(len(rm) - 1, int(round(frac * (len(rm) - 1))))]


def _robust(result: dict, row: dict) -> tuple[float | None, str]:
    """The row's median final error and lost-run count from ``result["diagnostics"]`` (None, "–" if absent)."""
    for d in result.get("diagnostics", ()):
        if d["setting"] == row["setting"] and row["method"] in d.get("final_median_m", {}):
            return d["final_median_m"][row["method"]], str(d["final_lost_runs"][row["method"]])
    return None, "–"


def _fmt(v: float | None, digits: int = 2) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def render_table(result: dict) -> str:
    """Terminal table: per curve, the RMSE at 10 % and 25 % of the run, the final RMSE [95 % interval] and [A]'s."""
    t_end = result["rows"][0]["time_s"][-1] if result["rows"] else 0.0
    lines = [
        f"{result['experiment']}: {result['title']}",
        f"  ({result['runs']} runs per curve{', quick variant' if result.get('quick') else ''}; RMSE in m; final: "
        f"last {FINAL_FRACTION:.0%} of {t_end:.1f} s, mean [95 % interval]; uniform prior: "
        + ", ".join(f"{_fmt(v)} m in {d}D" for d, v in sorted(result["prior_rmse_m"].items()))
        + ")",
    ]
    head = (
        f"{'setting':<38}{'method':<10}{'@10%':>7}{'@25%':>7}{'final':>8}{'95 % interval':>16}{'median':>8}"
        f"{'lost':>7}{'[A]':>7}  note"
    )
    lines += [head, "-" * (len(head) + 30)]
    for r in result["rows"]:
        f = r["final_rmse_m"]
        med, lost = _robust(result, r)
        lines.append(
            f"{_label(r['setting']):<38}{r['method']:<10}{_fmt(_curve_at(r, 0.1)):>7}{_fmt(_curve_at(r, 0.25)):>7}"
            f"{_fmt(f['mean']):>8}{'[' + _fmt(f['ci95'][0]) + ', ' + _fmt(f['ci95'][1]) + ']':>16}"
            f"{_fmt(med, 3):>8}{lost:>7}{_fmt(f['paper']):>7}  {f['paper_note']}"
        )
    lines.append(
        f"  median: median over runs of the run's final error; lost: runs whose final error exceeds {FAILED_M} m"
    )
    if result.get("notes"):
        lines += ["", textwrap.fill(result["notes"], 120)]
    return "\n".join(lines)


def markdown_table(result: dict) -> str:
    """Markdown: one line per curve."""
    lines = [
        f"**{result['experiment']}** — {result['title']} ({result['runs']} runs per curve; RMSE in m; final = "
        f"last {FINAL_FRACTION:.0%} of the steps, mean [95 % interval]; uniform prior "
        + ", ".join(f"{_fmt(v)} m in {d}D" for d, v in sorted(result["prior_rmse_m"].items()))
        + ")",
        "",
        "| setting | method | RMSE @10 % | RMSE @25 % | final RMSE | median final error | lost runs | [A] | [A] says |",
        "|" + " --- |" * 9,
    ]
    for r in result["rows"]:
        f = r["final_rmse_m"]
        med, lost = _robust(result, r)
        lines.append(
            f"| {_label(r['setting'])} | {r['method']} | {_fmt(_curve_at(r, 0.1))} | {_fmt(_curve_at(r, 0.25))} | "
            f"{_fmt(f['mean'], 3)} [{_fmt(f['ci95'][0], 3)}, {_fmt(f['ci95'][1], 3)}] | {_fmt(med, 3)} | "
            f"{lost}/{result['runs']} | {_fmt(f['paper'])} | {f['paper_note']} |"
        )
    lines += [
        "",
        f"Median final error: median over runs of each run's final error (RMS over the last "
        f"{FINAL_FRACTION:.0%} of steps); lost runs: final error above {FAILED_M} m.",
    ]
    if result.get("notes"):
        lines += ["", result["notes"]]
    return "\n".join(lines)


_COLORS = {"rssi": "tab:red", "phase": "tab:blue", "combined": "tab:green"}
_KERNEL_COLOR = "tab:purple"


def _band(ax, r, color, label):
    t = np.asarray(r["time_s"])
    m = np.asarray(r["rmse_m"]["mean"])
    ci = np.asarray(r["rmse_m"]["ci95"])
    ax.plot(t, m, "-", color=color, lw=1.3, label=label)
    ax.fill_between(t, ci[:, 0], ci[:, 1], color=color, alpha=0.15, lw=0)


def plot_curves(result: dict, path: str) -> None:
    """fig-5.5/5.6: RMSE over time, one panel per multipath, three weightings, [A]'s values as dashed lines."""
    import matplotlib.pyplot as plt

    panels = [m for m in MULTIPATHS if any(r["setting"]["multipath"] == m for r in result["rows"])]
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.4), squeeze=False, sharey=True)
    for ax, mp in zip(axes[0], panels):
        rows = [r for r in result["rows"] if r["setting"]["multipath"] == mp]
        for r in rows:
            refresh = r["setting"].get("refresh", "gaussian")
            c = _COLORS[r["method"]] if refresh == "gaussian" else _KERNEL_COLOR
            f = r["final_rmse_m"]
            name = r["method"] if refresh == "gaussian" else f"{r['method']}, {refresh} refresh"
            _band(ax, r, c, f"{name} (final {f['mean']:.2f} m)")
            if f["paper"] is not None:
                ax.axhline(f["paper"], color=c, ls="--", lw=1.0, alpha=0.8)
        dims = rows[0]["setting"]["dims"]
        ax.axhline(result["prior_rmse_m"][str(dims)], color="0.4", ls=":", lw=1.0, label="uniform prior")
        ax.set_title(f"{mp} multipath, {dims}D, anchor {rows[0]['setting']['anchor_distance_m']:g} m", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[0][0].set_ylabel("RMSE (m), 95 % CI; dashed: [A]")
    fig.suptitle(f"{result['experiment']}: {result['title']} ({result['runs']} runs)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_anchor(result: dict, path: str) -> None:
    """fig-5.3: RMSE over time per anchor distance, and the final RMSE against the distance (λ/2 marked)."""
    import matplotlib.pyplot as plt

    rows = result["rows"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.4))
    cmap = plt.get_cmap("viridis")
    for i, r in enumerate(rows):
        _band(
            ax,
            r,
            cmap(i / max(1, len(rows) - 1)),
            f"{r['setting']['anchor_distance_lambda']:g} λ ({r['setting']['anchor_distance_m']:.3f} m)",
        )
    ax.axhline(result["prior_rmse_m"]["3"], color="0.4", ls=":", lw=1.0, label="uniform prior")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMSE (m), 95 % CI")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, title="anchor-to-tag", title_fontsize=7)
    x = np.array([r["setting"]["anchor_distance_lambda"] for r in rows])
    m = np.array([r["final_rmse_m"]["mean"] for r in rows])
    ci = np.array([r["final_rmse_m"]["ci95"] for r in rows])
    bx.errorbar(
        x, m, yerr=[m - ci[:, 0], ci[:, 1] - m], fmt="o-", color="tab:red", capsize=3, label="RSSI-only, final RMSE"
    )
    med = [_robust(result, r)[0] for r in rows]
    if all(v is not None for v in med):
        bx.plot(x, med, "s--", color="tab:red", mfc="none", label="RSSI-only, median final error")
    bx.axvline(0.5, color="k", ls="--", lw=1.0, label="λ/2 ([A]: RMSE grows sharply beyond)")
    bx.axhline(result["prior_rmse_m"]["3"], color="0.4", ls=":", lw=1.0, label="uniform prior")
    bx.set_xscale("log", base=2)
    bx.set_xticks(x)
    bx.set_xticklabels([f"{v:g} λ" for v in x])
    bx.minorticks_off()
    bx.set_xlabel(f"anchor-to-tag distance (λ = {WAVELENGTH} m)")
    bx.set_ylabel("final RMSE (m)")
    bx.set_ylim(bottom=0)
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7)
    fig.suptitle(f"{result['experiment']}: {result['title']} ({result['runs']} runs)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------
# the experiments


def _summarize_cells(raw: dict, cells: Sequence[Cell], methods: Sequence[str], paper_fn) -> dict:
    rows, diagnostics = [], []
    for cell in cells:
        s, vals = cell.setting, raw[cell.id]
        setting = _setting_json(s)
        for w in methods:
            err = np.asarray(vals[f"err_{w}"], np.float64)
            curve, final = rmse_summary(err)
            paper, note = paper_fn(s, w)
            rows.append(
                {
                    "setting": setting,
                    "method": w,
                    "time_s": [round(t * s.step_period, 6) for t in range(err.shape[1])],
                    "rmse_m": curve,
                    "final_rmse_m": {**final, "paper": paper, "paper_note": note},
                }
            )
        k = np.asarray(vals["gamma_k"], np.float64)
        finals = {w: np.sqrt(_final_mse(np.square(np.asarray(vals[f"err_{w}"], np.float64)))) for w in methods}
        diagnostics.append(
            {
                "setting": setting,
                "final_median_m": {w: float(np.median(f)) for w, f in finals.items()},
                "final_lost_runs": {w: int(np.sum(f > FAILED_M)) for w, f in finals.items()},
                "gamma_k_median": float(np.median(k)),
                "gamma_theta_median": float(np.median(vals["gamma_theta"])),
                "gamma_default_fraction": float(np.mean(vals["gamma_default"])),
                "tag_reads_mean": float(np.mean(vals["tag_reads"])),
                "anchor_reads_mean": float(np.mean(vals["anchor_reads"])),
            }
        )
    return {"rows": rows, "diagnostics": diagnostics}


def _experiment(
    name: str,
    title: str,
    settings: Sequence[UHFSetting],
    methods: Sequence[str],
    paper_fn,
    plot,
    notes: str,
    quick_weightings: Sequence[str] | None = None,
    quick_settings: Sequence[int] | None = None,
) -> Experiment:
    """Build and register an experiment: one cell per setting, one row per (setting, method).

    ``quick_weightings``: the weightings the quick variant's cells compute (a superset of
    ``methods``, to share another experiment's function); ``quick_settings``: the indices of
    the settings the quick variant runs (default all).
    """
    methods = tuple(methods)
    settings = tuple(settings)

    def cells(quick: bool) -> list[Cell]:
        out = []
        chosen = settings if not quick or quick_settings is None else [settings[i] for i in quick_settings]
        for s in chosen:
            s = replace(s, **QUICK) if quick else s
            weightings = tuple(quick_weightings) if quick and quick_weightings else methods
            fn = run_once(weightings, s.dims, s.num_particles, s.refresh)
            # [A]'s Gaussian cells keep the ids of fig-5.5/5.6 (so the same seeded runs): common random numbers
            cid = f"{s.multipath}|{s.dims}d|anchor={s.anchor_distance:.6g}" + (
                "" if s.refresh == "gaussian" else f"|refresh={s.refresh}"
            )
            out.append(Cell(cid, cid, "+".join(methods), s, fn, (run_inputs(s),)))
        return out

    def summarize(raw: dict, cell_list: list[Cell], quick: bool) -> dict:
        out = _summarize_cells(raw, cell_list, methods, paper_fn)
        step = cell_list[0].setting.step_period
        return {
            **out,
            "prior_rmse_m": {"2": prior_rmse(2), "3": prior_rmse(3)},
            "step_period_s": step,
            "final_fraction": FINAL_FRACTION,
            "wavelength_m": WAVELENGTH,
            "notes": notes,
        }

    return register(Experiment(name, title, cells, summarize, render_table, markdown_table, plot, notes))


_COMMON_NOTES = (
    "Ours, not [A]'s: the tag is drawn uniformly 0.3 m inside the 2 x 3 x 2 m box, its phase offset uniformly; "
    "the reader (boresight +y) drives a lawnmower of passes along x at y = -0.5, -0.2 m and z = 0.5, 1.5 m, one read "
    "per step, 0.2 m/s; multipath presets of jaxnav.sim.uhf_reader; (k, theta) fitted in closed form from all the "
    "anchor's reads; Alg. 6 with sigma_phase = 0.1 lambda, ESS threshold 0.1, Gaussian refresh. The three weightings "
    "run on the same draws. RMSE interval: Student-t interval of the mean squared error over runs, square-rooted. "
    "Final = last 10 % of the steps. The RMSE is ruled by the runs where the filter locks onto a wrong mode of its "
    "first reads (a tag in the antenna's side lobe reads like one ~3x farther in its main lobe) and never recovers: "
    "see the median and lost-run columns."
)

_experiment(
    "fig-5.3",
    "RSSI-only tag localization against the anchor-to-tag distance, strong multipath, 3D ([A] Fig. 5.3)",
    [UHFSetting(multipath="strong", dims=3, anchor_distance=d * WAVELENGTH) for d in ANCHOR_LAMBDAS],
    ("rssi",),
    lambda s, w: (None, FIG_5_3_NOTE),
    plot_anchor,
    "Anchor at 0.25, 0.5, 1, 2, 4 lambda (lambda = 0.173 m, [A] §5.2) in a random direction from the tag, inside the "
    "box. " + _COMMON_NOTES,
    quick_weightings=METHODS,
    quick_settings=(1, 4),
)

_experiment(
    "fig-5.5",
    "Tag localization in 3D (2 x 3 x 2 m): RSSI, phase, combined, light and strong multipath ([A] Fig. 5.5)",
    [UHFSetting(multipath=m, dims=3) for m in MULTIPATHS],
    METHODS,
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag. " + _COMMON_NOTES,
)

_experiment(
    "fig-5.6",
    "Tag localization in 2D (2 x 3 m, known height): RSSI, phase, combined, light and strong multipath ([A] Fig. 5.6)",
    [UHFSetting(multipath=m, dims=2) for m in MULTIPATHS],
    METHODS,
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag; the filter knows the tag's height, the error is over x, y. "
    + _COMMON_NOTES,
)

_experiment(
    "uhf-refresh",
    "Ours, not [A]'s: Alg. 6 combined in 3D with [A]'s Gaussian refresh against a kernel (regularised) "
    "refresh, light and strong multipath",
    [UHFSetting(multipath=m, dims=3, refresh=r) for m in MULTIPATHS for r in REFRESHES],
    ("combined",),
    lambda s, w: PAPER[(s.multipath, s.dims, w)],
    plot_curves,
    f"Anchor {CLOSE_ANCHOR} m from the tag. The Gaussian cells are fig-5.5's combined curves (same cell ids, same "
    "seeded runs). The kernel refresh moves every resampled particle by h L eps (L L^T the set's covariance, h = "
    "Silverman's bandwidth, 0.37 for 2000 particles in 4 dimensions: jaxnav.core.resampling.kernel_refresh) instead "
    "of redrawing the whole set from one Gaussian, so the early multimodal posterior keeps its modes. " + _COMMON_NOTES,
)
