"""Break jaxnav's W2 step (``mcl.kernel``) into its parts and time each part.

``python -m benchmarks.profile_w2 [--sizes 1000,1000000] [--repeats K] [--out FILE]``

Every part is its own small jitted function of the W2 inputs, timed two ways:

* ``per_call``: one jitted call, median over repeats (includes ~10–30 µs of
  dispatch, which matters only at small N);
* ``in_scan``: the part run ``S = 20`` times inside one ``lax.scan`` whose
  ``xs`` carry a fresh key and a perturbed input per iteration (so XLA cannot
  hoist the work out of the loop), time / S.

Parts (in the order of ``mcl.kernel``):

``motion``       ``velocity_sample`` (arc motion + pose noise)
``likelihood``   ``landmarks.lookup`` + ``landmarks.log_likelihood`` (8 landmarks)
``normalize``    ``weights.normalize(lw + loglik)`` (logsumexp, guards)
``estimate``     ``weights.particle_mean`` (weighted mean, circular θ)
``ess``          ``weights.ess``
``resample``     ``resampling.conditional_resample`` (normalises and ESS again,
                 ``lax.cond``, ``systematic`` + gather)
``systematic``   ``resampling.systematic`` alone (indices only)
``gather``       ``jnp.take(particles, idx, axis=0)`` alone
``step``         the whole ``mcl.kernel``

and, to explain ``motion``:

``normal_threefry``  one ``jax.random.normal(key, (N, 3))`` with the default
                     threefry key (``velocity_sample`` draws two of these)
``normal_jaxnav``    the same numbers from :func:`jaxnav.core.rng.normal` (what
                     the motion models draw)
``normal_rbg``       the same draw with an ``impl="rbg"`` key

The sum of motion … resample should be close to ``step``; the largest part
is where to optimise. ``--numpy`` also splits the NumPy peer's step (move,
weigh = likelihood + normalise + ESS, indices, gather) for a side-by-side.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp

from benchmarks.harness import fmt_time, time_calls

S = 20


def _parts(n: int):
    from benchmarks.workloads.w2_mcl import INIT_SD, START, _world
    from jaxnav.core import resampling, rng, weights
    from jaxnav.localization import mcl
    from jaxnav.models import landmarks as lm
    from jaxnav.models.motion import velocity_sample

    landmarks, motion_noise, sensor_noise, sim = _world()
    config = mcl.MCLConfig(num_particles=n, motion_model="velocity", resampling="systematic", ess_threshold=1.0)
    params = mcl.MCLParams(motion_noise, sensor_noise, landmarks)
    state = mcl.init(
        jax.random.key(1), config, params, jnp.asarray(START, jnp.float32), jnp.asarray(INIT_SD, jnp.float32)
    )
    ctrl = sim.controls[0]
    obs = jax.tree_util.tree_map(lambda a: a[0], sim.observations)
    x = state.particles
    pos, valid, _ = lm.lookup(landmarks, obs)
    ll = lm.log_likelihood(x, pos, obs.z, valid, sensor_noise)
    lw = weights.normalize(state.log_weights + ll).log_weights
    idx = resampling.systematic(jax.random.key(5), lw, n)

    # each part: f(key, x, lw, idx) -> array
    parts = {
        "motion": lambda k, x, lw, idx: velocity_sample(k, x, ctrl, motion_noise),
        "likelihood": lambda k, x, lw, idx: _lik(lm, landmarks, obs, sensor_noise, x),
        "normalize": lambda k, x, lw, idx: weights.normalize(lw + ll).log_weights,
        "estimate": lambda k, x, lw, idx: weights.particle_mean(x, lw, (2,)),
        "ess": lambda k, x, lw, idx: weights.ess(lw),
        "resample": lambda k, x, lw, idx: resampling.conditional_resample(k, x, lw, 1.0, "systematic").particles,
        "systematic": lambda k, x, lw, idx: resampling.systematic(k, lw, n),
        "gather": lambda k, x, lw, idx: jnp.take(x, idx, axis=0),
        "step": lambda k, x, lw, idx: mcl.kernel(k, mcl.MCLState(x, lw), config, params, ctrl, obs)[0].particles,
        "normal_threefry": lambda k, x, lw, idx: jax.random.normal(k, x.shape, x.dtype),
        "normal_jaxnav": lambda k, x, lw, idx: rng.normal(k, x.shape, x.dtype),
        "normal_rbg": lambda k, x, lw, idx: jax.random.normal(
            jax.random.key(jax.random.bits(k, (), jnp.uint32), impl="rbg"), x.shape, x.dtype
        ),
    }
    return parts, (x, lw, idx)


def _lik(lm, landmarks, obs, sensor_noise, x):
    pos, valid, _ = lm.lookup(landmarks, obs)
    return lm.log_likelihood(x, pos, obs.z, valid, sensor_noise)


def profile(n: int, repeats: int) -> dict:
    parts, (x, lw, idx) = _parts(n)
    out = {}
    for name, f in parts.items():
        per_call = jax.jit(f)
        keys = iter(list(jax.random.split(jax.random.key(7), repeats + 4)))
        jax.block_until_ready(per_call(next(keys), x, lw, idx))
        t_call = time_calls(
            lambda: jax.block_until_ready(per_call(next(keys), x, lw, idx)), repeats=repeats, warmup=1, budget_s=10.0
        )

        def scanned(key, xs_x, xs_lw):
            def body(c, inp):
                i, xi, lwi = inp
                r = f(jax.random.fold_in(key, i), xi, lwi, idx)
                return c + jnp.sum(r).astype(jnp.float32), None

            c, _ = jax.lax.scan(body, jnp.float32(0), (jnp.arange(S), xs_x, xs_lw))
            return c

        g = jax.jit(scanned)
        eps = jnp.arange(S, dtype=x.dtype)[:, None, None] * 1e-6
        xs_x = jax.block_until_ready(x[None] + eps)
        xs_lw = jax.block_until_ready(lw[None] + eps[:, :, 0])
        jax.block_until_ready(g(jax.random.key(8), xs_x, xs_lw))
        t_scan = time_calls(
            lambda: jax.block_until_ready(g(jax.random.key(8), xs_x, xs_lw)),
            repeats=max(3, repeats // 5),
            warmup=0,
            budget_s=20.0,
        )
        out[name] = {"per_call_s": t_call.median_s, "in_scan_s": t_scan.median_s / S}
        del xs_x, xs_lw
    return out


def profile_numpy(n: int, repeats: int) -> dict:
    """The NumPy peer's step split the same way: move, weigh (likelihood + normalise + ESS),
    indices (systematic), gather (``x[idx]`` for the three arrays)."""
    from benchmarks.peers.numpy_mcl import NumpyMCL
    from benchmarks.workloads.w2_mcl import POSE_SD, SENSOR_SD, _initial_state, _peer_inputs

    x0, lm, controls, zs = _peer_inputs(_initial_state(n))
    pf = NumpyMCL(x0, lm, POSE_SD, SENSOR_SD, seed=7)
    pf.step(controls[0], zs[0])
    w, _, _ = pf.weigh(zs[1])
    idx = pf.indices(w)
    x, y, th = pf.x.copy(), pf.y.copy(), pf.th.copy()

    def reset():
        pf.x, pf.y, pf.th = x.copy(), y.copy(), th.copy()

    def gather():
        pf.resample(idx)
        reset()

    parts = {
        "move": lambda: pf.move(controls[1]),
        "weigh": lambda: pf.weigh(zs[1]),
        "indices": lambda: pf.indices(w),
        "gather+reset": gather,
        "step": lambda: pf.step(controls[1], zs[1]),
    }
    out = {}
    for name, f in parts.items():
        out[name] = {"per_call_s": time_calls(f, repeats=repeats, warmup=1, budget_s=10.0).median_s}
        reset()
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.profile_w2")
    p.add_argument("--sizes", default="1000,10000,100000,1000000")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--out", default=None, help="optional JSON file")
    p.add_argument("--numpy", action="store_true", help="also split the NumPy peer's step into its parts")
    a = p.parse_args(argv)
    from benchmarks.harness import CpuMonitor, import_all_jaxnav, jaxnav_source_state

    import_all_jaxnav()
    print(f"jaxnav {jaxnav_source_state()}")
    result = {}
    for n in [int(float(s)) for s in a.sizes.split(",")]:
        t0 = time.perf_counter()
        with CpuMonitor() as mon:
            r = profile(n, a.repeats)
        result[n] = r
        print(f"N={n}  ({time.perf_counter() - t0:.0f} s, other processes {mon.other_cores} cores)")
        print(f"  {'part':<16} {'per_call':>12} {'in_scan':>12}")
        for name, v in r.items():
            print(f"  {name:<16} {fmt_time(v['per_call_s']):>12} {fmt_time(v['in_scan_s']):>12}")
        if a.numpy:
            with CpuMonitor() as mon:
                r_np = profile_numpy(n, a.repeats)
            result[f"numpy_{n}"] = r_np
            print(f"  NumPy peer (float32), other processes {mon.other_cores} cores")
            for name, v in r_np.items():
                print(f"  {name:<16} {fmt_time(v['per_call_s']):>12}")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
