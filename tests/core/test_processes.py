"""A sweep under ``jax.distributed``: two processes on the loopback write what one process writes."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from jaxnav.core import processes
from tests import child_process

_SWEEP = r"""
import json, sys
import jax, jax.numpy as jnp, numpy as np
from jaxnav.core import processes
from jaxnav.experiments import sweep as sw

address, count, rank, path = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
if count > 1:
    processes.initialize(address, count, rank)

def noisy(key, scale):  # a small filter-like run: a random walk scored against its start
    steps = jax.random.normal(key, (200, 2)) * scale
    path = jnp.cumsum(steps, axis=0)
    return {"end_m": jnp.linalg.norm(path[-1]), "max_m": jnp.max(jnp.linalg.norm(path, axis=1)), "first": path[0]}

cells = [("calm", noisy, (jnp.float32(0.1),)), ("wild", noisy, (jnp.float32(1.0),))]
for runs in (6, 10):  # the second sweep resumes the first's checkpoint and extends it
    out = sw.sweep(cells, runs, jax.random.PRNGKey(7), path, chunk_size=2, progress=False)
bits = {c: {f: np.asarray(v).tobytes().hex() for f, v in fields.items()} for c, fields in out.items()}
print("RESULT " + json.dumps({"devices": len(jax.devices()), "bits": bits}), flush=True)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(count: int, rank: int, path: str, address: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", _SWEEP, address, str(count), str(rank), path],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )


def _result(proc: subprocess.Popen) -> dict:
    try:
        out, err = proc.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == 0, err[-3000:]
    return child_process.result(out)


def test_two_processes_write_the_checkpoint_one_process_writes(tmp_path):
    """A two-cell sweep of 6 runs, then extended to 10 from its checkpoint: in one process, and in two
    processes of one CPU device each under ``jax.distributed`` (Gloo on the loopback). Both processes
    return the one-process runs, bit for bit, and process 0 writes the same checkpoint, byte for byte;
    the other writes nothing."""
    alone = _result(_start(1, 0, str(tmp_path / "alone.json"), ""))
    address = f"127.0.0.1:{_free_port()}"
    # each process is given its own path: process 0 reads and writes its checkpoint for both
    paths = [tmp_path / "first.json", tmp_path / "second.json"]
    procs = [_start(2, rank, str(paths[rank]), address) for rank in (0, 1)]
    first, second = (_result(p) for p in procs)
    assert alone["devices"] == 1 and first["devices"] == second["devices"] == 2
    assert first["bits"] == alone["bits"] and second["bits"] == alone["bits"]
    assert paths[0].read_text() == (tmp_path / "alone.json").read_text()
    assert not paths[1].exists()


@pytest.mark.parametrize(("count", "rank"), [(0, None), (True, None), (2, 2), (2, -1)])
def test_bad_process_layouts_are_refused_by_name(count, rank):
    with pytest.raises(ValueError, match="num_processes|process_id"):
        processes.initialize("127.0.0.1:1", count, rank)


def test_one_process_is_the_first_and_shares_its_text():
    assert processes.is_first()
    assert processes.share_text("checkpoint") == "checkpoint" and processes.share_text(None) is None


def _cli(args: list[str], cwd) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "jaxnav", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )


def test_the_cli_under_two_processes_writes_and_prints_once(tmp_path):
    """``jaxnav experiments run`` with ``--coordinator``, ``--num-processes`` and ``--process-id``: process
    0 prints the table and writes the JSON of a one-process run, byte for byte; process 1 prints nothing
    and writes nothing in its own folder."""
    run = ["experiments", "run", "table-5.2", "--quick", "--runs", "2", "--chunk", "1", "--no-progress"]
    alone = _cli([*run, "--out", "alone"], tmp_path)
    out_alone, err = alone.communicate(timeout=240)
    assert alone.returncode == 0, err[-3000:]
    address = f"127.0.0.1:{_free_port()}"
    procs = [
        _cli(
            [*run, "--out", folder, "--coordinator", address, "--num-processes", "2", "--process-id", str(rank)],
            tmp_path,
        )
        for rank, folder in enumerate(("first", "second"))
    ]
    outs = [p.communicate(timeout=240) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs[0][1][-2000:] + outs[1][1][-2000:]
    # Gloo, the CPU processes' transport, prints a line of its own when it connects
    printed = [[line for line in out.splitlines() if not line.startswith("[Gloo]")] for out, _ in outs]
    assert printed[0][1:] == [line.replace("alone", "first") for line in out_alone.splitlines()[1:]]
    assert printed[1] == [] and not (tmp_path / "second").exists()
    for ext in (".json", ".runs.json", ".md"):
        stem = "table-5.2.quick" + ext
        assert (tmp_path / "first" / stem).read_bytes() == (tmp_path / "alone" / stem).read_bytes()


@pytest.mark.parametrize("flag", [["--num-processes", "0"], ["--process-id", "-1"]])
def test_the_cli_refuses_a_bad_process_layout(flag, tmp_path):
    proc = _cli(["experiments", "run", "table-3.1", "--quick", *flag], tmp_path)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and flag[0] in err and "Traceback" not in err
