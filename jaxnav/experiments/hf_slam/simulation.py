"""One HF-RFID SLAM method on one simulated setting: simulate, filter, score, draw ([W] ch. 3–4).

**Overview**

A :class:`HFSetting` fixes everything of one cell of [W]'s tables: tag
density, reader footprint, trajectory, particle counts and the noise levels
(ours where [W] gives none; listed below). :func:`run_once` is a pure
function of ``(key, method, setting)``: it lays a jittered carpet, simulates
the trajectory (:mod:`jaxnav.sim.tag_carpet`), runs PF-SLAM, PS-SLAM or
FastSLAM on the odometry and detections, and scores the result like [W]; it
jits and ``vmap``-s over keys, so many seeded runs are one call.

Errors (:class:`Errors`, millimetres and radians as [W] prints them):

* robot ``x``, ``y``: mean absolute error of the estimated position per axis
  over all steps; ``theta``: mean absolute heading error; ``dr``: mean
  distance between estimated and true position;
* tag ``tx``, ``ty``, ``dt``: the same over the tags the method mapped, at
  the end of the run: ``tx = (1/n) Σ_mapped |t̂x − tx|`` and so on over the
  ``n`` mapped tags. A run that mapped no tag (``n = 0``) has nothing to
  score: its tag errors are NaN, not 0 (:mod:`jaxnav.experiments.stats`
  counts such runs and leaves them out of the means).

[W] does not define its columns; in Tables 4.1–4.2 ``dr`` exceeds
``√(x² + y²)``, which holds for mean absolute errors and a mean distance
(the norm of means is at most the mean of norms), so we use those. All runs
start from the known true pose ([W] Alg. 1).

Noise levels and sizes ([W] gives none, these are ours): odometry velocity
noise σ = (20 mm/s, 20 mm/s, 0.01 rad/s) on 0.1 s steps ([W] eq. 3.6, world
frame; a random walk of about 0.5 % of the distance driven over one 7 m lap),
installation jitter ±10 mm, β = 0.1 in [W] eq. 3.7, PS-SLAM tag jitter
σ/10 with lag 20; a 3 m × 2.5 m carpet with the rectangle 2 m × 1.5 m driven
at 200 mm/s, the random trajectory at 100–400 mm/s inside the carpet.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core.filter import check_key
from jaxnav.core.validation import check_choice, check_positive_int
from jaxnav.core.weights import wrap_angle
from jaxnav.experiments import report
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise
from jaxnav.sim import tag_carpet as tc
from jaxnav.sim import trajectories
from jaxnav.slam import fastslam, pf_slam, ps_slam

__all__ = [
    "METHODS",
    "METHOD_LABELS",
    "TRAJECTORIES",
    "SMOOTHER_READINGS",
    "FASTSLAM_GAUSSIANS",
    "HFSetting",
    "World",
    "MethodRun",
    "Errors",
    "ERROR_COLUMNS",
    "COLUMN_HEADS",
    "TAG_COLUMNS",
    "NOTHING_MAPPED",
    "make_world",
    "reachable_tags",
    "num_steps",
    "memory_estimate",
    "run_method",
    "fastslam_parallel_slots",
    "filter_world",
    "score",
    "run_once",
    "run_once_compiled",
    "error_cell",
    "dead_reckoning",
    "MapShift",
    "map_shift",
    "fastslam_sensor",
    "detection_counts",
    "format_errors",
    "plot_run",
]

METHODS = ("pf_slam", "ps_slam", "fastslam")
"""The SLAM methods :func:`run_method` runs (PF-SLAM, PS-SLAM, FastSLAM)."""
METHOD_LABELS = {"pf_slam": "PF-SLAM", "ps_slam": "PS-SLAM", "fastslam": "FastSLAM"}
"""The names of :data:`METHODS` in the tables, the figures and :func:`plot_run`."""
TRAJECTORIES = ("rectangle", "random", "kidnapping")

FASTSLAM_GAUSSIANS = {
    "footprint": lambda side: side / math.sqrt(12.0),
    "half_side": lambda side: side / 2.0,
    "small_reader": lambda side: 0.06 / math.sqrt(12.0),
}
"""The readings of ``HFSetting.fastslam_gaussian``: each maps the reader's side ``s`` (m) to the σ (m,
per axis) of FastSLAM's Gaussian detection."""
"""The trajectories a :class:`HFSetting` can drive."""
SMOOTHER_READINGS = ("robot_target", "resampled_state", "history", "smoothing_order", "tag_init")
"""The fields of :class:`~jaxnav.slam.ps_slam.PSSLAMConfig` a :class:`HFSetting` may set (``smoother_readings``)."""


@dataclass(frozen=True)
class HFSetting:
    """A simulated HF-RFID SLAM setting (hashable: a static argument of jitted functions).

    Attributes:
        density: tags/m² (100, 16, 4 in [W]); its pitch ``1/√density`` must exceed twice the
            installation jitter (neighbours could swap places) and fit on the carpet.
        reader_side: footprint side (m): 0.06 ([W] ch. 3), 0.1–0.5 ([W] §4.4.3); at most the
            carpet's shorter side.
        trajectory: "rectangle" (driven ``laps`` times), "random" or "kidnapping" ([W] §3.4.3).
        carpet: ``(w, h)`` of the carpet (m), from the origin.
        rectangle: ``(x0, y0, width, height)`` of the rectangle (m).
        laps: laps of the rectangle.
        random_steps: steps of the random trajectory.
        speed: rectangle speed (m/s); speed_range: random-trajectory speeds (m/s).
        dt: step (s).
        installation_jitter: tag installation error bound (m).
        odometry_sd: σ of [W] eq. 3.6 (m/s, m/s, rad/s).
        robot_particles, tag_particles: I and J (FastSLAM uses I).
        lag: PS-SLAM lag L; smoother_jitter: PS-SLAM tag jitter (m), None = σ/10.
        smoother_readings: ``((field, value), …)``: PS-SLAM's readings of [W] Alg. 2 other than the
            defaults, fields of :class:`~jaxnav.slam.ps_slam.PSSLAMConfig` (``robot_target``,
            ``resampled_state``, ``history``, ``smoothing_order``, ``tag_init``); ``()`` runs the defaults.
        beta: β of [W] eq. 3.7.
        fastslam_version: 1 or 2.
        fastslam_gaussian: the Gaussian FastSLAM's EKFs take for a detection, a point measurement at the
            detecting reader's centre ([W] §3.2 gives no σ): ``"footprint"`` (default), the footprint's
            own variance ``s²/12`` per axis (σ = s/√12, the uniform square's); ``"half_side"``, σ = s/2;
            ``"small_reader"``, the 60 mm reader's σ = 0.06/√12 m whatever the reader's side (the
            model of [W] ch. 3 kept for the large readers of ch. 4). See :data:`FASTSLAM_GAUSSIANS`.
        map_known: PF-SLAM starts with every tag surveyed at its true position
            (:func:`jaxnav.slam.pf_slam.surveyed_tags`): localization on the known carpet through the
            same eq. 3.7, the floor that the readers' resolution and the odometry set. PF-SLAM only.
    """

    density: float = 16.0
    reader_side: float = 0.06
    trajectory: str = "rectangle"
    carpet: tuple[float, float] = (3.0, 2.5)
    rectangle: tuple[float, float, float, float] = (0.5, 0.5, 2.0, 1.5)
    laps: int = 3
    random_steps: int = 2000
    speed: float = 0.2
    speed_range: tuple[float, float] = (0.1, 0.4)
    dt: float = 0.1
    installation_jitter: float = 0.01
    odometry_sd: tuple[float, float, float] = (0.02, 0.02, 0.01)
    robot_particles: int = 500
    tag_particles: int = 100
    lag: int = 20
    smoother_jitter: float | None = None
    smoother_readings: tuple[tuple[str, str], ...] = ()
    beta: float = hf_rfid.DEFAULT_BETA
    fastslam_version: int = 1
    fastslam_gaussian: str = "footprint"
    map_known: bool = False

    def __post_init__(self) -> None:
        check_choice("trajectory", self.trajectory, TRAJECTORIES)
        for name in ("density", "reader_side", "speed", "dt"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a number > 0, got {value!r}")
        for name in ("laps", "random_steps", "robot_particles", "tag_particles", "lag"):
            check_positive_int(name, getattr(self, name))
        self._check_carpet()
        check_choice("fastslam_version", self.fastslam_version, (1, 2))
        check_choice("fastslam_gaussian", self.fastslam_gaussian, tuple(FASTSLAM_GAUSSIANS))
        if not isinstance(self.map_known, bool):
            raise ValueError(f"map_known must be True or False, got {self.map_known!r}")
        if len(self.odometry_sd) != 3 or any(not (s >= 0) for s in self.odometry_sd):
            raise ValueError(f"odometry_sd must be three numbers ≥ 0, got {self.odometry_sd!r}")
        x0, y0, w, h = self.rectangle
        inside = w > 0 and h > 0 and x0 >= 0 and y0 >= 0 and x0 + w <= self.carpet[0] and y0 + h <= self.carpet[1]
        if self.trajectory != "random" and not inside:
            raise ValueError(f"rectangle {self.rectangle!r} must lie inside the carpet (0, 0)–{self.carpet!r}")
        if self.smoother_jitter is not None and not self.smoother_jitter >= 0:
            raise ValueError(f"smoother_jitter must be ≥ 0 m or None, got {self.smoother_jitter!r}")
        for pair in self.smoother_readings:
            if not (isinstance(pair, tuple) and len(pair) == 2 and pair[0] in SMOOTHER_READINGS):
                raise ValueError(
                    f"smoother_readings must be (field, value) pairs with a field in {SMOOTHER_READINGS}, got {pair!r}"
                )
        ps_slam.PSSLAMConfig(max_tags=1, **dict(self.smoother_readings))  # refuses a value it does not know

    def _check_carpet(self) -> None:
        """The carpet, its density and the readers must make a lattice the readers can drive over."""
        if len(self.carpet) != 2 or not all(
            isinstance(c, (int, float)) and math.isfinite(c) and c > 0 for c in self.carpet
        ):
            raise ValueError(f"carpet must be (width, height), two numbers > 0 m, got {self.carpet!r}")
        j = self.installation_jitter
        if not (isinstance(j, (int, float)) and math.isfinite(j) and j >= 0):
            raise ValueError(f"installation_jitter must be a number ≥ 0 m, got {j!r}")
        side = min(self.carpet)
        pitch = tc.density_to_pitch(self.density)
        if j > 0 and pitch <= 2.0 * j:  # neighbours could swap places: the lattice order is lost
            raise ValueError(
                f"density {self.density:g} tags/m² gives a pitch of {1000 * pitch:.3g} mm, not more than twice the "
                f"installation jitter ({1000 * j:g} mm): the density must be below {1 / (2 * j) ** 2:g} tags/m²"
            )
        if pitch > side:
            raise ValueError(
                f"density {self.density:g} tags/m² gives a pitch of {pitch:.3g} m, more than the carpet's shorter side "
                f"({side:g} m): the density must be at least {1 / side**2:.3g} tags/m² to lay a lattice of tags"
            )
        if self.reader_side > side:
            raise ValueError(
                f"reader_side {self.reader_side:g} m is larger than the carpet's shorter side ({side:g} m): "
                f"a reader footprint must fit on the carpet ([W] uses 0.06 to 0.5 m)"
            )

    @property
    def pitch(self) -> float:
        return tc.density_to_pitch(self.density)

    @property
    def layout(self) -> tc.CarpetLayout:
        """The carpet's lattice (the tag count fixes the filters' ``max_tags``)."""
        p = self.pitch
        nx = int(math.floor(self.carpet[0] / p + 1e-9)) + 1
        ny = int(math.floor(self.carpet[1] / p + 1e-9)) + 1
        return tc.CarpetLayout(p, nx, ny, (0.0, 0.0), self.installation_jitter)

    def sensor(self) -> hf_rfid.HFReaderParams:
        return hf_rfid.reader_params(self.reader_side, beta=self.beta)

    def motion(self) -> OmniNoise:
        return OmniNoise(jnp.asarray(self.odometry_sd, jnp.float32))


class World(NamedTuple):
    """A simulated world: the carpet and the run over it."""

    carpet: tc.TagCarpet
    run: tc.HFRun


class MethodRun(NamedTuple):
    """A filter's output on a :class:`World`.

    Attributes:
        estimates: ``[T, 3]`` robot estimate per step.
        tags: ``[num_tags, 2]`` estimated tag positions (m), row = tag ID.
        seen: ``[num_tags]`` bool, the method mapped the tag.
        lost: ``[T]`` bool, kidnapping recovery fired (always False for FastSLAM).
    """

    estimates: jax.Array
    tags: jax.Array
    seen: jax.Array
    lost: jax.Array


class Errors(NamedTuple):
    """[W]'s error columns (mm, rad); see the module docstring. The tag columns are NaN when no tag was mapped."""

    x_mm: jax.Array
    y_mm: jax.Array
    theta_rad: jax.Array
    dr_mm: jax.Array
    tx_mm: jax.Array
    ty_mm: jax.Array
    dt_mm: jax.Array


ERROR_COLUMNS = Errors._fields
"""The field names of [W]'s table columns — robot x, y, θ, distance; tag x, y, distance (mm, rad)."""
COLUMN_HEADS = ("x [mm]", "y [mm]", "θ [rad]", "dr [mm]", "tx [mm]", "ty [mm]", "dt [mm]")
"""The printed heads of :data:`~jaxnav.experiments.hf_slam.simulation.ERROR_COLUMNS`."""
TAG_COLUMNS = ("tx_mm", "ty_mm", "dt_mm")
"""The columns scored over the mapped tags (NaN when the run mapped none)."""
NOTHING_MAPPED = f"{report.NA} (nothing mapped)"
"""How a tag error is written when no tag was mapped."""


def _controls(key: jax.Array, s: HFSetting) -> tuple[jax.Array, jax.Array]:
    x0, y0, w, h = s.rectangle
    if s.trajectory == "rectangle":
        return trajectories.rectangle_controls(w, h, s.speed, s.dt, s.laps, (x0, y0))
    margin = 0.15  # keep the reader array over the carpet
    return trajectories.random_controls(
        key, (margin, margin, s.carpet[0] - margin, s.carpet[1] - margin), s.random_steps, s.speed_range, s.dt
    )


def make_world(key: jax.Array, setting: HFSetting) -> World:
    """Lay a jittered carpet and simulate ``setting.trajectory`` over it (traceable: ``vmap`` over keys)."""
    k_carpet, k_path, k_odo = jax.random.split(key, 3)
    carpet = tc.make_carpet(k_carpet, setting.carpet, pitch=setting.pitch, jitter=setting.installation_jitter)
    sensor = setting.sensor()
    if setting.trajectory == "kidnapping":
        x0, y0, w, h = setting.rectangle
        run = tc.kidnapping_scenario(
            k_odo,
            carpet,
            sensor,
            setting.motion(),
            w,
            h,
            (x0, y0),
            setting.speed,
            setting.dt,
            laps_after=setting.laps,
            footprint_side=setting.reader_side,
        )
    else:
        start, controls = _controls(k_path, setting)
        run = tc.simulate(k_odo, carpet, sensor, start, controls, setting.motion(), footprint_side=setting.reader_side)
    return World(carpet, run)


def reachable_tags(setting: HFSetting) -> np.ndarray:
    """IDs of the tags a reader can reach from the setting's path (host, static), sorted.

    For the rectangle (and the kidnapping, which stays on it) the truth follows the
    rectangle exactly, so a tag can only be detected if its nominal position lies within
    ``reach = max_b |offset_b| + side/√2 + jitter`` of the path. FastSLAM's per-particle map
    only needs those tags: a real FastSLAM allocates landmarks as they are first seen, so
    sizing its map to the tags the run can detect (instead of the whole carpet) is what its
    memory and copy cost would be. A random trajectory can reach every tag.
    """
    layout = setting.layout
    ids = np.arange(layout.num_tags)
    if setting.trajectory == "random":
        return ids
    with jax.ensure_compile_time_eval():  # host numbers, also when called under jit/vmap
        offsets = np.asarray(hf_rfid.default_reader_offsets(), np.float64)
        nominal = tc.TagCarpet(layout, jnp.zeros((layout.num_tags, 2), jnp.float32))
        pos = np.asarray(tc.tag_positions(nominal), np.float64)  # the lattice without installation jitter
    reach = np.max(np.linalg.norm(offsets, axis=1)) + setting.reader_side / math.sqrt(2.0) + layout.max_jitter + 1e-6
    x0, y0, w, h = setting.rectangle
    corners = np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h], [x0, y0]])
    dist = np.full(len(ids), np.inf)
    for a, b in zip(corners[:-1], corners[1:]):
        t = np.clip(((pos - a) @ (b - a)) / np.dot(b - a, b - a), 0.0, 1.0)
        dist = np.minimum(dist, np.linalg.norm(pos - (a + t[:, None] * (b - a)), axis=1))
    return ids[dist <= reach]


def num_steps(setting: HFSetting) -> int:
    """The number of filter steps of the setting's trajectory, from its sizes alone (no arrays built).

    Exact for the rectangle and the random trajectory (:mod:`jaxnav.sim.trajectories`); for the
    kidnapping, an upper bound (a lap up to the kidnapping, one on to the end of its lap, then ``laps`` laps).
    """
    if setting.trajectory == "random":
        return setting.random_steps
    _, _, w, h = setting.rectangle
    edges = 2 * sum(max(1, round(length / (setting.speed * setting.dt))) for length in (w, h))
    turns = 4 * max(1, round((math.pi / 2) / (math.pi / 4) / setting.dt))
    laps = setting.laps + (2 if setting.trajectory == "kidnapping" else 0)
    return laps * (edges + turns)


def memory_estimate(method: str, setting: HFSetting) -> int:
    """Bytes one run of ``method`` on ``setting`` holds at once, estimated from the sizes alone.

    The recorded run (``T`` steps of ``K`` detection slots, :func:`jaxnav.sim.tag_carpet.detection_capacity`),
    the tag table (PF-SLAM and PS-SLAM: ``num_tags × J`` particles, times the lag for PS-SLAM) or
    FastSLAM's per-particle maps, and the arrays of one step (``K × K`` slot groups, ``I × K``
    robot weights, ``K × J`` tag updates), at 4 bytes a number, doubled for XLA's temporaries.
    A rough figure (within a few times), to refuse sizes that cannot fit.
    """
    check_choice("method", method, METHODS)
    layout = setting.layout
    k = tc.detection_capacity(layout, setting.reader_side, hf_rfid.default_reader_offsets())
    t, n = num_steps(setting), layout.num_tags
    i, j = setting.robot_particles, setting.tag_particles
    run = t * (3 * k + 16)  # detections (ids, readers, mask), poses, odometry and the trace
    step = k * k + i * k + 8 * k * j + 8 * i
    if method == "fastslam":
        # per particle: each reachable tag's mean (2), covariance (4) and count, and the resampled copy
        table = 2 * i * len(reachable_tags(setting)) * 7
    else:
        table = n * j * 3 * (1 + (2 * setting.lag if method == "ps_slam" else 0))
    return 4 * 2 * (run + step + table)


def fastslam_parallel_slots(setting: HFSetting) -> int:
    """FastSLAM's ``parallel_slots`` for a setting: the expected number of tags under the readers
    in one step, ``readers · side² · density``, at least 1 (3 at 100 tags/m² with 60 mm readers,
    1 at 16 tags/m²). Only the speed depends on it (``FastSLAMConfig.parallel_slots``)."""
    readers = len(hf_rfid.default_reader_offsets())
    return max(1, round(readers * setting.reader_side**2 * setting.density))


def run_method(key: jax.Array, method: str, setting: HFSetting, world: World) -> MethodRun:
    """Run ``method`` (one of :data:`~jaxnav.experiments.hf_slam.simulation.METHODS`) on ``world``'s odometry and detections."""
    return filter_world(key, method, setting, world)[0]


def filter_world(
    key: jax.Array, method: str, setting: HFSetting, world: World, tag_jitter_sd: Any = None
) -> tuple[MethodRun, Any]:
    """:func:`run_method` and the filter's whole per-step trace (``SLAMInfo`` or ``FastSLAMInfo``).

    ``tag_jitter_sd``: PS-SLAM's tag jitter (m) as an array, which may be traced (a ``vmap`` over
    jitters); ``None`` takes ``setting.smoother_jitter``."""
    check_choice("method", method, METHODS)
    k_init, k_run = jax.random.split(key)
    run = world.run
    sensor = setting.sensor()
    num_tags = world.carpet.layout.num_tags
    start = run.start_pose
    if method == "fastslam":
        # The map holds the tags this path can reach (reachable_tags), in ID order.
        reach = reachable_tags(setting)
        num_map = len(reach)
        slot_of = np.full(num_tags + 1, num_map, np.int32)
        slot_of[reach] = np.arange(num_map, dtype=np.int32)
        config = fastslam.FastSLAMConfig(
            num_particles=setting.robot_particles,
            num_landmarks=num_map,
            version=setting.fastslam_version,
            motion_model="omni",
            observation_model="hf_footprint",
            map_copy="gather",  # run_once is vmapped over runs: see FastSLAMConfig.map_copy
            parallel_slots=fastslam_parallel_slots(setting),
        )
        params = fastslam.FastSLAMParams(setting.motion(), fastslam_sensor(setting))
        state = fastslam.init(k_init, config, params, start)
        obs = hf_rfid.landmark_observations(run.detections, sensor)
        ids = jnp.asarray(slot_of)[jnp.where(obs.mask, jnp.clip(obs.ids, 0, num_tags), num_tags)]
        final, trace = fastslam.run(k_run, state, config, params, run.odometry, obs._replace(ids=ids))
        map_tags, map_seen = fastslam.map_estimate(final)
        tags = jnp.zeros((num_tags, 2), map_tags.dtype).at[reach].set(map_tags)
        seen = jnp.zeros((num_tags,), bool).at[reach].set(map_seen)
        return MethodRun(trace.estimate, tags, seen, jnp.zeros(run.odometry.shape[0], bool)), trace
    if method == "pf_slam":
        module = pf_slam
        config = pf_slam.PFSLAMConfig(setting.robot_particles, setting.tag_particles, num_tags)
        params = pf_slam.PFSLAMParams(setting.motion(), sensor)
    else:
        module = ps_slam
        config = ps_slam.PSSLAMConfig(
            setting.robot_particles, setting.tag_particles, num_tags, lag=setting.lag, **dict(setting.smoother_readings)
        )
        jitter = (
            ps_slam.default_jitter(sensor)
            if setting.smoother_jitter is None
            else jnp.asarray(setting.smoother_jitter, jnp.float32)
        )
        if tag_jitter_sd is not None:
            jitter = jnp.asarray(tag_jitter_sd, jnp.float32)
        params = ps_slam.PSSLAMParams(setting.motion(), sensor, jitter)
    module.check_capacity(config, num_tags)
    state = module.init(k_init, config, params, start)
    if setting.map_known:
        if method != "pf_slam":
            raise ValueError(f"map_known is read by PF-SLAM only, not by method {method!r}")
        state = state._replace(tags=pf_slam.surveyed_tags(config, tc.tag_positions(world.carpet)))
    final, trace = module.run(k_run, state, config, params, run.odometry, run.detections)
    tags, seen = module.map_estimate(final)
    return MethodRun(trace.estimate, tags, seen, trace.lost), trace


def fastslam_sensor(setting: HFSetting) -> hf_rfid.HFReaderParams:
    """The reader parameters FastSLAM gets: the setting's, with the detection's Gaussian σ of
    ``setting.fastslam_gaussian``. FastSLAM's footprint model reads the footprint only through its
    covariance ``half_width²/3`` (:func:`jaxnav.models.hf_rfid.footprint_cov`), so σ is set as
    ``half_width = √3·σ``; the readers' offsets (the measurements) are the setting's."""
    sensor = setting.sensor()
    if setting.fastslam_gaussian == "footprint":
        return sensor
    sd = FASTSLAM_GAUSSIANS[setting.fastslam_gaussian](setting.reader_side)
    return sensor._replace(half_width=jnp.asarray(math.sqrt(3.0) * sd, sensor.half_width.dtype))


def detection_counts(run: tc.HFRun, num_tags: int) -> jax.Array:
    """``[num_tags]`` number of steps in which each tag was detected (by any reader)."""
    det = run.detections
    t = det.ids.shape[0]
    # one count per (step, tag), however many readers saw it
    per_step = (
        jnp.zeros((t, num_tags), bool)
        .at[jnp.arange(t)[:, None], jnp.where(det.mask, det.ids, num_tags)]
        .set(True, mode="drop")
    )
    return jnp.sum(per_step, axis=0)


def score(world: World, result: MethodRun) -> Errors:
    """[W]'s errors of one run (module docstring), in mm and rad; the tag errors are NaN when no tag was mapped."""
    truth = world.run.true_poses
    e = result.estimates[:, :2] - truth[:, :2]
    dtheta = jnp.abs(wrap_angle(result.estimates[:, 2] - truth[:, 2]))
    true_tags = tc.tag_positions(world.carpet)
    seen = result.seen
    count = jnp.sum(seen)
    n = jnp.maximum(count, 1)
    et = jnp.where(seen[:, None], result.tags - true_tags, 0.0)
    mm = 1000.0

    def over_mapped(total):  # mean over the mapped tags; NaN when none was mapped (nothing to score)
        return jnp.where(count > 0, mm * total / n, jnp.nan)

    return Errors(
        x_mm=mm * jnp.mean(jnp.abs(e[:, 0])),
        y_mm=mm * jnp.mean(jnp.abs(e[:, 1])),
        theta_rad=jnp.mean(dtheta),
        dr_mm=mm * jnp.mean(jnp.linalg.norm(e, axis=1)),
        tx_mm=over_mapped(jnp.sum(jnp.abs(et[:, 0]))),
        ty_mm=over_mapped(jnp.sum(jnp.abs(et[:, 1]))),
        dt_mm=over_mapped(jnp.sum(jnp.linalg.norm(et, axis=1))),
    )


def run_once(key: jax.Array, method: str, setting: HFSetting) -> tuple[Errors, World, MethodRun]:
    """Simulate, filter and score one seeded run: ``(errors, world, result)``. Pure; ``vmap`` over keys."""
    k_world, k_filter = jax.random.split(key)
    world = make_world(k_world, setting)
    result = run_method(k_filter, method, setting, world)
    return score(world, result), world, result


_run_once_program = jax.jit(run_once, static_argnums=(1, 2))


def run_once_compiled(key: jax.Array, method: str, setting: HFSetting) -> tuple[Errors, World, MethodRun]:
    """:func:`run_once` as one compiled program per ``(method, setting)``: what ``jaxnav hf-slam`` runs.

    Called op by op instead, :func:`run_once` dispatches (and the first time compiles) each of the
    simulation's many small operations on its own: the whole ``jaxnav hf-slam`` command with its
    default run takes 9.2 s against 11.8 s op by op (medians of four, 2 CPU cores).
    """
    check_key(key)
    return _run_once_program(key, method, setting)


@functools.lru_cache(maxsize=256)
def error_cell(method: str, setting: HFSetting) -> Callable[[jax.Array], Errors]:
    """``key -> Errors`` of one seeded run of ``method`` on ``setting`` (a sweep cell's function).

    Cached: experiments sharing a (method, setting) cell get the same function, so
    they share its compilation (:func:`jaxnav.core.batch.compiled_vmap`).
    """

    def fn(key):
        return run_once(key, method, setting)[0]

    return fn


def dead_reckoning(run: tc.HFRun) -> jax.Array:
    """``[T, 3]`` odometry integrated from the start pose ([W] eq. 3.6 without noise)."""
    return trajectories.integrate_controls(run.start_pose, run.odometry, "omni")


class MapShift(NamedTuple):
    """How far a SLAM map lies from the truth as a whole, and how well it has the truth's shape.

    Attributes:
        shift_mm: ``[2]`` the mean of ``mapped − true`` over the mapped tags (mm): the shift of the
            whole map, which the detections cannot see (the robot is localised against the same map).
        tag_mm: the tags' mean error ``|mapped − true|`` (mm), [W]'s ``dt``.
        tag_unshifted_mm: the same with the shift taken off every tag, ``|mapped − true − shift|`` (mm):
            the map's shape error.
        robot_unshifted_mm: the robot's mean position error with the shift taken off, ``|x̂ − x − shift|``
            (mm), to set beside [W]'s ``dr``.
    """

    shift_mm: np.ndarray
    tag_mm: float
    tag_unshifted_mm: float
    robot_unshifted_mm: float


def map_shift(world: World, result: MethodRun) -> MapShift | None:
    """The map's common shift and the errors without it (:class:`MapShift`); None when no tag was mapped.

    A SLAM map is pinned to the world only through the robot's start pose and the first detections, so
    an error made then moves the whole map and the robot's estimate with it, and no later detection
    can see it: the errors that remain once that shift is removed say how well the filter built the
    map and followed the robot on it.
    """
    seen = np.asarray(result.seen, bool)
    if not seen.any():
        return None
    d = np.asarray(result.tags, np.float64)[seen] - np.asarray(tc.tag_positions(world.carpet), np.float64)[seen]
    shift = d.mean(axis=0)
    e = np.asarray(result.estimates, np.float64)[:, :2] - np.asarray(world.run.true_poses, np.float64)[:, :2]
    mm = 1000.0
    return MapShift(
        shift_mm=mm * shift,
        tag_mm=mm * float(np.linalg.norm(d, axis=1).mean()),
        tag_unshifted_mm=mm * float(np.linalg.norm(d - shift, axis=1).mean()),
        robot_unshifted_mm=mm * float(np.linalg.norm(e - shift, axis=1).mean()),
    )


def format_errors(rows: list[tuple[str, Any]]) -> str:
    """A table like [W]'s: one row per ``(label, Errors)`` (a tag error with no tag mapped: :data:`~jaxnav.experiments.hf_slam.simulation.NOTHING_MAPPED`)."""
    columns = [report.Column("method", 16, "<")] + [report.Column(h, 9) for h in COLUMN_HEADS]
    cells = []
    for label, e in rows:
        cells.append(
            [label]
            + [
                report.number(
                    float(v), 3 if c == "theta_rad" else 1, nan=NOTHING_MAPPED if c in TAG_COLUMNS else report.NA
                )
                for c, v in zip(ERROR_COLUMNS, e)
            ]
        )
    return report.text(columns, cells)


def _draw_run(setting: HFSetting, method: str, world: World, result: MethodRun):
    """The figure of :func:`plot_run`."""
    import matplotlib.pyplot as plt

    name = METHOD_LABELS.get(method, method)
    run = world.run
    truth = np.asarray(run.true_poses)
    est = np.asarray(result.estimates)
    dr = np.asarray(dead_reckoning(run))
    tags = np.asarray(tc.tag_positions(world.carpet))
    seen = np.asarray(result.seen, bool)
    mapped = np.asarray(result.tags)
    times = np.arange(truth.shape[0]) * setting.dt

    # constrained layout makes room for the map's legend under it (tight_layout would cut it off)
    fig, (ax_map, ax_err, ax_tag) = plt.subplots(1, 3, figsize=(17, 5.8), layout="constrained")
    ax_map.plot(tags[:, 0], tags[:, 1], ".", color="0.75", ms=3, label="tags (truth)")
    ax_map.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="true path")
    ax_map.plot(dr[:, 0], dr[:, 1], "-", color="tab:gray", lw=0.8, label="odometry")
    ax_map.plot(est[:, 0], est[:, 1], "-", color="tab:blue", lw=1, label=f"{name} path")
    ax_map.plot(tags[seen, 0], tags[seen, 1], "o", mfc="none", color="k", ms=5, label="detected tags (truth)")
    ax_map.plot(mapped[seen, 0], mapped[seen, 1], "x", color="tab:red", ms=5, label=f"{name} map")
    ax_map.plot(*truth[0, :2], "o", color="tab:green", ms=8, label="start")
    kid = np.nonzero(np.asarray(run.kidnapped))[0]
    for k in kid:
        ax_map.plot(*truth[k - 1, :2], "v", color="tab:orange", ms=10, label="kidnapped here (B)")
        ax_map.plot(*truth[k, :2], "^", color="tab:orange", ms=10, label="put down here (C)")
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("x (m)")
    ax_map.set_ylabel("y (m)")
    ax_map.set_title(
        f"{name}: {setting.density:g} tags/m², {1000 * setting.reader_side:g} mm readers, {setting.trajectory}"
    )
    ax_map.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3)

    err = 1000 * np.linalg.norm(est[:, :2] - truth[:, :2], axis=1)
    err_dr = 1000 * np.linalg.norm(dr[:, :2] - truth[:, :2], axis=1)
    ax_err.plot(times, err_dr, color="tab:gray", lw=0.8, label=f"odometry (mean {err_dr.mean():.0f} mm)")
    ax_err.plot(times, err, color="tab:blue", lw=1, label=f"{name} (mean {err.mean():.0f} mm)")
    for k in kid:
        ax_err.axvline(times[k], color="tab:orange", ls="--", lw=1, label="kidnapping")
    ax_err.set_yscale("log")
    ax_err.set_xlabel("time (s)")
    ax_err.set_ylabel("robot position error (mm)")
    ax_err.set_title("robot error")
    ax_err.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3)

    shift = map_shift(world, result)
    if shift is not None:
        d = 1000 * (mapped - tags)[seen]
        bins = np.linspace(0.0, max(float(np.linalg.norm(d, axis=1).max()), 1.0), 16)
        dx, dy = shift.shift_mm
        ax_tag.hist(np.linalg.norm(d, axis=1), bins, color="tab:red", alpha=0.5,
                    label=f"as mapped (mean {shift.tag_mm:.0f} mm)")  # fmt: skip
        ax_tag.hist(np.linalg.norm(d - shift.shift_mm, axis=1), bins, histtype="step", lw=2, color="k",
                    label=f"the map's common shift ({dx:+.0f}, {dy:+.0f}) mm taken off (mean {shift.tag_unshifted_mm:.0f} mm)")  # fmt: skip
        ax_tag.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1))
    ax_tag.set_xlabel("final tag error (mm)")
    ax_tag.set_ylabel("mapped tags")
    ax_tag.set_title(f"{int(seen.sum())} mapped tags: error against the truth")
    return fig


def plot_run(setting: HFSetting, method: str, world: World, result: MethodRun, path: str) -> None:
    """Path and map (left), robot error over time (middle), the mapped tags' errors with and without the
    map's common shift (right, :func:`map_shift`); a PNG at ``path``."""
    import matplotlib.pyplot as plt

    fig = _draw_run(setting, method, world, result)
    fig.savefig(path, dpi=110)
    plt.close(fig)
