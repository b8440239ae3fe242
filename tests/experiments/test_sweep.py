"""Resumable batch Monte Carlo (jaxnav.experiments.sweep); the intervals are tested in test_stats.py."""

from __future__ import annotations

import json
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.core import batch
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
    data["sha256"] = sw._checksum(data)  # written by that code: its checksum matches
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


_LAPACK_SWEEP = """
import jax, jax.numpy as jnp
from jaxnav.experiments import sweep as sw

def cholesky_loop(key):  # 12,500 Cholesky factors of 3 x 3 matrices per run, 300 times
    y = jax.random.normal(key, (12_500, 3))
    def body(c, _):
        return c + jnp.linalg.cholesky(y[:, :, None] * y[:, None, :] + (3.0 + c) * jnp.eye(3)).sum() * 1e-9, None
    return {"total": jax.lax.scan(body, 0.0, None, length=300)[0]}

out = sw.sweep([("a", cholesky_loop), ("b", cholesky_loop)], 4, jax.random.PRNGKey(0), None, 2, False, workers=2)
print("done", sorted(out))
"""


def test_programs_that_call_lapack_run_one_at_a_time_and_finish():
    """Two chunks of a program that factorises 25,000 small matrices at a time, started together from two
    worker threads, hang XLA:CPU (jax 0.10.2; :func:`jaxnav.core.batch.calls_lapack`): the sweep runs
    such chunks one at a time and finishes (in a child process, which a hang would not leave: the
    test fails at its timeout instead). ``calls_lapack`` tells the programs apart."""
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-c", _LAPACK_SWEEP], capture_output=True, text=True, timeout=240, check=False
    )
    assert proc.returncode == 0 and "done ['a', 'b']" in proc.stdout, proc.stderr[-2000:]
    x = jnp.ones((4, 3, 3)) + 3 * jnp.eye(3)
    assert batch.calls_lapack(jax.jit(jnp.linalg.cholesky).lower(x).compile())
    assert not batch.calls_lapack(jax.jit(jnp.sin).lower(x).compile())


# ---------------------------------------------------------------------------
# chunk widths: a run is bit for bit the same whenever its chunk has the same width


def _bits(result):
    return {c: {f: (v.dtype.str, v.shape, v.tobytes()) for f, v in fields.items()} for c, fields in result.items()}


def test_a_resume_with_another_chunk_size_is_refused(tmp_path):
    """The checkpoint records the chunk width; resuming it with a chunk size that would compute chunks of
    another width is refused (naming both sizes, the file and the ways on); with the same size it gives
    the uninterrupted sweep's bits."""
    key = jax.random.PRNGKey(6)
    path = str(tmp_path / "runs.json")
    uninterrupted = sw.sweep(_cells(), 6, key, chunk_size=2, progress=False)

    def stop(cell, done):
        if cell == "shifted":
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sw.sweep(_cells(), 6, key, path, chunk_size=2, progress=False, on_chunk=stop)
    assert json.load(open(path))["chunk_size"] == 2
    before = open(path).read()
    with pytest.raises(ValueError) as err:
        sw.sweep(_cells(), 6, key, path, chunk_size=3, progress=False)
    message = str(err.value)
    assert path in message and "chunks of 2" in message and "chunks of 3" in message
    assert "--chunk 2" in message and "--fresh" in message and "\n" not in message
    assert open(path).read() == before  # a refused checkpoint is left as it was
    resumed = sw.sweep(_cells(), 6, key, path, chunk_size=2, progress=False)
    assert _bits(resumed) == _bits(uninterrupted)
    other = sw.sweep(_cells(), 6, key, path, chunk_size=3, progress=False, fresh=True)
    assert json.load(open(path))["chunk_size"] == 3 and other["noisy"]["a"].shape == (6,)


def test_a_longer_sweep_extends_a_shorter_one_chunk_by_chunk(tmp_path):
    """R = 5 in chunks of 3, then R = 9: the chunk holding runs 3–5 is evaluated again (the same keys at
    the same places), so the 9 runs are bit for bit those of a 9-run sweep; a complete checkpoint is read
    whatever the chunk size (nothing is evaluated), and a shorter sweep reads its first runs."""
    key = jax.random.PRNGKey(7)
    path = str(tmp_path / "runs.json")
    sw.sweep(_cells(), 5, key, path, chunk_size=3, progress=False)
    seen = []
    longer = sw.sweep(_cells(), 9, key, path, chunk_size=3, progress=False, on_chunk=lambda c, d: seen.append((c, d)))
    assert seen == [("noisy", 6), ("noisy", 9), ("shifted", 6), ("shifted", 9)]
    assert _bits(longer) == _bits(sw.sweep(_cells(), 9, key, chunk_size=3, progress=False))
    assert _bits(sw.sweep(_cells(), 9, key, path, chunk_size=7, progress=False)) == _bits(longer)
    shorter = sw.sweep(_cells(), 4, key, path, chunk_size=1, progress=False)
    assert all(np.array_equal(shorter[c]["a"], longer[c]["a"][:4]) for c in shorter)


def test_a_sweep_shorter_than_a_chunk_keeps_its_width(tmp_path):
    """R = 3 with the default 25 runs per chunk computes one chunk of 3 (no padding); extending it to 6 runs
    with 25 would compute a chunk of 6, so it is refused, and works with --chunk 3. A checkpoint of chunks of
    4 resumed with chunk size 4 for 2 runs evaluates a whole chunk of 4: the runs of the checkpoint's width."""
    key = jax.random.PRNGKey(8)
    path = str(tmp_path / "runs.json")
    sw.sweep(_cells(), 3, key, path, progress=False)
    assert json.load(open(path))["chunk_size"] == 3
    with pytest.raises(ValueError, match=r"chunks of 3 .* chunks of 6 \(--chunk 25 with --runs 6\).*--chunk 3"):
        sw.sweep(_cells(), 6, key, path, progress=False)
    assert _bits(sw.sweep(_cells(), 6, key, path, chunk_size=3, progress=False)) == _bits(
        sw.sweep(_cells(), 6, key, chunk_size=3, progress=False)
    )

    padded = str(tmp_path / "padded.json")
    with pytest.raises(KeyboardInterrupt):
        sw.sweep(_cells(), 8, key, padded, chunk_size=4, progress=False, on_chunk=_interrupt_at("shifted"))
    two = sw.sweep(_cells(), 2, key, padded, chunk_size=4, progress=False)
    full = sw.sweep(_cells(), 8, key, chunk_size=4, progress=False)
    assert _bits(two) == _bits({c: {f: v[:2] for f, v in fields.items()} for c, fields in full.items()})


def _interrupt_at(cell_id):
    def stop(cell, done):
        if cell == cell_id:
            raise KeyboardInterrupt

    return stop


def test_non_finite_runs_are_written_as_null_and_read_as_nan(tmp_path):
    """A run that returns NaN or ±inf is stored as null (standard JSON, no NaN literal) and comes back as
    NaN, from the checkpoint and without one alike; integers and booleans keep their type."""

    class Mixed(NamedTuple):
        x: jax.Array
        n: jax.Array
        ok: jax.Array

    def fn(key):
        r = jax.random.uniform(key)
        x = jnp.where(r < 0.3, jnp.nan, jnp.where(r > 0.8, jnp.inf, r))
        return Mixed(x, jnp.int32(3), r > 0.5)

    key = jax.random.PRNGKey(9)
    path = str(tmp_path / "runs.json")
    first = sw.sweep([("c", fn)], 12, key, path, chunk_size=4, progress=False)
    text = open(path).read()
    assert "NaN" not in text and "Infinity" not in text and "null" in text
    stored = json.loads(text)["cells"]["c"]
    x = first["c"]["x"]
    assert [v is None for v in stored["x"]] == (~np.isfinite(x)).tolist() and np.isnan(x).sum() >= 2
    assert not np.any(np.isinf(x)) and first["c"]["n"].dtype.kind == "i" and first["c"]["ok"].dtype == bool
    assert _bits(sw.sweep([("c", fn)], 12, key, path, chunk_size=4, progress=False)) == _bits(first)
    assert _bits(sw.sweep([("c", fn)], 12, key, chunk_size=4, progress=False)) == _bits(first)
