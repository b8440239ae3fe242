"""U1 uhf-tag-update: the static UHF-RFID tag localization update of [A] Alg. 6 on N particles.

It measures two things: a combined RSSI + phase update at 1e4 to 1e6
particles, in a scan, against a plain NumPy vectorised version of the same
update in the same run; and 10 tags vmapped against one tag (whether there is
a per-tag overhead: the aim is at most 10× the time of one tag).

The update
----------
:func:`jaxnav.localization.rfid_tag.step` with ``weighting="combined"``,
``dims=3``, ``ess_threshold=0.1``, ``refresh=True`` (the defaults): for each of
the ``J = 4`` reads of a step, ``log W_RSSI`` (two-ray power, stepped antenna
pattern, squared-Gamma density) plus ``log W_PHASE`` (Gaussian on [A]'s phase
distance), summed; ``logsumexp`` normalisation; weighted-mean estimate with the
offset on the circle; ESS; when ``ESS < 0.1 N`` the Gaussian refresh of
[A] §4.3.3 (from the weighted set's moments, see ``rfid_tag.resample``),
clipped into the search box.

Data
----
The 2 × 3 × 2 m search box of [A] §5.2 (:data:`jaxnav.sim.uhf_reader.SEARCH_BOX_A`);
a reader path :func:`~jaxnav.sim.uhf_reader.lawnmower_path` of four passes
along x from −0.5 to 2.5 m at depths y = −0.3, −0.6 m and heights z = 0.5,
1.5 m, 13 poses per pass plus connectors: **T = 57 steps**, boresight facing
+y; **J = 4 read slots per step** from
:func:`~jaxnav.sim.uhf_reader.simulate_reads` under
:data:`~jaxnav.sim.uhf_reader.LIGHT_MULTIPATH` (key 0). Ten tags: tag 0 at
``(1.2, 1.4, 0.9)`` m (offset 0.7 rad), tags 1–9 drawn uniformly inside the
box with 0.2–0.3 m margins (``default_rng(5)``), offsets uniform on the
circle. Filter parameters :func:`rfid_tag.default_params` with the light
preset's ``(k, θ) = (20, 0.05)``. Initial particles: :func:`rfid_tag.init`
with key 1 (tag ``g`` of the tag rows: ``fold_in(key 1, g)``; tag 0 uses
key 1 itself, so every implementation and row starts tag 0 from the same
particles), handed to NumPy as arrays.

Rows
----
Size ``{"N"}`` (N = 1e4, 1e5, 1e6; one tag, tag 0), time per step = time
of the T-step trajectory / T (the mean over the trajectory: steps that
resample cost more, so a median of single steps would favour neither side
consistently):

* ``jaxnav`` ``in_scan``: :func:`rfid_tag.run` (one ``lax.scan`` over the
  57 steps), ``compile_s`` of ``rfid_tag.run.jitted``.
* ``jax-baseline`` ``in_scan``: a hand-written plain-JAX ``lax.scan`` of the
  same update (the reference of what plain JAX reaches), particles as ``[4, N]`` rows, each read's
  geometry written component by component; not a peer.
* ``numpy`` ``per_call``: :class:`benchmarks.peers.numpy_uhf.NumpyRFIDTag`,
  float32, one ``step`` per time step from a Python loop.

Rows carry ``resamplings`` (how many of the 57 steps resampled: each
implementation draws its own random numbers, so the counts may differ by
one or two and are reported beside the times).

Size ``{"N": 1e4, "tags": G}`` (G = 1, 10): ``jaxnav`` ``in_scan`` with
``call = "run_tags"``: :func:`rfid_tag.run_tags` (``vmap`` of the scan over
tags) on ``G`` tags, time per step for all G tags together, and
``per_tag_s``; the ``tags = 10`` row adds ``ratio_to_tags_1``
(``time(10) / time(1)``, at most 10 without a per-tag overhead) and ``ratio_to_run`` (over
the unbatched :func:`rfid_tag.run` of tag 0 at N = 1e4 in the same run).
The tags are reweighed under ``vmap``; at steps where some tag resamples a
``lax.map`` over the tags runs each tag's own ``cond``, so a tag pays for the
refresh only when it resamples.

Floor
-----
``24 N`` bytes per step: the particles read once (4 float32 columns, 16 N)
and the log-weights read and written (8 N). A lower bound that leaves out
the resampling steps; the update is compute-bound (four reads × sqrt,
atan2, log, exp per particle), so the ratio to it is large.
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import Context, Timing, _GcOff, guarded, make_row, time_calls
from benchmarks.workloads import Workload, register

NAME = "U1"
J = 4  # read slots per step
PASS_POSES = 13
TAG0 = (1.2, 1.4, 0.9)
OFFSET0 = 0.7
NUM_TAGS = 10
SIZES_N = (10**4, 10**5, 10**6)
TAG_N = 10**4
TAG_COUNTS = (1, 10)
FLOOR_DOC = (
    "24 N bytes per step: particles read once (4 float32 columns, 16 N) + log-weights read and "
    "written (8 N); resampling steps not counted; / measured bandwidth"
)


def floor_bytes(n: int) -> int:
    """Bytes one U1 step must move at least once: particles read (16 N) + log-weights read and written (8 N)."""
    return 16 * n + 8 * n


# ---------------------------------------------------------------------------
# shared data

_CACHE: dict = {}


def world():
    """``(params, reads [G, T, J], tags [G, 3], offsets [G])`` shared by every implementation and size."""
    if "world" in _CACHE:
        return _CACHE["world"]
    from jaxnav.localization import rfid_tag as rt
    from jaxnav.sim import uhf_reader as ur

    lo, hi = ur.SEARCH_BOX_A
    path = ur.lawnmower_path((-0.5, 2.5), (-0.3, -0.6), (0.5, 1.5), PASS_POSES)
    rng = np.random.default_rng(5)
    others = rng.uniform([0.2, 0.3, 0.3], [1.8, 2.7, 1.7], (NUM_TAGS - 1, 3))
    tags = np.vstack([np.asarray(TAG0), others]).astype(np.float32)
    offsets = np.concatenate([[OFFSET0], rng.uniform(-math.pi, math.pi, NUM_TAGS - 1)]).astype(np.float32)
    reads = ur.simulate_reads(jax.random.key(0), path, tags, offsets, multipath="light", reads_per_step=J)
    params = rt.default_params(box_lo=lo, box_hi=hi, gamma=ur.LIGHT_MULTIPATH.gamma)
    _CACHE["world"] = jax.block_until_ready((params, reads, tags, offsets))
    return _CACHE["world"]


def tag_reads(g: int | slice):
    """Reads of tag ``g`` (``[T, J]``) or of a slice of tags (``[G, T, J]``)."""
    _, reads, _, _ = world()
    return jax.tree_util.tree_map(lambda x: x[g], reads)


def config(n: int):
    from jaxnav.localization import rfid_tag as rt

    return rt.RFIDTagConfig(num_particles=n, dims=3, weighting="combined", ess_threshold=0.1, refresh=True)


def initial_state(n: int, g: int = 0):
    """jaxnav's initial particles for tag ``g`` (key 1 for tag 0, ``fold_in(key 1, g)`` otherwise)."""
    from jaxnav.localization import rfid_tag as rt

    params = world()[0]
    key = jax.random.key(1) if g == 0 else jax.random.fold_in(jax.random.key(1), g)
    return jax.block_until_ready(rt.init(key, config(n), params))


def _steps() -> int:
    return int(tag_reads(0).mask.shape[0])


def _big(n: int) -> bool:
    return n >= 10**6


# ---------------------------------------------------------------------------
# jaxnav


def _jaxnav_run(ctx: Context, size: dict, n: int, state0, floor_s: float) -> dict:
    from jaxnav.localization import rfid_tag as rt

    params = world()[0]
    reads = tag_reads(0)
    cfg = config(n)
    t_steps = _steps()
    key = jax.random.key(2)
    compile_s = ctx.compile_s((NAME, "run", n), rt.run.jitted, key, state0, cfg, params, reads)
    fn = lambda: jax.block_until_ready(rt.run(key, state0, cfg, params, reads))  # noqa: E731
    _, trace = fn()
    t = time_calls(fn, repeats=ctx.reps(3 if _big(n) else 10), warmup=0, budget_s=60.0, min_repeats=2)
    _CACHE[("run", n)] = t.per(t_steps).median_s
    return make_row(
        NAME,
        "jaxnav",
        size,
        "in_scan",
        t.per(t_steps),
        compile_s=compile_s,
        floor_s=floor_s,
        steps=t_steps,
        reads_per_step=J,
        resamplings=int(np.asarray(trace.resampled).sum()),
        dtype="float32",
        note=f"rfid_tag.run over {t_steps} steps (one lax.scan), time / {t_steps}",
    )


def _jaxnav_run_tags(ctx: Context, size: dict, g: int) -> dict:
    from jaxnav.localization import rfid_tag as rt

    params = world()[0]
    reads = tag_reads(slice(0, g))
    cfg = config(TAG_N)
    states = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *(initial_state(TAG_N, i) for i in range(g)))
    t_steps = _steps()
    key = jax.random.key(2)
    compile_s = ctx.compile_s((NAME, "run_tags", g), rt.run_tags_jitted, key, cfg, params, reads, states)
    fn = lambda: jax.block_until_ready(rt.run_tags(key, cfg, params, reads, states))  # noqa: E731
    _, trace = fn()
    t = time_calls(fn, repeats=ctx.reps(10), warmup=0, budget_s=60.0, min_repeats=3)
    per_step = t.per(t_steps).median_s
    _CACHE[("run_tags", g)] = per_step
    extra = {}
    if g != 1 and ("run_tags", 1) in _CACHE:
        extra["ratio_to_tags_1"] = per_step / _CACHE[("run_tags", 1)]
    if ("run", TAG_N) in _CACHE:
        extra["ratio_to_run"] = per_step / _CACHE[("run", TAG_N)]
    return make_row(
        NAME,
        "jaxnav",
        size,
        "in_scan",
        t.per(t_steps),
        compile_s=compile_s,
        steps=t_steps,
        reads_per_step=J,
        call="run_tags",
        per_tag_s=per_step / g,
        resamplings=int(np.asarray(trace.resampled).sum()),
        valid_read_fraction=float(np.asarray(reads.mask).mean()),
        dtype="float32",
        note=f"rfid_tag.run_tags on {g} tag(s) (vmap of the scan), time / {t_steps} steps for all tags",
        **extra,
    )


# ---------------------------------------------------------------------------
# hand-written plain-JAX baseline (not a peer)


def _baseline_loglik(gain: str = "atan2"):
    """Plain-JAX ``loglik(p [4, N], reads) -> [N]`` of the combined weights, each read's geometry
    written component by component on ``[N, J]``.

    ``gain`` picks how the antenna lobe is found: ``"atan2"`` (``jnp.arctan2`` of the off-boresight
    angle, as jaxnav's model), ``"fastmath"`` (:func:`jaxnav.core.fastmath.atan2`), or ``"cos"``
    (no angle: ``γ ≤ φ ⇔ d·b ≥ D cos φ`` for the horizontal unit boresight ``b`` and ``φ ∈ [0, π]``;
    the profile's what-if, not used by the benchmark row).
    """
    from benchmarks.peers.numpy_uhf import model_from_params
    from jaxnav.core import fastmath

    m = model_from_params(world()[0])
    two_pi = 2.0 * math.pi
    pe = m.tx_power * m.tag_efficiency * m.tag_gain**2
    c_rssi = -math.log(2.0) - m.k * math.log(m.theta) - math.lgamma(m.k)
    c_phase = -math.log(m.phase_sigma) - 0.5 * math.log(two_pi)
    g0, gs, gb = pe * m.g0**2, pe * m.g_sll**2, pe * m.g_bll**2

    def loglik(p, rd):
        reader, y, phi, lam, mask = rd
        rx, ry, rz, psi = (reader[None, :, i] for i in range(4))
        x, yy, z, off = (p[i][:, None] for i in range(4))
        dx, dy, dz = x - rx, yy - ry, z - rz
        d = jnp.sqrt(dx * dx + dy * dy + dz * dz)
        c, s = jnp.cos(psi), jnp.sin(psi)
        dot = dx * c + dy * s
        if gain == "cos":
            coef = jnp.where(dot >= d * math.cos(m.phi_s), g0, jnp.where(dot >= d * math.cos(2 * m.phi_s), gs, gb))
        else:
            lat = dx * s - dy * c
            atan2 = fastmath.atan2 if gain == "fastmath" else jnp.arctan2
            gam = atan2(jnp.sqrt(dz * dz + lat * lat), dot)
            coef = jnp.where(gam <= m.phi_s, g0, jnp.where(gam <= 2 * m.phi_s, gs, gb))
        dcl = jnp.maximum(d, 1e-6)
        inv2 = 1.0 / (dcl * dcl)
        lam_ = lam[None, :]
        loss = jnp.where(dcl < 4 * math.pi * rz * z / lam_, (lam_ / (4 * math.pi)) ** 2 * inv2, (rz * z * inv2) ** 2)
        a = coef * loss * loss
        log_y = jnp.log(jnp.where(mask, y, 1.0))[None, :]
        log_u = 0.5 * (log_y - jnp.log(a))
        lr = jnp.where(a > 0, c_rssi - log_y + m.k * log_u - jnp.exp(log_u) / m.theta, -jnp.inf)
        res = phi[None, :] + 4 * math.pi * d / lam_ - off
        q = lam_ / (4 * math.pi * m.phase_sigma) * (res - two_pi * jnp.round(res * (1.0 / two_pi)))
        return jnp.sum(jnp.where(mask[None, :], lr - 0.5 * q * q + c_phase, 0.0), axis=-1)

    return loglik


def _baseline_fn(n: int, gain: str = "atan2"):
    """A jitted ``run(key, particles [4, N], log_weights [N], reads)`` of the U1 update in plain JAX
    (``gain``: see :func:`_baseline_loglik`; the benchmark row uses ``"atan2"``)."""
    if ("baseline_fn", n, gain) in _CACHE:
        return _CACHE[("baseline_fn", n, gain)]
    from benchmarks.peers.numpy_uhf import model_from_params

    m = model_from_params(world()[0])
    two_pi = 2.0 * math.pi
    lo = jnp.asarray(m.box_lo, jnp.float32)[:, None]
    hi = jnp.asarray(m.box_hi, jnp.float32)[:, None]
    loglik = _baseline_loglik(gain)

    def wrap(a):
        return a - two_pi * jnp.round(a * (1.0 / two_pi))

    def step(carry, inp):
        p, lw = carry
        key, rd = inp
        l = lw + loglik(p, rd)
        l = jnp.where(jnp.isnan(l), -jnp.inf, l)
        top = jnp.max(l)
        l = l - jnp.where(jnp.isfinite(top), top, 0.0)
        e = jnp.exp(l)
        s = jnp.sum(e)
        degenerate = ~(s > 0)
        probs = jnp.where(degenerate, 1.0 / n, e / s)
        l = jnp.where(degenerate, -math.log(n), l - jnp.log(s))
        est = (p @ probs).at[3].set(jnp.arctan2(jnp.sin(p[3]) @ probs, jnp.cos(p[3]) @ probs))
        ess = 1.0 / jnp.sum(probs * probs)
        threshold = jnp.where(jnp.any(rd[4]), 0.1, 0.0)

        def resample():
            k1, k2 = jax.random.split(key)
            cdf = jnp.cumsum(probs)
            cdf = cdf / cdf[-1]
            pts = (jax.random.uniform(k1, ()) + jnp.arange(n, dtype=jnp.float32)) / n
            idx = jnp.minimum(jnp.searchsorted(cdf, pts, side="right"), n - 1)
            q = p[:, idx]
            mu = jnp.mean(q, axis=1)
            mu = mu.at[3].set(jnp.arctan2(jnp.mean(jnp.sin(q[3])), jnp.mean(jnp.cos(q[3]))))
            r = (q - mu[:, None]).at[3].apply(wrap)
            cov = r @ r.T / n + 1e-9 * jnp.eye(4, dtype=jnp.float32)
            new = mu[:, None] + jnp.linalg.cholesky(cov) @ jax.random.normal(k2, (4, n), jnp.float32)
            new = new.at[3].apply(wrap).at[:3].set(jnp.clip(new[:3], lo, hi))
            return new, jnp.full((n,), -math.log(n), jnp.float32)

        resampled = ess < threshold * n
        p, l = jax.lax.cond(resampled, resample, lambda: (p, l))
        return (p, l), (est, ess, resampled)

    @jax.jit
    def run(key, p, lw, reads):
        keys = jax.vmap(lambda t: jax.random.fold_in(key, t))(jnp.arange(reads[4].shape[0]))
        return jax.lax.scan(step, (p, lw), (keys, reads))

    _CACHE[("baseline_fn", n, gain)] = run
    return run


def _baseline_row(ctx: Context, size: dict, n: int, state0, floor_s: float) -> dict:
    run = _baseline_fn(n)
    r = tag_reads(0)
    args = (
        jax.random.key(3),
        state0.particles.T,
        state0.log_weights,
        (r.reader, r.rssi, r.phase, r.wavelength, r.mask),
    )
    t_steps = _steps()
    compile_s = ctx.compile_s((NAME, "baseline", n), run, *args)
    fn = lambda: jax.block_until_ready(run(*args))  # noqa: E731
    _, (_, _, resampled) = fn()
    t = time_calls(fn, repeats=ctx.reps(3 if _big(n) else 10), warmup=0, budget_s=60.0, min_repeats=2)
    return make_row(
        NAME,
        "jax-baseline",
        size,
        "in_scan",
        t.per(t_steps),
        compile_s=compile_s,
        floor_s=floor_s,
        steps=t_steps,
        reads_per_step=J,
        resamplings=int(np.asarray(resampled).sum()),
        dtype="float32",
        note="hand-written plain-JAX lax.scan, [4, N] particles (not a peer; STYLE.md item 14)",
    )


# ---------------------------------------------------------------------------
# NumPy peer


def _numpy_row(ctx: Context, size: dict, n: int, state0, floor_s: float) -> dict:
    from benchmarks.peers import numpy_uhf

    params = world()[0]
    model = numpy_uhf.model_from_params(params)
    r = tag_reads(0)
    reads = tuple(np.asarray(x) for x in (r.reader, r.rssi, r.phase, r.wavelength, r.mask))
    p0 = np.asarray(state0.particles)
    lw0 = np.asarray(state0.log_weights)
    t_steps = _steps()
    pf = numpy_uhf.NumpyRFIDTag(p0, model, lw0, ess_threshold=0.1, seed=7)
    pf.step(tuple(x[0] for x in reads))  # warm-up: allocates the scratch buffers (kept by reset)
    passes = ctx.reps(2 if _big(n) else (3 if n >= 10**5 else 10))
    samples, counts, spent = [], [], 0.0
    with _GcOff():
        for i in range(passes):
            pf.reset(p0, lw0, seed=8 + i)
            t0 = time.perf_counter()
            counts.append(pf.run(reads))
            dt = time.perf_counter() - t0
            samples.append(dt / t_steps)
            spent += dt
            if spent >= 60.0 and len(samples) >= 2:
                break
    t = Timing.from_samples(samples)
    return make_row(
        NAME,
        "numpy",
        size,
        "per_call",
        t,
        floor_s=floor_s,
        steps=t_steps,
        reads_per_step=J,
        resamplings=int(np.median(counts)),
        dtype="float32",
        note=f"NumpyRFIDTag (vectorised NumPy, float32), Python loop over the {t_steps} steps, time / {t_steps}",
    )


# ---------------------------------------------------------------------------


def run(ctx: Context, size: dict) -> list[dict]:
    n = int(size["N"])
    if "tags" in size:
        g = int(size["tags"])
        return guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jaxnav_run_tags(ctx, size, g))
    floor_s = ctx.floor(floor_bytes(n))
    state0 = initial_state(n)
    rows = []
    rows += guarded(ctx, NAME, "jaxnav", size, "in_scan", lambda: _jaxnav_run(ctx, size, n, state0, floor_s))
    rows += guarded(ctx, NAME, "jax-baseline", size, "in_scan", lambda: _baseline_row(ctx, size, n, state0, floor_s))
    rows += guarded(ctx, NAME, "numpy", size, "per_call", lambda: _numpy_row(ctx, size, n, state0, floor_s))
    return rows


register(
    Workload(
        name=NAME,
        title=f"U1 UHF-RFID tag update ([A] Alg. 6, RSSI + phase), J = {J} reads per step (time per step)",
        sizes=[{"N": n} for n in SIZES_N] + [{"N": TAG_N, "tags": g} for g in TAG_COUNTS],
        quick_sizes=[{"N": SIZES_N[0]}] + [{"N": TAG_N, "tags": g} for g in TAG_COUNTS],
        run=run,
        x_key="N",
        floor_doc=FLOOR_DOC,
    )
)


# ---------------------------------------------------------------------------
# part-by-part profile (python -m benchmarks.workloads.u1_uhf_update --profile [--sizes 10000,1000000])


def _min_time(fn, calls: int) -> float:
    fn()
    best = math.inf
    with _GcOff():
        for _ in range(calls):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
    return best


def profile(sizes=(10**4, 10**6), rounds: int = 3) -> list[dict]:
    """Time the parts of one U1 step (tag 0, step 5 of the path) for jaxnav, the plain-JAX baseline and NumPy.

    Parts: jaxnav's jitted step without resampling (``ess_threshold`` 1e-6) and
    its resampling + Gaussian refresh alone (``conditional_resample`` with
    threshold 1) and without the refresh; ``rfid_tag.log_likelihoods``
    (combined, RSSI only, phase only) and the antenna gain alone; normalise +
    estimate + ESS given the log-likelihoods; the baseline's log-likelihood
    with ``jnp.arctan2``, with ``fastmath.atan2`` and with the cosine test of
    the lobe (no angle); NumPy's log-likelihood, step without resampling and
    resampling + refresh. At N = 1e4 also ``run_tags``' parts for G = 10 tags
    (the log-likelihood and the resampling under ``vmap``, where the
    ``lax.cond`` becomes a select). Each entry is the best of ``rounds``
    interleaved rounds of a few calls (the machine is shared).
    """
    from benchmarks.peers import numpy_uhf
    from jaxnav.core import resampling
    from jaxnav.core import weights as W
    from jaxnav.localization import rfid_tag as rt
    from jaxnav.models import uhf_rfid as U

    params = world()[0]
    model = numpy_uhf.model_from_params(params)
    out = []
    for n in sizes:
        calls = 2 if n >= 10**6 else (5 if n >= 10**5 else 20)
        cfg = config(n)
        cfg_nr = rt.RFIDTagConfig(num_particles=n, ess_threshold=1e-6)
        state = initial_state(n)
        r = jax.tree_util.tree_map(lambda x: x[5], tag_reads(0))
        rd = (r.reader, r.rssi, r.phase, r.wavelength, r.mask)
        key = jax.random.key(4)
        pt = jax.block_until_ready(state.particles.T)
        ll = jax.block_until_ready(rt.log_likelihoods(cfg, params, state.particles, r))
        lw = jax.block_until_ready(W.normalize(state.log_weights + ll).log_weights)
        cfg_w = {w: rt.RFIDTagConfig(num_particles=n, weighting=w) for w in ("rssi", "phase")}

        def norm_est(lw0, l, p):
            nrm = W.normalize(lw0 + l)
            probs = jnp.exp(nrm.log_weights)
            return W.mean_from_probabilities(p, probs, (3,)), W.ess_from_probabilities(probs), nrm

        jit = {
            "jaxnav step, no resampling": (jax.jit(lambda k, s: rt.kernel(k, s, cfg_nr, params, r)), (key, state)),
            "jaxnav refresh (rfid_tag.resample)": (
                jax.jit(lambda k, p, w: rt.resample(k, p, w, cfg, params)),
                (key, state.particles, rt.weigh(state, cfg, params, r)),
            ),
            "jaxnav resample, no refresh": (
                jax.jit(
                    lambda k, p, l: resampling.conditional_resample(
                        k, p, l, threshold=1.0, refresh=False, normalized=True
                    )
                ),
                (key, state.particles, lw),
            ),
            "jaxnav log_likelihoods (combined)": (
                jax.jit(lambda p: rt.log_likelihoods(cfg, params, p, r)),
                (state.particles,),
            ),
            "jaxnav log_likelihoods (rssi only)": (
                jax.jit(lambda p: rt.log_likelihoods(cfg_w["rssi"], params, p, r)),
                (state.particles,),
            ),
            "jaxnav log_likelihoods (phase only)": (
                jax.jit(lambda p: rt.log_likelihoods(cfg_w["phase"], params, p, r)),
                (state.particles,),
            ),
            "jaxnav antenna gain alone": (
                jax.jit(
                    lambda p: jnp.sum(
                        U.antenna_gain(
                            p[:, None, :3] - r.reader[None, :, :3], r.reader[None, :, 3], params.channel.antenna, None
                        ),
                        -1,
                    )
                ),
                (state.particles,),
            ),
            "jaxnav normalise + estimate + ESS": (jax.jit(norm_est), (state.log_weights, ll, state.particles)),
            "baseline loglik, jnp.arctan2": (jax.jit(_baseline_loglik("atan2")), (pt, rd)),
            "baseline loglik, fastmath.atan2": (jax.jit(_baseline_loglik("fastmath")), (pt, rd)),
            "baseline loglik, cos test (no angle)": (jax.jit(_baseline_loglik("cos")), (pt, rd)),
        }
        if n == TAG_N:
            g = NUM_TAGS
            rg = jax.tree_util.tree_map(lambda x: x[:, 5], tag_reads(slice(0, g)))
            pg = jnp.stack([initial_state(n, i).particles for i in range(g)])
            keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(g))
            jit[f"vmap {g} tags: log_likelihoods"] = (
                jax.jit(jax.vmap(lambda p, rr: rt.log_likelihoods(cfg, params, p, rr))),
                (pg, rg),
            )
            wg = jax.vmap(lambda p, rr: rt.weigh(rt.RFIDTagState(p, jnp.full((n,), -math.log(n))), cfg, params, rr))(
                pg, rg
            )
            jit[f"{g} tags: lax.map of each tag's refresh"] = (
                jax.jit(lambda k, p, w: jax.lax.map(lambda a: rt.resample(*a, cfg, params), (k, p, w))),
                (keys, pg, wg),
            )
        fns = {}
        for name, (f, args) in jit.items():
            f.lower(*args).compile()
            fns[name] = lambda f=f, args=args: jax.block_until_ready(f(*args))
        p0, lw0 = np.asarray(state.particles), np.asarray(state.log_weights)
        rn = tuple(np.asarray(x) for x in rd)
        pf = numpy_uhf.NumpyRFIDTag(p0, model, lw0, ess_threshold=0.0)
        probs = np.exp(np.asarray(lw))

        def np_step():
            pf.reset(p0, lw0)
            pf.step(rn)

        fns["numpy log-likelihood"] = lambda: pf.log_likelihoods(rn)
        fns["numpy step, no resampling"] = np_step
        est = (pf.p @ probs).astype(pf.dtype)
        fns["numpy refresh"] = lambda: pf._refresh(probs, est, None)
        best = {k: math.inf for k in fns}
        for _ in range(rounds):
            for k, f in fns.items():
                best[k] = min(best[k], _min_time(f, calls))
        for k, v in best.items():
            out.append({"N": n, "part": k, "seconds": v})
            print(f"N={n:>8}  {k:<58} {v * 1e3:9.2f} ms", flush=True)
        print(flush=True)
    return out


if __name__ == "__main__":
    import argparse

    from benchmarks import harness

    ap = argparse.ArgumentParser(description="U1: part-by-part profile of one update")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--sizes", default="10000,1000000")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=None, help="also write the parts as JSON (with machine and versions)")
    a = ap.parse_args()
    if a.profile:
        with harness.CpuMonitor() as mon:
            parts = profile(tuple(int(s) for s in a.sizes.split(",")), a.rounds)
        if a.out:
            harness.write_json(
                a.out,
                {
                    "machine": harness.machine_info({}),
                    "versions": harness.versions(),
                    "other_load_cores": mon.other_cores,
                    "parts": parts,
                    "command": "python -m benchmarks.workloads.u1_uhf_update --profile "
                    f"--sizes {a.sizes} --rounds {a.rounds}",
                },
            )
