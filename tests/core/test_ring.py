"""Tests of jaxnav.core.ring against a plain Python list model.

The model of a ring of capacity ``L`` after pushes ``x_1 … x_k`` is the list
``[x_1, …, x_k][-L:]``. Every ring query must agree with the same query on
that list; unwritten slots must hold zeros (never NaN).
"""

from __future__ import annotations

from functools import partial

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

from jaxnav.core import ring as Rg

EPS32 = float(np.finfo(np.float32).eps)
CAPACITIES = [1, 3, 5]
ITEM_SHAPE = (2,)

# One compilation per capacity for each operation (items have a fixed shape).
_push = jax.jit(Rg.ring_push)


@partial(jax.jit, static_argnames="last")
def _queries(ring, last=None):
    return dict(
        ordered=Rg.ring_ordered(ring),
        mask=Rg.ring_valid_mask(ring),
        latest=Rg.ring_latest(ring),
        mean=Rg.ring_mean(ring, last),
        count=ring.count,
        head=ring.head,
    )


def _push_all(ring, items):
    for x in items:
        ring = _push(ring, jnp.asarray(x))
    return ring


def _expected(items, capacity, last=None):
    """The list model: the last ``capacity`` items, oldest first."""
    kept = list(items)[-capacity:] if items else []
    window = kept[-min(last, capacity) :] if last is not None else kept
    k = len(kept)
    ordered = np.zeros((capacity,) + ITEM_SHAPE)
    if k:
        ordered[capacity - k :] = np.asarray(kept)
    return dict(
        ordered=ordered,
        mask=np.arange(capacity) >= capacity - k,
        latest=np.asarray(items[-1]) if items else np.zeros(ITEM_SHAPE),
        mean=np.mean(np.asarray(window, np.float64), axis=0) if window else np.zeros(ITEM_SHAPE),
        count=k,
        head=len(items) % capacity,
    )


def _assert_matches(got, want, scale):
    np.testing.assert_array_equal(got["ordered"], want["ordered"].astype(np.float32))
    np.testing.assert_array_equal(got["mask"], want["mask"])
    np.testing.assert_array_equal(got["latest"], want["latest"].astype(np.float32))
    assert int(got["count"]) == want["count"]
    assert int(got["head"]) == want["head"]
    # Mean of ≤ 5 float32 values: a few ulps of the largest magnitude.
    np.testing.assert_allclose(got["mean"], want["mean"], rtol=0, atol=8 * EPS32 * max(1.0, scale))
    assert not np.any(np.isnan(np.asarray(got["ordered"])))


@st.composite
def push_sequences(draw):
    capacity = draw(st.sampled_from(CAPACITIES))
    length = draw(st.integers(0, 2 * capacity))
    items = draw(
        st.lists(
            hnp.arrays(np.float32, ITEM_SHAPE, elements=st.floats(-1e3, 1e3, width=32)),
            min_size=length,
            max_size=length,
        )
    )
    last = draw(st.none() | st.integers(1, capacity + 2))
    return capacity, items, last


@settings(max_examples=50, deadline=None)
@given(push_sequences())
def test_ring_matches_list_model(case):
    """After any push sequence of length 0…2L, every query equals the list model's,
    including ``ring_mean(last=k)`` (``k`` may exceed L: it is capped)."""
    capacity, items, last = case
    ring = _push_all(Rg.ring_init(capacity, ITEM_SHAPE), items)
    scale = max((float(np.abs(x).max()) for x in items), default=1.0)
    _assert_matches(_queries(ring, last), _expected(items, capacity, last), scale)
    # Rows outside the valid mask are unwritten zeros.
    got = _queries(ring)
    assert np.all(np.asarray(got["ordered"])[~np.asarray(got["mask"])] == 0.0)


@pytest.mark.parametrize("capacity", CAPACITIES)
def test_every_prefix_matches_list_model(capacity):
    """Check the model after *every* push of a 2L+1 sequence (wrap-around included)."""
    items = [np.array([i + 1.0, -(i + 1.0)], np.float32) for i in range(2 * capacity + 1)]
    ring = Rg.ring_init(capacity, ITEM_SHAPE)
    _assert_matches(_queries(ring), _expected([], capacity), 1.0)
    for k, x in enumerate(items, start=1):
        ring = _push(ring, jnp.asarray(x))
        for last in (None, 1, capacity):
            _assert_matches(_queries(ring, last), _expected(items[:k], capacity, last), 2.0 * k)


def test_ring_mean_last_window():
    ring = _push_all(Rg.ring_init(5), [jnp.float32(v) for v in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)])
    # Kept: 2, 4, 8, 16, 32 (1 was overwritten).
    assert float(Rg.ring_mean(ring)) == pytest.approx(62.0 / 5)
    assert float(Rg.ring_mean(ring, last=1)) == 32.0
    assert float(Rg.ring_mean(ring, last=2)) == 24.0
    assert float(Rg.ring_mean(ring, last=99)) == pytest.approx(62.0 / 5)
    with pytest.raises(ValueError):
        Rg.ring_mean(ring, last=0)
    # An empty ring has mean zero, not NaN.
    assert float(Rg.ring_mean(Rg.ring_init(3))) == 0.0


def test_scan_push_equals_python_loop():
    """Pushing inside ``lax.scan`` (under jit) gives the same ring as a Python loop."""
    capacity = 3
    xs = jnp.arange(14, dtype=jnp.float32).reshape(7, 2)

    @jax.jit
    def scanned(xs):
        def body(ring, x):
            ring = Rg.ring_push(ring, x)
            return ring, Rg.ring_mean(ring)

        return jax.lax.scan(body, Rg.ring_init(capacity, ITEM_SHAPE), xs)

    ring, means = scanned(xs)
    looped = _push_all(Rg.ring_init(capacity, ITEM_SHAPE), list(np.asarray(xs)))
    for a, b in zip(ring, looped):
        np.testing.assert_array_equal(a, b)
    items = list(np.asarray(xs))
    want = [_expected(items[: k + 1], capacity)["mean"] for k in range(len(items))]
    np.testing.assert_allclose(means, np.asarray(want), rtol=1e-6)


def test_batch_of_rings_under_vmap():
    """A batch of rings (one per particle) is a vmap of the single-ring functions;
    rings at different fill levels answer independently."""
    capacity, batch = 3, 4
    rings = []
    sequences = []
    for b in range(batch):  # ring b has received b + 1 pushes
        seq = [np.array([10.0 * b + i, -1.0 * i], np.float32) for i in range(b + 1)]
        sequences.append(seq)
        rings.append(_push_all(Rg.ring_init(capacity, ITEM_SHAPE), seq))
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *rings)
    got = jax.jit(jax.vmap(lambda r: _queries.__wrapped__(r, 2)))(stacked)
    for b in range(batch):
        want = _expected(sequences[b], capacity, 2)
        _assert_matches(jax.tree_util.tree_map(lambda x: x[b], got), want, 40.0)

    # vmapped push of one item per ring, from a vmapped init.
    empty = jax.vmap(lambda _: Rg.ring_init(capacity, ITEM_SHAPE))(jnp.arange(batch))
    items = jnp.arange(2 * batch, dtype=jnp.float32).reshape(batch, 2)
    pushed = jax.jit(jax.vmap(Rg.ring_push))(empty, items)
    np.testing.assert_array_equal(pushed.count, np.ones(batch))
    np.testing.assert_array_equal(jax.vmap(Rg.ring_latest)(pushed), items)
    assert pushed.data.shape == (batch, capacity, 2)


@pytest.mark.parametrize("capacity", [0, -1])
def test_ring_init_rejects_nonpositive_capacity(capacity):
    with pytest.raises(ValueError, match="capacity"):
        Rg.ring_init(capacity)


def test_ring_init_shape_and_dtype():
    ring = Rg.ring_init(4, (3,), jnp.int32)
    assert ring.data.shape == (4, 3) and ring.data.dtype == jnp.int32
    assert ring.capacity == 4
    assert int(ring.head) == 0 and int(ring.count) == 0
    assert ring.head.dtype == jnp.int32 and ring.count.dtype == jnp.int32
