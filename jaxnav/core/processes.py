"""Many processes, one study: ``jax.distributed`` for :func:`~jaxnav.core.batch.monte_carlo` and sweeps.

Under ``jax.distributed`` every process of a job runs the same program (JAX's multi-controller
model): the same script, the same arguments. ``jax.devices()`` then lists the devices of every
process, and a chunk per device of all of them is one call (:func:`jaxnav.core.batch.compiled_vmap`):
each process computes the keys of the whole call, places its own devices' blocks, and receives
every block's results (:class:`AcrossProcesses`). So every process holds the same results, bit for
bit those of one process with as many devices, and only the first process (:func:`is_first`)
writes files and draws progress.

:func:`initialize` starts the runtime: with no arguments JAX reads the job from the environment
(SLURM, Open MPI, and the other clusters ``jax.distributed.initialize`` knows); the coordinator's
address, the number of processes and this process's id can be given instead. On CPUs the
processes exchange values through Gloo (``jax_cpu_collectives_implementation``).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

__all__ = ["initialize", "is_first", "spans_processes", "share_text", "AcrossProcesses"]


def initialize(
    coordinator_address: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> None:
    """Join this process to a ``jax.distributed`` job (before anything uses a device).

    ``coordinator_address`` (``"host:port"`` of process 0), ``num_processes`` and ``process_id``
    default to what JAX reads from the environment (SLURM, Open MPI, …). CPU processes exchange
    values through Gloo.
    """
    if num_processes is not None and (isinstance(num_processes, bool) or int(num_processes) < 1):
        raise ValueError(f"num_processes must be a positive integer, got {num_processes!r}")
    if process_id is not None and num_processes is not None and not 0 <= int(process_id) < int(num_processes):
        raise ValueError(f"process_id must be in [0, {num_processes}), got {process_id!r}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address, num_processes, process_id)


def is_first() -> bool:
    """Whether this is process 0 of the job (always, without ``jax.distributed``): the one that writes."""
    return jax.process_index() == 0


def spans_processes(devices: Any) -> bool:
    """Whether ``devices`` include another process's."""
    return any(d.process_index != jax.process_index() for d in devices)


def share_text(text: str | None) -> str | None:
    """Process 0's ``text`` in every process (``None`` travels too); without ``jax.distributed``, ``text``.

    Every process must call it at the same point (a collective): the others' ``text`` is ignored.
    """
    if jax.process_count() == 1:
        return text
    from jax.experimental import multihost_utils

    data = np.frombuffer(b"" if text is None else text.encode("utf-8"), np.uint8)
    header = np.asarray([text is not None, data.size], np.int64)
    header = np.asarray(multihost_utils.broadcast_one_to_all(header))
    if not header[0]:
        return None
    padded = np.zeros(int(header[1]), np.uint8)
    if is_first():
        padded[:] = data
    return bytes(np.asarray(multihost_utils.broadcast_one_to_all(padded))).decode("utf-8")


def _global(value: Any, sharding: Any) -> jax.Array:
    """The global array of ``sharding`` whose blocks are those of ``value`` (the same in every process)."""
    if jax.dtypes.issubdtype(getattr(value, "dtype", np.float32), jax.dtypes.prng_key):
        data = _global(jax.random.key_data(value), sharding)
        return jax.random.wrap_key_data(data, impl=jax.random.key_impl(value))
    host = np.asarray(value)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index], dtype=host.dtype)


class AcrossProcesses:
    """A compiled program over the devices of several processes, called like a one-process one.

    Its arguments are host values, the same in every process; each process places its own
    devices' blocks of them (``shardings``: one per argument) and gets the whole result back as
    NumPy arrays (``process_allgather``). Other attributes are the executable's.
    """

    def __init__(self, exe: Any, shardings: tuple):
        self.exe, self.shardings = exe, shardings

    def __call__(self, *args: Any) -> Any:
        from jax.experimental import multihost_utils

        placed = [
            jax.tree_util.tree_map(lambda x, s=sharding: _global(x, s), arg)
            for arg, sharding in zip(args, self.shardings)
        ]
        return multihost_utils.process_allgather(self.exe(*placed), tiled=True)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.exe, name)
