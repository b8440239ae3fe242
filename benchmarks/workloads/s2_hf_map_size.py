"""S2 — HF-RFID SLAM time per update against the number of tags already in the map ([W] Fig. 3.8, Fig. 4.1b).

The workload: 500 robot particles, maps of
N = 10, 100, 1,000, 10,000 and 100,000 tags already mapped (``--quick``:
10 and 1,000); PF-SLAM and PS-SLAM (100 tag particles, lag 20) and FastSLAM
1.0 on the HF reader model, 60 mm readers (the default array of eight,
2 rows × 4 at 60 mm), odometry noise σ = (20 mm/s, 20 mm/s, 0.01 rad/s) of
:class:`jaxnav.experiments.hf_slam.HFSetting`. The claim under test ([W]
§3.3.1): a PF/PS-SLAM step touches only the detected tags, so its time does
not grow with the map (target ``t(100,000) / t(10) ≤ 1.5``), while FastSLAM's
resampling copies every particle's whole map (``O(I·N)``).

World (synthetic, fixed, the same for every method)
---------------------------------------------------
The N tags lie on a lattice whose spacing is that of the four corner readers
of the array, ``(Δx, Δy) = (0.18 m, 0.06 m)`` (≈ 93 tags/m², close to the
100 tags/m² of [W] Fig. 3.8), ``nx × ny = N`` with ``ny`` the largest divisor
of N not above √N (10 = 5 × 2, 1,000 = 40 × 25, 100,000 = 400 × 250); tag
``(c, r)`` has ID ``r·nx + c``. At every step the robot (θ = 0) stands so that
the corner readers 0, 3, 4, 7 lie exactly over the tags ``(c, r)``,
``(c+1, r)``, ``(c, r+1)``, ``(c+1, r+1)`` of a 2 × 2 block, and no other
reader sees a tag (the other readers are 60 mm from the nearest lattice
column, twice their half-width): **exactly K = 4 detections per step, all of
already-mapped tags** (4 slots, all valid). The block is drawn uniformly over
the map at every step (``numpy.random.default_rng(0)``), so the table rows a
step touches are spread over the whole map (no cache locality helps large
maps); the odometry carries the jump (``v = Δp/Δt``, Δt = 0.1 s, ω = 0).
T = 200 steps.

Prefilled map ("already mapped"): every tag's 100 particles are its true
position plus N(0, (5 mm)²) per axis (``jax.random.key(3)``), uniform
log-weights, estimate = their mean, detection count 5 (``count > 0``: seen);
PS-SLAM's rings hold these particles in every slot. The PF/PS state is built
directly as the module's NamedTuple with ``max_tags = N``; the robot's 500
particles start at the true start pose. FastSLAM's map is the same positions
with covariance ``(5 mm)² I`` in every particle, through
``fastslam.init(..., landmark_means=..., landmark_covs=...)``
(``500 × 100,000 × 6`` floats = 1.2 GB at the largest size).

Modes, as S1 (:mod:`benchmarks.workloads.s1_hf_particles`): ``per_call``
(public ``step``, donated state carried forward, median over
``100 · repeats`` steps, default repeats 2, within a 20 s budget) and
``in_scan`` (``run`` over 200 steps for PF/PS-SLAM, 20 for FastSLAM, median
of ``repeats`` calls, default 3, within 30 s, / steps). ``in_scan`` calls
the donated jitted scan ``run.jitted_donated`` on a fresh prefilled state made
before the timer starts: without donation ``run`` copies the whole state into
its scan once per call (``O(N)``, amortised over the steps; PF-SLAM at 100,000
tags 0.53 ms per step instead of 0.27 ms). The row records the time of one
such copy in ``state_copy_s``, the state size in ``state_bytes``, and in
``public_call_s`` the median time of one public ``run(..., donate_state=True)``
call on a fresh state, which adds the check of a state the filter has not seen
(one pass over it, once per call: O(N), not per step).

Every row carries ``ratio_to_10_tags``: its median over the median of the
same method and mode at 10 tags (measured earlier in the same run); the
ratio at the largest size is also written to the run's notes.
"""

from __future__ import annotations

import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, guarded
from benchmarks.workloads import REGISTRY, Workload, register
from benchmarks.workloads.s1_hf_particles import INIT_KEY, METHODS, filter_setup, measure, method_observations

NAME = "S2"
TAGS = (10, 100, 1000, 10_000, 100_000)
QUICK_TAGS = (10, 1000)
ROBOT_PARTICLES = 500
TAG_PARTICLES = 100
LAG = 20
READER_SIDE = 0.06  # m
ODOMETRY_SD = (0.02, 0.02, 0.01)  # m/s, m/s, rad/s (HFSetting's default)
DETECTING_READERS = (0, 3, 4, 7)  # the corner readers of the default 2 × 4 array
T = 200
SCAN_STEPS = {"pf_slam": 200, "ps_slam": 200, "fastslam": 20}
DT = 0.1  # s
TAG_SD = 0.005  # m, spread of a mapped tag's particles / FastSLAM landmark sd
COUNT = 5  # detections of every prefilled tag
PER_CALL_STEPS = 100  # per repeat
PER_CALL_BUDGET_S = 20.0
SCAN_BUDGET_S = 30.0
MAP_KEY = 3

__all__ = [
    "lattice_shape",
    "S2World",
    "make_world",
    "sensor",
    "motion",
    "prefilled_state",
    "run_rows",
    "run",
    "ratio_notes",
]


def sensor():
    from jaxnav.models import hf_rfid

    return hf_rfid.reader_params(READER_SIDE)


def motion():
    from jaxnav.models.motion import OmniNoise

    return OmniNoise(jnp.asarray(ODOMETRY_SD, jnp.float32))


def lattice_shape(n: int) -> tuple[int, int]:
    """``(nx, ny)`` with ``nx · ny = n``, ``ny`` the largest divisor of ``n`` with ``ny ≤ √n`` (≥ 2 rows)."""
    if n < 4:
        raise ValueError(f"S2 needs at least 4 tags (a 2 × 2 block), got {n}")
    ny = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    if ny < 2:
        raise ValueError(f"{n} tags cannot form a lattice of at least 2 rows and 2 columns")
    return n // ny, ny


class S2World:
    """The synthetic S2 world of N tags (module docstring).

    Attributes:
        positions: ``[N, 2]`` tag positions (m), row = tag ID.
        start_pose: ``[3]``; controls: ``[T, 4]`` ``(v_x, v_y, ω, Δt)``.
        detections: :class:`~jaxnav.models.hf_rfid.TagDetections`, ``[T, 4]``.
        true_poses: ``[T, 3]``.
    """

    def __init__(self, positions, start_pose, controls, detections, true_poses):
        self.positions = positions
        self.start_pose = start_pose
        self.controls = controls
        self.detections = detections
        self.true_poses = true_poses


def make_world(n: int, t: int = T, seed: int = 0) -> S2World:
    """Tags on the corner-reader lattice, a robot jumping to a random 2 × 2 block each step, 4 detections per step."""
    from jaxnav.models import hf_rfid

    nx, ny = lattice_shape(n)
    offsets = np.asarray(sensor().offsets, np.float64)
    r = np.asarray(DETECTING_READERS)
    dx = offsets[r[1], 0] - offsets[r[0], 0]
    dy = offsets[r[2], 1] - offsets[r[0], 1]
    cols, rows = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    positions = np.stack([cols.ravel() * dx, rows.ravel() * dy], axis=-1)  # ID = r·nx + c
    rng = np.random.default_rng(seed)
    c = rng.integers(0, nx - 1, t + 1)
    rr = rng.integers(0, ny - 1, t + 1)
    poses = np.stack([c * dx - offsets[r[0], 0], rr * dy - offsets[r[0], 1], np.zeros(t + 1)], axis=-1)
    controls = np.concatenate([(poses[1:, :2] - poses[:-1, :2]) / DT, np.zeros((t, 1)), np.full((t, 1), DT)], axis=1)
    block = np.stack([rr * nx + c, rr * nx + c + 1, (rr + 1) * nx + c, (rr + 1) * nx + c + 1], axis=-1)[1:]
    det = hf_rfid.TagDetections(
        jnp.asarray(block, jnp.int32),
        jnp.asarray(np.broadcast_to(r, (t, len(r))), jnp.int32),
        jnp.ones((t, len(r)), bool),
    )
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return S2World(f32(positions), f32(poses[0]), f32(controls), det, f32(poses[1:]))


_WORLDS: dict[int, S2World] = {}


def _world(n: int) -> S2World:
    if n not in _WORLDS:
        _WORLDS.clear()
        _WORLDS[n] = make_world(n)
    return _WORLDS[n]


def prefilled_state(method: str, module, config, params, w: S2World):
    """The initial state with every tag of ``w`` already mapped (module docstring)."""
    n = int(w.positions.shape[0])
    if method == "fastslam":
        covs = jnp.broadcast_to((TAG_SD**2) * jnp.eye(2, dtype=jnp.float32), (n, 2, 2))
        return module.init(
            jax.random.key(INIT_KEY), config, params, w.start_pose, landmark_means=w.positions, landmark_covs=covs
        )
    i, j = config.num_particles, config.num_tag_particles
    poses = jnp.tile(w.start_pose[None, :], (i, 1))
    log_w = jnp.full((i,), -np.log(i), jnp.float32)
    particles = w.positions[:, None, :] + TAG_SD * jax.random.normal(jax.random.key(MAP_KEY), (n, j, 2), jnp.float32)
    fields = dict(
        particles=particles,
        log_weights=jnp.full((n, j), -np.log(j), jnp.float32),
        estimates=jnp.mean(particles, axis=1),
        counts=jnp.full((n,), COUNT, jnp.int32),
    )
    if method == "ps_slam":
        fields["history"] = jnp.array(jnp.broadcast_to(particles[:, None], (n, config.lag, j, 2)))
        table = module.SmootherTable(**fields)
        return jax.block_until_ready(module.PSSLAMState(poses, log_w, table))
    table = module.TagTable(**fields)
    return jax.block_until_ready(module.PFSLAMState(poses, log_w, table))


def _nbytes(tree) -> int:
    return int(sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree_util.tree_leaves(tree)))


def _copy_time(state) -> float:
    """Best of two copies of ``state`` (the first also compiles the copy)."""
    best = math.inf
    for _ in range(2):
        t0 = time.perf_counter()
        out = jax.block_until_ready(jax.tree_util.tree_map(jnp.copy, state))
        best = min(best, time.perf_counter() - t0)
        del out
    return best


# medians of this run, (method, mode) -> {tags: median_s}, for the ratios to 10 tags
_MEDIANS: dict[tuple[str, str], dict[int, float]] = {}


def _add_ratio(row: dict) -> None:
    if row.get("median_s") is None:
        return
    table = _MEDIANS.setdefault((row["method"], row["mode"]), {})
    n = int(row["size"]["tags"])
    table[n] = row["median_s"]
    if min(TAGS) in table:
        row["ratio_to_10_tags"] = row["median_s"] / table[min(TAGS)]


def ratio_notes(rows: list[dict]) -> list[str]:
    """``t(largest)/t(10)`` per method and mode among ``rows`` (S2 rows), as sentences."""
    out = []
    for method in METHODS:
        for mode in ("per_call", "in_scan"):
            sel = {
                int(r["size"]["tags"]): r["median_s"]
                for r in rows
                if r.get("workload") == NAME
                and r.get("method") == method
                and r.get("mode") == mode
                and r.get("median_s") is not None
            }
            if min(TAGS) in sel and len(sel) > 1:
                big = max(sel)
                target = " (target ≤ 1.5)" if method != "fastslam" else " (grows with the map)"
                out.append(f"S2 {method} {mode}: t({big})/t({min(TAGS)}) = {sel[big] / sel[min(TAGS)]:.2f}{target}")
    return out


def run_rows(
    ctx: Context, size: dict, methods=METHODS, modes=("per_call", "in_scan"), steps: int | None = None
) -> list[dict]:
    """S2 rows of one size; ``steps`` shortens the trajectory (tests only)."""
    i, n = int(size["robot_particles"]), int(size["tags"])
    w = _world(n)
    controls, detections = w.controls, w.detections
    sens, mot = sensor(), motion()
    rows: list[dict] = []
    for method in methods:
        module, config, params = filter_setup(method, i, n, sens, mot, lag=LAG, tag_particles=TAG_PARTICLES)
        t_scan = SCAN_STEPS[method] if steps is None else min(steps, SCAN_STEPS[method])
        t_len = T if steps is None else steps
        obs_all = method_observations(method, detections, sens)
        extra: dict[str, Any] = dict(
            detections_per_step=len(DETECTING_READERS), slots=len(DETECTING_READERS), reader_side_m=READER_SIDE
        )
        if method != "fastslam":
            extra["tag_particles"] = TAG_PARTICLES
        if method == "ps_slam":
            extra["lag"] = LAG

        def make_state(method=method, module=module, config=config, params=params):
            return prefilled_state(method, module, config, params, w)

        for mode in modes:
            steps_here = t_scan if mode == "in_scan" else t_len
            ctrl = controls[:steps_here]
            obs = jax.tree_util.tree_map(lambda a: a[:steps_here], obs_all)

            def one(
                method=method,
                mode=mode,
                module=module,
                config=config,
                params=params,
                ctrl=ctrl,
                obs=obs,
                make_state=make_state,
                extra=extra,
            ):
                more = dict(extra)
                if mode == "in_scan":
                    state = make_state()
                    more["state_bytes"] = _nbytes(state)
                    more["state_copy_s"] = _copy_time(state)
                    del state
                return measure(
                    ctx,
                    NAME,
                    size,
                    method,
                    mode,
                    module=module,
                    config=config,
                    params=params,
                    make_state=make_state,
                    controls=ctrl,
                    observations=obs,
                    compile_key=(NAME, method, i, n, int(ctrl.shape[0])),
                    per_call_steps=PER_CALL_STEPS * ctx.reps(2),
                    per_call_budget_s=PER_CALL_BUDGET_S,
                    scan_repeats=ctx.reps(3),
                    scan_budget_s=SCAN_BUDGET_S,
                    donate_scan=True,
                    **more,
                )

            for r in guarded(ctx, NAME, "jaxnav", size, mode, one):
                r.setdefault("method", method)
                _add_ratio(r)
                rows.append(r)
    wl = REGISTRY.get(NAME)
    if wl is not None and n == int(ctx.sizes_of(wl)[-1]["tags"]):
        measured = [
            {"workload": NAME, "method": m, "mode": mo, "size": {"tags": t}, "median_s": v}
            for (m, mo), tab in _MEDIANS.items()
            for t, v in tab.items()
        ]
        for line in ratio_notes(measured):
            ctx.note(line)
    return rows


def run(ctx: Context, size: dict) -> list[dict]:
    return run_rows(ctx, size)


register(
    Workload(
        name=NAME,
        title="S2 HF-RFID SLAM time per update vs tags already mapped ([W] Figs. 3.8, 4.1b): 500 robot particles, "
        "4 detections per step",
        sizes=[{"robot_particles": ROBOT_PARTICLES, "tags": n} for n in TAGS],
        quick_sizes=[{"robot_particles": ROBOT_PARTICLES, "tags": n} for n in QUICK_TAGS],
        run=run,
        x_key="tags",
        series_key="method",
    )
)
