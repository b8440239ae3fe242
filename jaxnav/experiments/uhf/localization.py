"""[A] §5.2: UHF-RFID tag localization from RSSI and phase ([A] Alg. 6), one simulated run and its summaries.

The settings, runs and RMSE summaries of [A] §5.2's experiments; the
experiments themselves (Figs. 5.3, 5.5, 5.6 and ``uhf-refresh``) are in
:mod:`jaxnav.experiments.uhf.figures`.

.. rubric:: One run (:func:`run_once`; all choices ours, [A] gives no geometry)

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
  (:func:`jaxnav.sim.trajectories.lawnmower_path`) of passes along x over the
  box's full width, 0.5 and 0.2 m in front of its ``y = 0`` face, at heights
  0.5 and 1.5 m (two depths × two heights: the 3D-observable pattern of
  :mod:`jaxnav.sim.trajectories`, "Paths of a UHF reader"). One read slot per step; the reader
  moves at :data:`SPEED` = 0.2 m/s along the passes (connector moves are
  sampled no coarser), so step ``t`` is at ``time_s = t · Δt`` with
  ``Δt = pass spacing / speed`` (0.2 s in the full variant: 242 steps, 48.2 s).
* Reads of the tag and of the anchor: :func:`jaxnav.sim.uhf_reader.simulate_reads`
  with the ``"light"`` or ``"strong"`` preset, its fading drawn independently for
  the two tags or, with a setting's ``correlation_length``, from the spatially
  correlated field of :mod:`jaxnav.sim.uhf_reader` (the anchor and the tag fade
  together when closer than ``ℓ``). ``(k, θ)`` is fitted from all
  the anchor's reads with :func:`jaxnav.models.uhf_calibration.estimate_gamma`
  (closed form, [A] App. D–E; the defaults below 30 valid reads) using the
  anchor's known ``a`` (:func:`jaxnav.models.uhf_channel.power_scale`).
* [A] Alg. 6 (:mod:`jaxnav.localization.rfid_tag`, 2,000 particles in the
  full variant, ``σ_phase = 0.1 λ`` in both environments, ESS threshold 0.1,
  Gaussian refresh) runs on the tag's reads; in 2D ``tag_height`` is the
  tag's true height. The three weightings of a setting run on the **same**
  draws (tag, anchor, reads, filter keys): common random numbers, so their
  differences are not sampling noise between different scenes.
* The per-run result is the position error ``‖p̂_t − p‖`` over time (m; in
  2D over x, y only: the height is known, its error is 0).

.. rubric:: Summaries (:func:`rmse_summary`)

``RMSE(t) = √(mean over runs of err_r(t)²)``. Its 95 % interval is the
Student-t interval of the mean squared error over the runs
(:func:`jaxnav.experiments.stats.mean_ci`'s ``mean ± t_{0.975, R−1}·s/√R``, on
``err²``) mapped through the square root, its lower end clipped at 0 (a
monotone map keeps the interval's coverage). ``final_rmse_m`` is the same over
the last :data:`FINAL_FRACTION` = 10 % of the steps: each run's mean squared
error over those steps, then the root of their mean. Every run given counts
(a non-finite error makes the RMSE NaN): the experiments leave the runs that
diverged out first and count them (:mod:`jaxnav.experiments.uhf.figures`).
The uniform prior's RMSE (the box centre as estimate, :func:`prior_rmse`) is
the reference a method must beat: 0.90 m in 3D, 0.80 m in 2D.

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
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.resampling import REFRESHES
from jaxnav.core.validation import check_choice, check_nonnegative, check_positive, check_positive_int
from jaxnav.experiments import stats
from jaxnav.localization import rfid_tag as rt
from jaxnav.models import uhf_calibration
from jaxnav.models import uhf_rfid as U
from jaxnav.sim import trajectories
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
    "MULTIPATHS",
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
    "final_mse",
    "position_error",
]

WAVELENGTH = U.A_WAVELENGTH
"""λ = 0.173 m, as [A] §5.2 states (probably λ/2 of an 866 MHz reader; we use [A]'s number)."""
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
        correlation_length: ``None`` (the preset's fading, independent for every tag) or
            ``ℓ`` (m) of the spatially correlated fading
            (:func:`jaxnav.sim.uhf_reader.correlated_fading`; ``fig-5.3-correlated``).
        prior_margin: the filter's search box (its uniform prior, and the box its refresh is clipped
            to) is the room's box grown by this much (m) on every side, its floor kept at ``z = 0``;
            0 is [A]'s (``uhf-prior``). The tag and the anchor are drawn in the room's box either way.
    """

    multipath: str = "light"
    dims: int = 3
    anchor_distance: float = CLOSE_ANCHOR
    num_particles: int = 2000
    steps_per_pass: int = 51
    speed: float = SPEED
    margin: float = MARGIN
    refresh: str = "gaussian"
    correlation_length: float | None = None
    prior_margin: float = 0.0

    def __post_init__(self) -> None:
        check_choice("multipath", self.multipath, MULTIPATHS)
        check_choice("refresh", self.refresh, REFRESHES)
        if self.correlation_length is not None:
            check_positive("correlation_length", self.correlation_length)
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {self.dims!r}")
        check_nonnegative("anchor_distance", self.anchor_distance)
        check_positive_int("num_particles", self.num_particles)
        if check_positive_int("steps_per_pass", self.steps_per_pass) < 2:
            raise ValueError(f"steps_per_pass must be ≥ 2, got {self.steps_per_pass}")
        check_positive("speed", self.speed)
        check_nonnegative("margin", self.margin)
        check_nonnegative("prior_margin", self.prior_margin)
        lo, hi = S.SEARCH_BOX_A
        if not np.all(hi - lo > 2 * self.margin):
            raise ValueError(
                f"margin {self.margin} m leaves no room for the tag in the search box {lo.tolist()}–{hi.tolist()}"
            )

    @property
    def fading_fields(self) -> int | None:
        """The number of Gaussian fields of the correlated fading, ``⌈k⌉`` of the preset (None without it):
        a shape, given to :func:`run_once` because ``k`` is traced in a run."""
        if self.correlation_length is None:
            return None
        return math.ceil(float(S.get_multipath(self.multipath).gamma.k))

    @property
    def step_period(self) -> float:
        """Seconds per step, the pass spacing over the speed."""
        lo, hi = S.SEARCH_BOX_A
        return float(hi[0] - lo[0]) / (self.steps_per_pass - 1) / self.speed


QUICK = dict(num_particles=300, steps_per_pass=21)
"""What the quick variants change (300 particles and a pass spacing of 0.1 m, 97 steps of 0.5 s)."""


class UHFInputs(NamedTuple):
    """The arrays of one setting, given whole to every run of a cell (cells of equal shapes share a compilation).

    Attributes:
        path: ``[T, 4]`` reader poses (m, m, m, rad).
        multipath: the :class:`~jaxnav.sim.uhf_reader.Multipath` preset (float32 arrays).
        anchor_distance: m.
        margin: m.
        filter: :class:`~jaxnav.localization.rfid_tag.RFIDTagParams` (search box, channel,
            ``σ_phase``; ``gamma`` and ``tag_height`` are replaced in each run).
        room_lo, room_hi: ``[3]`` corners of the room's box (m), where the tag and the anchor are drawn
            (the filter's search box unless ``UHFSetting.prior_margin`` widens it).
    """

    path: jax.Array
    multipath: S.Multipath
    anchor_distance: jax.Array
    margin: jax.Array
    filter: rt.RFIDTagParams
    room_lo: jax.Array
    room_hi: jax.Array


def _path(s: UHFSetting) -> np.ndarray:
    lo, hi = S.SEARCH_BOX_A
    return trajectories.lawnmower_path((float(lo[0]), float(hi[0])), PASS_DEPTHS, PASS_HEIGHTS, s.steps_per_pass)


def run_inputs(s: UHFSetting) -> UHFInputs:
    """The arrays of setting ``s`` (host-side, validated)."""
    lo, hi = S.SEARCH_BOX_A
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    mp = S.get_multipath(s.multipath)
    if s.correlation_length is not None:
        mp = S.correlated_fading(mp, s.correlation_length)
    grow = np.full(3, s.prior_margin)
    prior_lo = np.maximum(np.asarray(lo) - grow, [-np.inf, -np.inf, 0.0])  # the floor stays the floor
    return UHFInputs(
        path=f32(_path(s)),
        multipath=jax.tree_util.tree_map(f32, mp),
        anchor_distance=f32(s.anchor_distance),
        margin=f32(s.margin),
        filter=rt.default_params(box_lo=prior_lo, box_hi=np.asarray(hi) + grow),
        room_lo=f32(lo),
        room_hi=f32(hi),
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
    u = rng.normal(key, (tries, 3), jnp.float32)
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
    box_lo, box_hi = inputs.room_lo, inputs.room_hi
    lo, hi = box_lo + inputs.margin, box_hi - inputs.margin
    tag = lo + rng.uniform(k_tag, (3,)) * (hi - lo)
    offset = rng.uniform(k_off, (), minval=-math.pi, maxval=math.pi)
    return Scene(tag, offset, anchor_position(k_anc, tag, inputs.anchor_distance, box_lo, box_hi))


def _simulate_and_filter(key, inputs: UHFInputs, configs: Sequence[rt.RFIDTagConfig], fading_fields=None):
    """``(scene, fit, reads of the tag, [trace per config])`` of one run (keys: :func:`_keys`)."""
    _, _, _, k_sim, k_init, k_run = _keys(key)
    scene = draw_scene(key, inputs)
    reads = S.simulate_reads(
        k_sim,
        inputs.path,
        jnp.stack([scene.tag, scene.anchor]),
        jnp.stack([scene.offset, jnp.zeros_like(scene.offset)]),
        multipath=inputs.multipath,
        fading_fields=fading_fields,
    )
    tag_reads = jax.tree_util.tree_map(lambda x: x[0], reads)
    anchor_reads = jax.tree_util.tree_map(lambda x: x[1], reads)
    a = S.anchor_power_scale(anchor_reads, scene.anchor)
    fit = uhf_calibration.estimate_gamma(anchor_reads.rssi.ravel(), a.ravel(), anchor_reads.mask.ravel())
    params = inputs.filter._replace(gamma=fit.params, tag_height=scene.tag[2])
    traces = []
    for cfg in configs:
        state0 = rt.init(k_init, cfg, params)
        traces.append(rt.run(k_run, state0, cfg, params, tag_reads)[1])
    return scene, fit, tag_reads, traces


def position_error(estimate: jax.Array, tag: jax.Array, dims: int) -> jax.Array:
    """Euclidean error (m) of ``estimate [..., ≥dims]`` against the true ``tag`` over the first ``dims`` coordinates (2: x, y)."""
    d = estimate[..., :dims] - tag[:dims]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


@functools.cache
def run_once(
    weightings: tuple[str, ...],
    dims: int,
    num_particles: int,
    refresh: str = "gaussian",
    fading_fields: int | None = None,
) -> Callable[..., dict]:
    """``(key, inputs: UHFInputs) -> {field: array}`` of one seeded run (cached: one function per arguments).

    ``fading_fields``: :attr:`UHFSetting.fading_fields` of settings with correlated fading (None otherwise).

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
        scene, fit, tag_reads, traces = _simulate_and_filter(key, inputs, configs, fading_fields)
        out = {f"err_{w}": position_error(tr.estimate, scene.tag, dims) for w, tr in zip(weightings, traces)}
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


def rmse_summary(err: np.ndarray, final_fraction: float = FINAL_FRACTION) -> tuple[dict, dict]:
    """RMSE over time and over the last steps, with 95 % intervals (module docstring, "Summaries").

    Args:
        err: ``[R, T]`` per-run errors (m); every run counts (``R = 0`` gives NaN).
        final_fraction: share of the last steps for the final RMSE.

    Returns:
        ``({"mean": [T], "ci95": [[lo, hi]] * T}, {"mean", "ci95": [lo, hi]})``.
    """
    e2 = np.square(np.asarray(err, np.float64))
    if e2.ndim != 2:
        raise ValueError(f"err must have shape [R, T], got {e2.shape}")
    m, lo, hi = stats.mean_ci_columns(e2)
    curve = {
        "mean": np.sqrt(m).tolist(),
        "ci95": np.stack([np.sqrt(np.maximum(lo, 0.0)), np.sqrt(hi)], axis=1).tolist(),
    }
    fm, flo, fhi = stats.mean_ci_columns(final_mse(e2, final_fraction)[:, None])
    final = {"mean": float(np.sqrt(fm[0])), "ci95": [float(np.sqrt(max(flo[0], 0.0))), float(np.sqrt(fhi[0]))]}
    return curve, final


def final_mse(e2: np.ndarray, final_fraction: float = FINAL_FRACTION) -> np.ndarray:
    """``[R]`` each run's mean squared error over the last ``final_fraction`` of the steps of ``e2 [R, T]``."""
    n_final = max(1, int(math.ceil(final_fraction * e2.shape[1] - 1e-9)))
    return e2[:, -n_final:].mean(axis=1)


FAILED_M = 0.5
"""A run whose final error (RMS over the last 10 % of steps) exceeds 0.5 m is counted as lost in the tables."""
