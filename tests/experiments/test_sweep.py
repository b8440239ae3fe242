"""Resumable batch Monte Carlo (jaxnav.experiments.sweep); the intervals are tested in test_stats.py."""

from __future__ import annotations

import json
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.experiments import sweep as sw


class Out(NamedTuple):
    a: jax.Array
    b: jax.Array


def _cells():
    def noisy(key):
        return Out(jax.random.normal(key), jnp.sum(jax.random.uniform(key, (3,))))

    def shifted(key):
        return Out(10.0 + jax.random.normal(key), jnp.zeros(()))

    return [("noisy", noisy), ("shifted", shifted)]


def test_runs_do_not_depend_on_chunking_or_on_the_number_of_runs():
    key = jax.random.PRNGKey(0)
    full = sw.sweep(_cells(), 7, key, chunk_size=3, progress=False)
    other = sw.sweep(_cells(), 7, key, chunk_size=7, progress=False)
    prefix = sw.sweep(_cells(), 4, key, chunk_size=2, progress=False)
    for cell in ("noisy", "shifted"):
        np.testing.assert_array_equal(full[cell]["a"], other[cell]["a"])
        np.testing.assert_array_equal(full[cell]["a"][:4], prefix[cell]["a"])
    assert np.all(full["shifted"]["a"] > 5) and len(set(full["noisy"]["a"].tolist())) == 7


def test_an_interrupted_sweep_resumes_to_the_same_result(tmp_path):
    key = jax.random.PRNGKey(1)
    path = str(tmp_path / "runs.json")
    uninterrupted = sw.sweep(_cells(), 6, key, chunk_size=2, progress=False)

    calls = []

    def stop_after_four_chunks(cell, done):
        calls.append(cell)
        if len(calls) == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sw.sweep(_cells(), 6, key, path, chunk_size=2, progress=False, on_chunk=stop_after_four_chunks)
    saved = json.load(open(path))["cells"]
    assert len(saved["noisy"]["a"]) == 6 and len(saved["shifted"]["a"]) == 2  # finished chunks are kept

    seen = []
    resumed = sw.sweep(_cells(), 6, key, path, chunk_size=2, progress=False, on_chunk=lambda c, d: seen.append((c, d)))
    assert seen == [("shifted", 4), ("shifted", 6)]  # only the missing chunks ran
    for cell in ("noisy", "shifted"):
        for field in ("a", "b"):
            np.testing.assert_array_equal(resumed[cell][field], uninterrupted[cell][field])


def test_a_checkpoint_of_another_sweep_is_refused(tmp_path):
    path = str(tmp_path / "runs.json")
    sw.sweep(_cells(), 2, jax.random.PRNGKey(0), path, progress=False)
    with pytest.raises(ValueError, match="other settings"):
        sw.sweep(_cells(), 2, jax.random.PRNGKey(5), path, progress=False)
    with pytest.raises(ValueError, match="unique"):
        sw.sweep(_cells() + _cells()[:1], 2, jax.random.PRNGKey(0), progress=False)


def test_cells_with_shared_args_and_map_batching():
    """A ``(id, fn, shared)`` cell gets its arrays after the key; ``batching="map"`` gives the runs
    ``"vmap"`` gives; a short sweep is not padded to a whole chunk (R = 3 with chunk 25)."""

    def fn(key, level):
        return Out(level + jax.random.normal(key), jnp.zeros(()))

    cells = [("low", fn, (jnp.float32(0.0),)), ("high", fn, (jnp.float32(100.0),))]
    key = jax.random.PRNGKey(3)
    by_vmap = sw.sweep(cells, 3, key, progress=False)
    by_map = sw.sweep(cells, 3, key, progress=False, batching="map")
    for c in ("low", "high"):
        np.testing.assert_allclose(by_map[c]["a"], by_vmap[c]["a"], rtol=1e-6)
        assert by_vmap[c]["a"].shape == (3,)
    # the same key per run, shifted by the cell's level (cell keys differ by id, so compare the spread)
    assert np.all(by_vmap["high"]["a"] > 90.0) and np.all(np.abs(by_vmap["low"]["a"]) < 10.0)
    with pytest.raises(ValueError, match="batching"):
        sw.sweep(cells, 3, key, progress=False, batching="pmap")


def test_workers_change_nothing_but_the_speed(tmp_path):
    """Chunks run concurrently are saved in chunk order: the numbers and the checkpoint are those of one worker."""
    key = jax.random.PRNGKey(4)
    one, two = str(tmp_path / "one.json"), str(tmp_path / "two.json")
    serial = sw.sweep(_cells(), 7, key, one, chunk_size=2, progress=False, workers=1)
    seen = []
    parallel = sw.sweep(
        _cells(), 7, key, two, chunk_size=2, progress=False, workers=3, on_chunk=lambda c, d: seen.append((c, d))
    )
    assert seen == [
        ("noisy", 2),
        ("noisy", 4),
        ("noisy", 6),
        ("noisy", 7),
        ("shifted", 2),
        ("shifted", 4),
        ("shifted", 6),
        ("shifted", 7),
    ]
    for cell in ("noisy", "shifted"):
        for field in ("a", "b"):
            np.testing.assert_array_equal(parallel[cell][field], serial[cell][field])
    assert json.load(open(one)) == json.load(open(two))
    with pytest.raises(ValueError, match="workers"):
        sw.sweep(_cells(), 2, key, progress=False, workers=0)
    assert sw.default_workers() >= 1


def test_fresh_discards_a_checkpoint_instead_of_resuming_it(tmp_path):
    path = str(tmp_path / "runs.json")
    key = jax.random.PRNGKey(0)
    first = sw.sweep(_cells(), 3, key, path, progress=False)
    data = json.load(open(path))
    data["cells"]["noisy"]["a"] = [99.0, 99.0, 99.0]  # what a stale checkpoint from older code would hold
    json.dump(data, open(path, "w"))
    assert np.all(sw.sweep(_cells(), 3, key, path, progress=False)["noisy"]["a"] == 99.0)  # resumed as is
    again = sw.sweep(_cells(), 3, key, path, progress=False, fresh=True)
    np.testing.assert_array_equal(again["noisy"]["a"], first["noisy"]["a"])
    assert json.load(open(path))["cells"]["noisy"]["a"] == first["noisy"]["a"].tolist()
    # a checkpoint of another version is refused, and fresh=True overrides that too
    data = json.load(open(path))
    data["meta"]["jaxnav"] = "0.0.0"
    json.dump(data, open(path, "w"))
    with pytest.raises(ValueError, match="fresh"):
        sw.sweep(_cells(), 3, key, path, progress=False)
    sw.sweep(_cells(), 3, key, path, progress=False, fresh=True)


def test_threads_asking_for_one_executable_compile_it_once():
    import threading

    from jaxnav.core.batch import compiled_vmap

    traces = []

    def fn(key):
        traces.append(1)  # runs once per trace
        return jax.random.normal(key)

    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    exes = []
    threads = [threading.Thread(target=lambda: exes.append(compiled_vmap(fn, keys))) for _ in range(4)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    assert len(traces) == 1 and all(e is exes[0] for e in exes)
