"""Tests of jaxnav.core.batch.monte_carlo: chunking, per-run slicing, progress, compilation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import batch as B

R = 7  # not divisible by 2, 3, 4, 5 or 6: every chunk size but 1 and 7 leaves a ragged last chunk


def _fn(key, x, extra):
    """A per-run computation using the key and two per-run arguments (one a pytree)."""
    k1, k2 = jax.random.split(key)
    return {
        "u": jax.random.uniform(k1, (3,)),
        "z": jax.random.normal(k2, ()) + x,
        "x": x,
        "pair": (extra["a"] * 2.0, extra["b"]),
    }


def _args():
    x = jnp.arange(R, dtype=jnp.float32) * 10.0
    extra = {"a": jnp.arange(2 * R, dtype=jnp.float32).reshape(R, 2), "b": jnp.arange(R, dtype=jnp.int32)}
    return x, extra


def _assert_trees_equal(a, b):
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(x, y)


def test_results_do_not_depend_on_chunk_size(getkey):
    """Run r always receives ``run_keys(key, R)[r]`` and the r-th slice of the
    arguments, so chunk sizes 1, 3 (ragged: 3 + 3 + 1), R and > R (capped at R)
    give identical outputs, with or without jit."""
    key = getkey()
    x, extra = _args()
    reference = B.monte_carlo(_fn, key, R, x, extra)  # one chunk of R
    for chunk in (1, 3, R + 5):
        _assert_trees_equal(B.monte_carlo(_fn, key, R, x, extra, chunk_size=chunk), reference)
    _assert_trees_equal(B.monte_carlo(_fn, key, R, x, extra, chunk_size=3, jit=False), reference)


def test_leading_axis_and_per_run_slicing(getkey):
    """Outputs are NumPy arrays with leading axis R; row r is ``fn(key_r, args[r])``."""
    key = getkey()
    x, extra = _args()
    out = B.monte_carlo(_fn, key, R, x, extra, chunk_size=3)
    for leaf in jax.tree_util.tree_leaves(out):
        assert isinstance(leaf, np.ndarray) and leaf.shape[0] == R
    assert out["u"].shape == (R, 3) and out["z"].shape == (R,)
    np.testing.assert_array_equal(out["x"], x)
    np.testing.assert_array_equal(out["pair"][0], 2.0 * np.asarray(extra["a"]))
    np.testing.assert_array_equal(out["pair"][1], extra["b"])
    keys = B.run_keys(key, R)
    np.testing.assert_array_equal(keys, jax.random.split(key, R))
    single = jax.jit(_fn)
    for r in (0, 3, R - 1):
        one = single(keys[r], x[r], jax.tree_util.tree_map(lambda a: a[r], extra))
        np.testing.assert_allclose(out["u"][r], one["u"], rtol=1e-6)
        np.testing.assert_allclose(out["z"][r], one["z"], rtol=1e-6)
    # Different runs got different keys.
    assert len({tuple(row) for row in out["u"].tolist()}) == R


def test_no_run_args(getkey):
    out = B.monte_carlo(lambda k: jax.random.uniform(k), getkey(), 5, chunk_size=2)
    assert isinstance(out, np.ndarray) and out.shape == (5,)
    assert len(set(out.tolist())) == 5


@pytest.mark.parametrize(("chunk", "expected"), [(3, [3, 6, 7]), (1, list(range(1, R + 1))), (R, [R]), (100, [R])])
def test_progress_called_once_per_chunk(chunk, expected, getkey):
    calls = []
    B.monte_carlo(
        lambda k: jax.random.uniform(k), getkey(), R, chunk_size=chunk, progress=lambda d, t: calls.append((d, t))
    )
    assert calls == [(d, R) for d in expected]


def test_compiles_once_with_ragged_last_chunk(getkey):
    """``fn`` is traced exactly once for R = 7 in chunks of 3 (3 + 3 + 1 padded to 3):
    one trace by ``vmap`` inside the single ``jit``, reused for every chunk.
    The counter is a Python side effect, so it counts traces, not calls."""
    traces = []

    def fn(key, x):
        traces.append(1)
        return x + jax.random.uniform(key)

    x = jnp.arange(R, dtype=jnp.float32)
    calls = []
    out = B.monte_carlo(fn, getkey(), R, x, chunk_size=3, progress=lambda d, t: calls.append(d))
    assert out.shape == (R,)
    assert len(calls) == 3  # three chunks were evaluated ...
    assert len(traces) == 1  # ... by one compiled function


@pytest.mark.parametrize("num_runs", [0, -3, 2.5, "4", True])
def test_rejects_nonpositive_num_runs(num_runs, getkey):
    """Not a positive integer: refused (2.5 silently ran 2 runs)."""
    with pytest.raises(ValueError, match="num_runs"):
        B.monte_carlo(lambda k: k, getkey(), num_runs)


@pytest.mark.parametrize("chunk", [0, -1, 2.5])
def test_rejects_nonpositive_chunk_size(chunk, getkey):
    with pytest.raises(ValueError, match="chunk_size"):
        B.monte_carlo(lambda k: k, getkey(), 4, chunk_size=chunk)


def test_rejects_mismatched_run_args(getkey):
    with pytest.raises(ValueError, match="leading axis"):
        B.monte_carlo(lambda k, x: x, getkey(), 5, jnp.zeros(4))
    # One bad leaf in a pytree argument is enough.
    with pytest.raises(ValueError, match=r"run_args\[1\]"):
        B.monte_carlo(lambda k, x, y: x, getkey(), 5, jnp.zeros(5), {"ok": jnp.zeros((5, 2)), "bad": jnp.zeros((2, 5))})
    # A scalar argument has no leading axis at all.
    with pytest.raises(ValueError, match="leading axis"):
        B.monte_carlo(lambda k, x: x, getkey(), 5, jnp.float32(1.0))


def test_compiled_vmap_shared_args_and_map_mode_agree_with_a_loop(getkey):
    """``shared`` arrays reach every row whole; ``mode="map"`` gives exactly what ``"vmap"`` gives,
    and both equal a Python loop of ``fn`` (same keys)."""

    def fn(key, scale, offset):
        return {"v": scale * jax.random.uniform(key, (2,)) + offset["o"], "s": jnp.sum(offset["o"])}

    keys = jax.random.split(getkey(), 5)
    scale, offset = jnp.float32(3.0), {"o": jnp.arange(2.0)}
    by_vmap = B.compiled_vmap(fn, keys, shared=(scale, offset))(keys, scale, offset)
    by_map = B.compiled_vmap(fn, keys, shared=(scale, offset), mode="map")(keys, scale, offset)
    loop = [fn(k, scale, offset) for k in keys]
    np.testing.assert_allclose(by_vmap["v"], np.stack([o["v"] for o in loop]), rtol=1e-6)
    np.testing.assert_allclose(by_map["v"], np.stack([o["v"] for o in loop]), rtol=1e-6)
    np.testing.assert_array_equal(by_map["s"], np.full(5, 1.0))


def test_compiled_vmap_shares_one_executable_across_shared_values(getkey):
    """Other values of the shared arrays (same shapes) reuse the executable; other shapes or
    another mode compile anew."""
    fn = lambda key, h: h * jax.random.uniform(key)  # noqa: E731
    keys = jax.random.split(getkey(), 3)
    a = B.compiled_vmap(fn, keys, shared=(jnp.float32(1.0),))
    assert B.compiled_vmap(fn, keys, shared=(jnp.float32(2.0),)) is a
    np.testing.assert_allclose(a(keys, jnp.float32(2.0)), 2.0 * a(keys, jnp.float32(1.0)), rtol=1e-6)
    assert B.compiled_vmap(fn, keys, shared=(jnp.float32(1.0),), mode="map") is not a
    assert B.compiled_vmap(fn, keys, shared=(jnp.ones(2),)) is not a
    with pytest.raises(ValueError, match="mode"):
        B.compiled_vmap(fn, keys, mode="pmap")
