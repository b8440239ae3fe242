"""W3 fastslam-step: one FastSLAM 1.0 step on M particles that each carry N landmarks.

The workload: FastSLAM 1.0, 2-D range-bearing;
M = 100, 500, 1000, 4000 particles; N = 10, 100, 1000 landmarks already in
every particle (a mean and a 2 × 2 covariance each); K = 5 landmarks observed
per step with known correspondences; an EKF update per observed landmark and
particle; the weight from the innovation likelihood; systematic resampling
every step, which copies each chosen particle's map. Median seconds per step
over T = 20 steps. Size keys ``{"M", "landmarks"}`` (``landmarks`` = N); the
twelve sizes run M-major (``--quick``: M = 100 with N = 10 and 100).

Data
----
Per N, shared by every M and every implementation:

* landmarks uniform in a 10 m × 10 m room (``numpy.random.default_rng(0)``);
* one trajectory of :func:`jaxnav.sim.landmark_world.simulate` (key 0, start
  ``(5, 5, 0)``, controls ``(v, ω, Δt) = (0.5 m/s, 0.1 rad/s, 0.1 s)`` for 20
  steps, pose noise sd ``(0.02 m, 0.02 m, 0.01 rad)``, range-bearing noise sd
  ``(0.1 m, 0.05 rad)``, the W2 noises); at each step the K = 5 landmarks
  nearest to the true pose are the observations (ids, measurements, mask all
  True);
* the prior map put in every particle: the true positions plus N(0, 0.05²) m
  noise (``default_rng(1)``), each with its own covariance
  ``R(φ) diag(s₁², s₂²) R(φ)ᵀ``, ``s ~ U(0.03, 0.1)`` m, ``φ ~ U(0, π)``.

The initial particles come from :func:`jaxnav.slam.fastslam.init` (key 1,
pose sd ``(0.05, 0.05, 0.02)``) and are handed to the peer as NumPy arrays.
The filter uses the simulation's noises (velocity model with zero α and the
pose sd above; the sensor sd above).

Implementations
---------------
* ``jaxnav`` ``per_call``: the public :func:`jaxnav.slam.fastslam.step`
  (host-side validation, then the jitted step, which *donates* the state)
  called 20 times from Python, one ``block_until_ready`` per step; each pass
  starts from a fresh copy of the initial state.
* ``jaxnav`` ``in_scan``: :func:`jaxnav.slam.fastslam.run` over the 20 steps
  (one ``lax.scan``), time / 20.
* ``numpy`` ``per_call``: :class:`benchmarks.peers.numpy_fastslam.NumpyFastSLAM`,
  float32, vectorised over particles, a Python loop over the 5 observations,
  maps resampled by fancy indexing.

jaxnav's step also computes the weighted-mean pose estimate, ESS and
diagnostics; the peer computes the ESS but not the estimate (not part of W3).

Floor
-----
Bytes that must move once per step, ``b`` the float size (4, float32),
int32 indices, K = 5 observed landmarks, a landmark = 2 + 4 floats
(mean, full 2 × 2 covariance as stored)::

    motion:          poses read + written                   2 · 3 · M · b
    landmark update: K landmarks read + written             2 · 6 · K · M · b
    weights:         log-weights written + read             2 · M · b
    resampling:      indices written                        4 · M
    copy:            poses read + written                   2 · 3 · M · b
                     maps (means + covs) read + written     2 · 6 · N · M · b
    total = M · (b · (14 + 12 K + 12 N) + 4) = M · (300 + 48 N) bytes (float32, K = 5)

At M = 4000, N = 1000: 193.2 MB, of which the map copy is 192 MB.
``floor_s = total / bandwidth`` (the same on every row of a size).

Part-by-part timing (what dominates a step):
``python -m benchmarks.workloads.w3_fastslam --profile [--sizes 4000x1000,4000x10]``.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, Timing, _GcOff, guarded, make_row, time_calls
from benchmarks.workloads import Workload, register

NAME = "W3"
T = 20
K = 5
ROOM = 10.0  # m
POSE_SD = (0.02, 0.02, 0.01)  # m, m, rad
SENSOR_SD = (0.1, 0.05)  # m, rad
CONTROL = (0.5, 0.1, 0.1)  # v [m/s], ω [rad/s], Δt [s]
START = (5.0, 5.0, 0.0)
INIT_SD = (0.05, 0.05, 0.02)
PRIOR_SD = 0.05  # m, error of the prior map's means
FLOAT_BYTES = 4
PARTICLES = (100, 500, 1000, 4000)
LANDMARKS = (10, 100, 1000)

FLOOR_DOC = (
    "M * (b*(14 + 12K + 12N) + 4) bytes per step, b = 4 (float32), K = 5: poses read+written by the motion "
    "(6Mb), the K observed landmarks (6 floats) read+written (12KMb), log-weights written+read (2Mb), int32 "
    "indices (4M), the resampling copy of poses (6Mb) and of every map, means + covariances read+written "
    "(12NMb); = M (300 + 48 N) bytes; / measured bandwidth"
)

__all__ = [
    "floor_bytes",
    "W3Data",
    "make_data",
    "config_params",
    "initial_state",
    "profile",
]


def floor_bytes(m: int, n: int, k: int = K, b: int = FLOAT_BYTES) -> int:
    """Bytes one W3 step must move once: ``M · (b·(14 + 12K + 12N) + 4)`` (see the module docstring)."""
    motion = 2 * 3 * m * b
    update = 2 * 6 * k * m * b
    log_weights = 2 * m * b
    indices = 4 * m
    copy = 2 * 3 * m * b + 2 * 6 * n * m * b
    return motion + update + log_weights + indices + copy


# ---------------------------------------------------------------------------
# data


class W3Data:
    """Inputs of one N, shared by every M and implementation.

    Attributes:
        landmarks: ``[N, 2]`` true positions (m).
        prior_means: ``[N, 2]``, prior_covs: ``[N, 2, 2]`` the map put in every particle.
        controls: ``[T, 3]``; true_poses: ``[T, 3]``.
        ids: ``[T, K]`` int32, z: ``[T, K, 2]``, mask: ``[T, K]`` the observations.
    """

    def __init__(self, landmarks, prior_means, prior_covs, controls, true_poses, ids, z, mask):
        self.landmarks = landmarks
        self.prior_means = prior_means
        self.prior_covs = prior_covs
        self.controls = controls
        self.true_poses = true_poses
        self.ids = ids
        self.z = z
        self.mask = mask

    def observations(self):
        """The ``[T, K]`` :class:`~jaxnav.models.landmarks.RangeBearingObs` (jax arrays)."""
        from jaxnav.models.landmarks import RangeBearingObs

        return RangeBearingObs(jnp.asarray(self.ids), jnp.asarray(self.z), jnp.asarray(self.mask))


def make_data(n: int, t: int = T, k: int = K, dtype=np.float32) -> W3Data:
    """Landmarks, prior map, trajectory and the K-nearest observations for N = ``n`` (seeded)."""
    from jaxnav.models.landmarks import RangeBearingNoise
    from jaxnav.models.motion import VelocityNoise
    from jaxnav.sim.landmark_world import simulate

    if k > n:
        raise ValueError(f"need at least K = {k} landmarks, got {n}")
    rng = np.random.default_rng(0)
    landmarks = rng.uniform(0.0, ROOM, (n, 2))
    rng1 = np.random.default_rng(1)
    prior_means = landmarks + rng1.normal(0.0, PRIOR_SD, (n, 2))
    s = rng1.uniform(0.03, 0.1, (n, 2))
    phi = rng1.uniform(0.0, math.pi, n)
    rot = np.stack([np.stack([np.cos(phi), -np.sin(phi)], -1), np.stack([np.sin(phi), np.cos(phi)], -1)], -2)
    prior_covs = rot @ (s[:, :, None] ** 2 * np.eye(2)) @ np.swapaxes(rot, -1, -2)
    prior_covs = 0.5 * (prior_covs + np.swapaxes(prior_covs, -1, -2))
    controls = np.tile(np.asarray(CONTROL), (t, 1))
    motion_noise = VelocityNoise(alphas=jnp.zeros((6,), dtype), pose_sd=jnp.asarray(POSE_SD, dtype))
    sensor_noise = RangeBearingNoise(jnp.asarray(SENSOR_SD, dtype))
    sim = simulate(
        jax.random.key(0),
        jnp.asarray(landmarks, dtype),
        jnp.asarray(START, dtype),
        jnp.asarray(controls, dtype),
        motion_noise,
        sensor_noise,
    )
    true_poses = np.asarray(sim.true_poses, np.float64)
    z_all = np.asarray(sim.observations.z)
    dist = np.hypot(landmarks[None, :, 0] - true_poses[:, None, 0], landmarks[None, :, 1] - true_poses[:, None, 1])
    ids = np.argsort(dist, axis=1, kind="stable")[:, :k].astype(np.int32)
    z = np.take_along_axis(z_all, ids[:, :, None], axis=1)
    return W3Data(
        landmarks.astype(dtype),
        prior_means.astype(dtype),
        prior_covs.astype(dtype),
        controls.astype(dtype),
        true_poses.astype(dtype),
        ids,
        z.astype(dtype),
        np.ones((t, k), bool),
    )


_DATA_CACHE: dict = {}


def _data(n: int) -> W3Data:
    if n not in _DATA_CACHE:
        _DATA_CACHE.clear()  # one N at a time (sizes run M-major, so this recomputes a few small sims)
        _DATA_CACHE[n] = make_data(n)
    return _DATA_CACHE[n]


def config_params(m: int, n: int, ess_threshold: float = 1.0):
    """``(FastSLAMConfig, FastSLAMParams)`` of W3 for M particles and N landmarks."""
    from jaxnav.models.landmarks import RangeBearingNoise
    from jaxnav.models.motion import VelocityNoise
    from jaxnav.slam import fastslam as fs

    config = fs.FastSLAMConfig(
        num_particles=m,
        num_landmarks=n,
        version=1,
        motion_model="velocity",
        resampling="systematic",
        ess_threshold=ess_threshold,
    )
    params = fs.FastSLAMParams(
        VelocityNoise(alphas=jnp.zeros((6,), jnp.float32), pose_sd=jnp.asarray(POSE_SD, jnp.float32)),
        RangeBearingNoise(jnp.asarray(SENSOR_SD, jnp.float32)),
    )
    return config, params


def initial_state(m: int, n: int):
    """jaxnav's initial state (key 1, pose sd ``INIT_SD``, the prior map in every particle)."""
    from jaxnav.slam import fastslam as fs

    data = _data(n)
    config, params = config_params(m, n)
    return jax.block_until_ready(
        fs.init(
            jax.random.key(1),
            config,
            params,
            jnp.asarray(START, jnp.float32),
            jnp.asarray(INIT_SD, jnp.float32),
            landmark_means=jnp.asarray(data.prior_means),
            landmark_covs=jnp.asarray(data.prior_covs),
        )
    )


def _fresh(state):
    """A copy of ``state`` in new buffers (the jitted steps donate their input)."""
    return jax.block_until_ready(jax.tree_util.tree_map(jnp.copy, state))


# ---------------------------------------------------------------------------
# timing


def _per_step_timing(
    start: Callable[[], Callable[[int], object]], *, passes: int, budget_s: float, min_steps: int = 5
) -> Timing:
    """Median per-step time over ``passes`` runs of the T steps (``start()`` resets and returns ``step(t)``)."""
    samples: list[float] = []
    spent = 0.0
    with _GcOff():
        for _ in range(passes):
            step = start()
            for t in range(T):
                t0 = time.perf_counter()
                step(t)
                dt = time.perf_counter() - t0
                samples.append(dt)
                spent += dt
                if spent >= budget_s and len(samples) >= min_steps:
                    return Timing.from_samples(samples)
    return Timing.from_samples(samples)


def _step_inputs(n: int):
    """Per-step keys, controls and observations, sliced on the device before any timing."""
    from jaxnav.models.landmarks import RangeBearingObs

    data = _data(n)
    run_key = jax.random.key(2)
    keys = [jax.random.fold_in(run_key, t) for t in range(T)]
    ctrls = [jnp.asarray(data.controls[t]) for t in range(T)]
    obs = [
        RangeBearingObs(jnp.asarray(data.ids[t]), jnp.asarray(data.z[t]), jnp.asarray(data.mask[t])) for t in range(T)
    ]
    return jax.block_until_ready((run_key, keys, ctrls, obs))


def _big(m: int, n: int) -> bool:
    return m * n >= 10**6


def _jax_per_call(ctx: Context, size: dict, state0, floor_s: float) -> dict:
    from jaxnav.slam import fastslam as fs

    m, n = int(size["M"]), int(size["landmarks"])
    config, params = config_params(m, n)
    _, keys, ctrls, obs = _step_inputs(n)
    compile_s = ctx.compile_s(
        (NAME, "jaxnav", "step", m, n), fs.step.jitted, keys[0], state0, config, params, ctrls[0], obs[0]
    )
    jax.block_until_ready(fs.step(keys[0], _fresh(state0), config, params, ctrls[0], obs[0]))  # warm-up

    def start():
        box = [_fresh(state0)]

        def step(t):
            new_state, info = fs.step(keys[t], box[0], config, params, ctrls[t], obs[t])
            jax.block_until_ready((new_state, info))
            box[0] = new_state

        return step

    t = _per_step_timing(start, passes=ctx.reps(2 if _big(m, n) else 3), budget_s=20.0)
    return make_row(
        NAME,
        "jaxnav",
        size,
        "per_call",
        t,
        compile_s=compile_s,
        floor_s=floor_s,
        landmarks=n,
        steps=t.repeats,
        dtype="float32",
        note="public fastslam.step (host-side validation + jitted step, donates state)",
    )


def _jax_in_scan(ctx: Context, size: dict, state0, floor_s: float) -> dict:
    from jaxnav.slam import fastslam as fs

    m, n = int(size["M"]), int(size["landmarks"])
    config, params = config_params(m, n)
    data = _data(n)
    controls, observations = jnp.asarray(data.controls), data.observations()
    run_key = jax.random.key(2)
    compile_s = ctx.compile_s(
        (NAME, "jaxnav", "run", m, n), fs.run.jitted, run_key, state0, config, params, controls, observations
    )

    def call():
        return jax.block_until_ready(fs.run(run_key, state0, config, params, controls, observations))

    t = time_calls(call, repeats=ctx.reps(3 if _big(m, n) else 7), warmup=1, budget_s=30.0, min_repeats=2)
    return make_row(
        NAME,
        "jaxnav",
        size,
        "in_scan",
        t.per(T),
        compile_s=compile_s,
        floor_s=floor_s,
        steps=T,
        landmarks=n,
        dtype="float32",
        note="fastslam.run over 20 steps (one lax.scan), time / 20",
    )


def _numpy_row(ctx: Context, size: dict, state0, floor_s: float) -> dict:
    from benchmarks.peers.numpy_fastslam import DEFAULT_DTYPE, NumpyFastSLAM

    m, n = int(size["M"]), int(size["landmarks"])
    data = _data(n)
    arrays = [np.asarray(x) for x in (state0.poses, state0.log_weights, state0.means, state0.covs)]

    def start():
        pf = NumpyFastSLAM(*arrays, POSE_SD, SENSOR_SD, seed=7, dtype=DEFAULT_DTYPE)

        def step(t):
            pf.step(data.controls[t], data.ids[t], data.z[t])

        return step

    warm = start()
    warm(0)
    t = _per_step_timing(start, passes=ctx.reps(2 if _big(m, n) else 3), budget_s=20.0)
    return make_row(
        NAME,
        "numpy",
        size,
        "per_call",
        t,
        floor_s=floor_s,
        landmarks=n,
        steps=t.repeats,
        dtype="float32",
        note="vectorised over particles, loop over the 5 observations, fancy-index copy",
    )


def run(ctx: Context, size: dict) -> list[dict]:
    m, n = int(size["M"]), int(size["landmarks"])
    floor_s = ctx.floor(floor_bytes(m, n))
    state0 = initial_state(m, n)
    rows = []
    rows += guarded(ctx, NAME, "jaxnav", size, "per_call", lambda: _jax_per_call(ctx, size, state0, floor_s))
    rows += guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jax_in_scan(ctx, size, state0, floor_s))
    rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, state0, floor_s))
    return rows


register(
    Workload(
        name=NAME,
        title="W3 FastSLAM 1.0 step, K = 5 observed, N landmarks per particle (time per step)",
        sizes=[{"M": mm, "landmarks": nn} for mm in PARTICLES for nn in LANDMARKS],
        run=run,
        x_key="M",
        floor_doc=FLOOR_DOC,
        series_key="landmarks",
    )
)


# ---------------------------------------------------------------------------
# part-by-part profile (python -m benchmarks.workloads.w3_fastslam --profile)


def profile(sizes=((4000, 1000), (4000, 10)), reps: int = 10) -> list[dict]:
    """Time jaxnav's W3 step and its parts per call (median of ``reps`` calls on a donated state).

    Parts: the full step; the step without resampling (``ess_threshold`` so low
    that the ``lax.cond`` never resamples); the step with every observation
    masked out (no EKF); the landmark update alone (``fastslam.update_landmarks``);
    the resampling alone (``conditional_resample`` of poses and maps, with the
    log-weights of a real step so that the ancestors are not the identity); a
    donated elementwise rewrite of the maps (XLA's bandwidth on them); the same
    resampling gather inside a ``lax.scan`` of 20 steps (per step: the temporary
    buffer is allocated once per scan, not once per step); NumPy's
    fancy-index copy of the maps with the same ancestors.
    """
    from jaxnav.core import resampling
    from jaxnav.models import observation
    from jaxnav.slam import fastslam as fs

    out = []
    for m, n in sizes:
        state0 = initial_state(m, n)
        config, params = config_params(m, n)
        cfg_nr, _ = config_params(m, n, ess_threshold=1e-6)
        _, keys, ctrls, obs = _step_inputs(n)
        key, u, o = keys[1], ctrls[1], obs[1]
        o_none = o._replace(mask=jnp.zeros_like(o.mask))
        r = observation.RANGE_BEARING.noise_cov(params.sensor)
        # the slots the step updates (every W3 id is in the map; out-of-range ids would be dropped)
        valid = o.mask & (o.ids >= 0) & (o.ids < n)
        ids = jnp.clip(o.ids, 0, n - 1)
        # log-weights after one real step (without resampling): realistic ancestors
        lw = jax.block_until_ready(
            fs.step.jitted(keys[0], _fresh(state0), cfg_nr, params, ctrls[0], obs[0])[0].log_weights
        )
        k_res, _ = jax.random.split(jax.random.split(key)[1])
        idx = resampling.resample_weights(k_res, jnp.exp(lw), m)
        moved = int(jnp.sum(idx != jnp.arange(m)))

        @partial(jax.jit, donate_argnums=0)
        def update_only(s):
            upd, _, ll, _ = fs.update_landmarks(
                observation.RANGE_BEARING, r, s.poses, s.means, s.covs, s.seen, o, valid, ids
            )
            # write the updated rows (slot k -> landmark upd.write[k]; write[k] = N drops the slot)
            means = s.means.at[:, upd.write].set(jnp.swapaxes(upd.rows_mu, 0, 1), mode="drop")
            covs = s.covs.at[:, upd.write].set(jnp.swapaxes(upd.rows_cov, 0, 1), mode="drop")
            return s._replace(means=means, covs=covs, log_weights=s.log_weights + 1e-6 * ll)

        @partial(jax.jit, donate_argnums=0)
        def resample_only(s):
            res = resampling.conditional_resample(key, (s.poses, s.means, s.covs), lw, threshold=1.0, normalized=True)
            p, mu, c = res.particles
            return s._replace(poses=p, means=mu, covs=c)

        @partial(jax.jit, donate_argnums=0)
        def rewrite(s):
            return s._replace(means=s.means * 1.0000001, covs=s.covs * 1.0000001)

        @partial(jax.jit, donate_argnums=0)
        def gather_in_scan(s):
            def body(c, _):
                return (jnp.take(c[0], idx, axis=0), jnp.take(c[1], idx, axis=0)), None

            (mu, c), _ = jax.lax.scan(body, (s.means, s.covs), None, length=T)
            return s._replace(means=mu, covs=c)

        parts = [
            ("full step (fastslam.step.jitted)", lambda s: fs.step.jitted(key, s, config, params, u, o)[0], 1),
            ("step without resampling", lambda s: fs.step.jitted(key, s, cfg_nr, params, u, o)[0], 1),
            ("step without observations", lambda s: fs.step.jitted(key, s, config, params, u, o_none)[0], 1),
            ("landmark update only", update_only, 1),
            ("resampling only (jnp.take)", resample_only, 1),
            ("resampling gather in a scan, per step", gather_in_scan, T),
            ("elementwise rewrite of the maps (XLA)", rewrite, 1),
        ]
        for label, f, div in parts:
            s = f(_fresh(state0))
            jax.block_until_ready(s)
            samples = []
            with _GcOff():
                for _ in range(reps if div == 1 else max(2, reps // 4)):
                    t0 = time.perf_counter()
                    s = jax.block_until_ready(f(s))
                    samples.append((time.perf_counter() - t0) / div)
            out.append(
                {
                    "M": m,
                    "landmarks": n,
                    "part": label,
                    "median_s": float(np.median(samples)),
                    "min_s": float(np.min(samples)),
                }
            )
        maps = (np.asarray(state0.means), np.asarray(state0.covs))
        idx_np = np.asarray(idx)
        samples = []
        with _GcOff():
            for _ in range(reps):
                t0 = time.perf_counter()
                _ = (maps[0][idx_np], maps[1][idx_np])
                samples.append(time.perf_counter() - t0)
        out.append(
            {
                "M": m,
                "landmarks": n,
                "part": f"NumPy fancy-index copy of the maps ({moved} of {m} moved)",
                "median_s": float(np.median(samples)),
                "min_s": float(np.min(samples)),
            }
        )
    return out


def _main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.workloads.w3_fastslam")
    p.add_argument("--profile", action="store_true", help="time jaxnav's W3 step part by part")
    p.add_argument("--sizes", default="4000x1000,4000x10", help="MxN pairs, comma-separated")
    p.add_argument("--reps", type=int, default=10)
    args = p.parse_args(argv)
    if not args.profile:
        p.print_help()
        return 0
    import os

    from benchmarks.harness import fmt_time, measure_bandwidth

    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",") if s]
    bw = measure_bandwidth()["bandwidth_bytes_per_s"]
    print(f"copy bandwidth {bw / 1e9:.2f} GB/s; load average {os.getloadavg()}")
    for row in profile(sizes, args.reps):
        floor = floor_bytes(row["M"], row["landmarks"]) / bw
        print(
            f"M={row['M']:<5} N={row['landmarks']:<5} {row['part']:<42} median {fmt_time(row['median_s']):>10}  "
            f"min {fmt_time(row['min_s']):>10}  ({row['median_s'] / floor:.1f}x floor)",
            flush=True,
        )
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
