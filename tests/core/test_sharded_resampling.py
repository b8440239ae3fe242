"""Resampling particles spread over four devices: the unsharded ancestors, exactly.

The checks run in a child process with four CPU devices (``--xla_force_host_platform_device_count``,
read once when JAX starts); the suite's own process has one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxnav.core import sharded
from tests import child_process

_CHILD = r"""
import functools, json
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, PartitionSpec as P
from jaxnav.core import resampling, sharded

mesh = Mesh(np.array(jax.devices()), ("particles",))
assert mesh.size == 4

@functools.lru_cache(None)
def spread(num_samples, scheme, logs):
    fn = sharded.resample if logs else sharded.resample_weights
    body = lambda key, w: fn(key, w, num_samples, "particles", scheme)
    return jax.jit(jax.shard_map(body, mesh=mesh, in_specs=(P(), P("particles")), out_specs=P("particles")))

@functools.lru_cache(None)
def whole(num_samples, scheme, logs):
    if logs:
        return jax.jit(lambda key, lw: getattr(resampling, scheme)(key, lw, num_samples))
    return jax.jit(lambda key, w: resampling.resample_weights(key, w, num_samples, scheme))

rng = np.random.default_rng(0)
def weight_cases(n):
    lognormal = np.exp(rng.normal(size=n) * 3).astype(np.float32)
    one = np.zeros(n, np.float32); one[n // 3] = 1.0
    holes = lognormal * (rng.random(n) < 0.5)
    wide = np.exp(np.clip(rng.normal(size=n) * 40, -80, 80)).astype(np.float32)
    subnormal = np.where(rng.random(n) < 0.5, np.float32(1e-45), np.float32(3e-45)) * (rng.random(n) < 0.8)
    return {"lognormal": lognormal, "one": one, "holes": holes, "zero": np.zeros(n, np.float32),
            "equal": np.ones(n, np.float32), "wide": wide, "subnormal": subnormal.astype(np.float32)}

out = {"trials": 0, "mismatches": [], "take": [], "logs": []}
for n in (40, 4100, 16384):
    for name, w in weight_cases(n).items():
        for m in (n, n // 8 * 4):  # M = N, and about N / 2 (a multiple of the four devices)
            for scheme in ("systematic", "stratified"):
                for k in range(2):
                    key = jax.random.PRNGKey(100 * k + n)
                    ref = np.asarray(whole(m, scheme, False)(key, jnp.asarray(w)))
                    got = np.asarray(spread(m, scheme, False)(key, jnp.asarray(w)))
                    out["trials"] += 1
                    if not np.array_equal(ref, got):
                        out["mismatches"].append([n, name, m, scheme, k, int(np.sum(ref != got))])
    # from log-weights where exp is exact (0 and -inf): the unsharded scheme's ancestors
    one = np.where(np.arange(n) == n // 3, 0.0, -np.inf).astype(np.float32)
    for name, lw in {"equal": np.zeros(n, np.float32), "one": one}.items():
        key = jax.random.PRNGKey(n)
        same = np.array_equal(np.asarray(whole(n, "systematic", True)(key, jnp.asarray(lw))),
                              np.asarray(spread(n, "systematic", True)(key, jnp.asarray(lw))))
        out["logs"].append([n, name, same])

# take: each device's slots get the rows their ancestors name, whichever device holds them
def moved(key, lw, parts, tags):
    a = sharded.resample(key, lw, lw.shape[0] * 4, "particles")
    return sharded.take((parts, tags), a, "particles"), a
step = jax.jit(jax.shard_map(moved, mesh=mesh, in_specs=(P(), P("particles"), P("particles"), P("particles")),
                             out_specs=((P("particles"), P("particles")), P("particles"))))
for n, lw in ((4096, rng.normal(size=4096) * 3), (40, np.where(np.arange(40) == 37, 0.0, -np.inf))):
    parts = np.arange(2 * n, dtype=np.float32).reshape(n, 2)
    tags = np.arange(n, dtype=np.int32)
    (p, t), a = step(jax.random.PRNGKey(1), jnp.asarray(lw, jnp.float32), jnp.asarray(parts), jnp.asarray(tags))
    a = np.asarray(a)
    out["take"].append([n, bool(np.array_equal(np.asarray(p), parts[a]) and np.array_equal(np.asarray(t), tags[a])),
                        bool(np.all(np.diff(a) >= 0)), int(a.min()), int(a.max())])
try:
    spread(6, "systematic", False)(jax.random.PRNGKey(0), jnp.ones(40))
except ValueError as err:
    out["uneven"] = str(err)
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def four_devices() -> dict:
    return child_process.run(_CHILD, devices=4, timeout=600)


def test_spread_weights_give_the_unsharded_ancestors_exactly(four_devices):
    """N = 40, 4100 (blocks of 1025: not whole rows of 1024) and 16384; M = N and about N / 2; systematic and
    stratified; lognormal weights, one positive weight, half zeros, all zero, all equal, weights over
    70 decades, and subnormal weights: 336 resamplings, every ancestor the unsharded one."""
    assert four_devices["trials"] == 3 * 7 * 2 * 2 * 2
    assert four_devices["mismatches"] == []


def test_spread_log_weights_give_the_unsharded_ancestors_where_exp_is_exact(four_devices):
    """From log-weights all 0, or one 0 and the rest −inf (where every exp is exact), the ancestors are
    those of ``resampling.systematic``; elsewhere the two programs may round an exp differently
    (the module docstring of :mod:`jaxnav.core.sharded`)."""
    assert [same for *_, same in four_devices["logs"]] == [True] * 6


def test_take_fetches_every_slot_from_the_device_that_holds_it(four_devices):
    """4 × 1024 particles of two leaves resampled to 4 × 4096 slots, and 40 particles of which only the
    38th may be drawn: every slot holds its ancestor's rows, the ancestors sorted and in range."""
    (wide, wide_ok, wide_sorted, low, high), single = four_devices["take"]
    assert wide == 4096 and wide_ok and wide_sorted and 0 <= low <= high < 4096
    assert single == [40, True, True, 37, 37]


def test_other_schemes_and_uneven_samples_are_refused(four_devices):
    """The multinomial scheme is refused by name (on this process's one device), and 6 samples over four
    devices are refused naming ``num_samples``."""
    mesh = Mesh(jax.devices()[:1], ("particles",))

    @jax.jit
    def call(w):
        body = lambda v: sharded.resample_weights(jax.random.PRNGKey(0), v, 4, "particles", "multinomial")  # noqa: E731
        return jax.shard_map(body, mesh=mesh, in_specs=P("particles"), out_specs=P("particles"))(w)

    with pytest.raises(ValueError, match="multinomial"):
        call(jnp.ones(4))
    assert "num_samples (6)" in four_devices["uneven"]
