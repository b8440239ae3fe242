"""Timing, machine description, memory bandwidth, result rows and the terminal table.

Timing protocol
---------------
* Every JAX function is compiled before it is timed. Compile time is measured
  on its own as the wall time of ``jax.jit(f).lower(*args).compile()`` (trace +
  lower + XLA compile) and reported as ``compile_s``; it is never part of
  ``median_s``.
* After at least one untimed warm-up call, each timed call is
  ``jax.block_until_ready(f(...))`` (NumPy peers are synchronous), timed with
  ``time.perf_counter`` with the garbage collector off (as ``timeit`` does).
* ``median_s`` is the median of the timed calls; ``min_s`` and ``repeats`` are
  recorded beside it.
* Slow implementations are capped by a time budget: timing stops once the
  budget is spent and ``min_repeats`` calls have been timed.

Floors
------
``floor_s = bytes that must move once / bandwidth``, the bandwidth being
measured in the same run by :func:`measure_bandwidth` (a copy of a 256 MiB
float64 NumPy array: bytes read + bytes written over the best time); in a
preset run (``--preset``) by :func:`measure_device_bandwidth` on JAX's device.
"""

from __future__ import annotations

import contextlib
import gc
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Timing",
    "time_calls",
    "time_compile",
    "Context",
    "make_row",
    "skipped_row",
    "guarded",
    "measure_bandwidth",
    "measure_device_bandwidth",
    "device_info",
    "machine_info",
    "versions",
    "write_json",
    "format_table",
]


# ---------------------------------------------------------------------------
# timing


@dataclass(frozen=True)
class Timing:
    """Result of a timing loop (seconds)."""

    median_s: float
    min_s: float
    repeats: int

    @staticmethod
    def from_samples(samples: Sequence[float]) -> Timing:
        if not samples:
            raise ValueError("no timing samples")
        return Timing(float(statistics.median(samples)), float(min(samples)), len(samples))

    def per(self, steps: int) -> Timing:
        """The timing of one of ``steps`` steps that each timed call made (median and minimum divided)."""
        return Timing(self.median_s / steps, self.min_s / steps, self.repeats)


class _GcOff:
    def __enter__(self):
        self._was = gc.isenabled()
        gc.collect()
        gc.disable()

    def __exit__(self, *exc):
        if self._was:
            gc.enable()


def time_calls(
    fn: Callable[[], Any],
    *,
    repeats: int,
    warmup: int = 1,
    budget_s: float | None = None,
    min_repeats: int = 3,
) -> Timing:
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` calls.

    ``fn`` must block until its result is ready (wrap JAX calls in
    ``jax.block_until_ready``). With ``budget_s``, timing stops early once the
    timed calls have used the budget and at least ``min_repeats`` were made.
    """
    for _ in range(warmup):
        fn()
    samples: list[float] = []
    with _GcOff():
        spent = 0.0
        while len(samples) < repeats:
            t0 = time.perf_counter()
            fn()
            dt = time.perf_counter() - t0
            samples.append(dt)
            spent += dt
            if budget_s is not None and len(samples) >= min_repeats and spent >= budget_s:
                break
    return Timing.from_samples(samples)


PLAIN_NOTE = ", with jax.random, jnp trigonometry and jnp.cumsum instead of the CPU fast paths"
"""What a ``jaxnav-plain`` row's note adds to its ``jaxnav`` twin's."""


@contextlib.contextmanager
def plain_forms():
    """Inside: jaxnav's CPU fast paths give way to plain JAX (:func:`jaxnav.core.fastmath.use_plain_forms`).

    For the ``jaxnav-plain`` rows, which time the same filter with ``jax.random``, ``jnp.sin``/``cos``,
    ``jnp.arctan2`` and ``jnp.cumsum`` beside the ``jaxnav`` row, so that each machine shows what the fast
    paths buy there. JAX's caches are cleared on entry and exit (the switch is read when tracing).
    """
    import jax

    from jaxnav.core import fastmath

    fastmath.use_plain_forms(True)
    jax.clear_caches()
    try:
        yield
    finally:
        fastmath.use_plain_forms(False)
        jax.clear_caches()


def time_compile(jitted: Any, *args: Any, **kwargs: Any) -> tuple[float, Any]:
    """Wall time of ``jitted.lower(*args, **kwargs).compile()`` and the compiled executable."""
    t0 = time.perf_counter()
    compiled = jitted.lower(*args, **kwargs).compile()
    return time.perf_counter() - t0, compiled


# ---------------------------------------------------------------------------
# rows


def make_row(
    workload: str,
    implementation: str,
    size: dict,
    mode: str,
    timing: Timing | None = None,
    *,
    median_s: float | None = None,
    compile_s: float | None = None,
    floor_s: float | None = None,
    **extra: Any,
) -> dict:
    """One measurement row (the row format of ``benchmarks/README.md``).

    Required keys: ``workload, implementation, size, mode, median_s``;
    ``compile_s`` and ``floor_s`` where they apply. Extra keys (``min_s``,
    ``repeats``, ``dtype``, ``note``, …) are informative.
    """
    if mode not in ("per_call", "in_scan"):
        raise ValueError(f"mode must be 'per_call' or 'in_scan', got {mode!r}")
    row: dict[str, Any] = {
        "workload": workload,
        "implementation": implementation,
        "size": dict(size),
        "mode": mode,
        "median_s": timing.median_s if timing is not None else median_s,
    }
    if compile_s is not None:
        row["compile_s"] = compile_s
    if floor_s is not None:
        row["floor_s"] = floor_s
    if timing is not None:
        row["min_s"] = timing.min_s
        row["repeats"] = timing.repeats
    row.update(extra)
    return row


def skipped_row(workload: str, implementation: str, size: dict, mode: str, reason: str, **extra: Any) -> dict:
    """A row recording that a measurement was not made, and why."""
    row = {
        "workload": workload,
        "implementation": implementation,
        "size": dict(size),
        "mode": mode,
        "median_s": None,
        "skipped": reason,
    }
    row.update(extra)
    return row


def guarded(
    ctx: Context, workload: str, implementation: str, size: dict, mode: str, fn: Callable[[], Any]
) -> list[dict]:
    """Measure one implementation: ``fn()`` (a row or a list of rows), guarded and monitored.

    * An exception becomes one skipped row carrying the error: one
      implementation failing (a peer bug, out of memory at the largest size)
      must not lose the other implementations' rows of that size.
    * The CPU used by other processes meanwhile is recorded on every row
      (``other_load_cores``). Above ``ctx.disturbed`` cores the measurement is
      repeated (``ctx.retries`` times, after waiting for the machine to be
      quiet) and the least disturbed attempt is kept (``attempt`` says which).
    * An implementation the run leaves out (:meth:`Context.wants`, a preset's
      ``implementations``) gives no row at all and ``fn`` is not called.
    """
    if not ctx.wants(implementation):
        return []
    best: tuple[list[dict], float | None] | None = None
    for attempt in range(1 + ctx.retries):
        if attempt > 0:
            wait_for_quiet(ctx.retry_wait_s)
        failed = False
        with CpuMonitor() as mon:
            try:
                out = fn()
                rows = list(out) if isinstance(out, (list, tuple)) else [out]
            except Exception as exc:
                import traceback

                traceback.print_exc()
                rows = [skipped_row(workload, implementation, size, mode, f"error: {type(exc).__name__}: {exc}")]
                failed = True
        load = mon.other_cores
        for r in rows:
            r["other_load_cores"] = load
            r["attempt"] = attempt + 1
        if best is None or (load is not None and (best[1] is None or load < best[1])):
            best = (rows, load)
        if failed or load is None or load <= ctx.disturbed:
            break
        last = attempt == ctx.retries
        ctx.note(
            f"{workload} {size_label(size)} {implementation} {mode}: other processes kept {load:.2f} cores busy "
            f"(attempt {attempt + 1}); " + ("kept the least disturbed attempt" if last else "measuring again")
        )
    return best[0]


@dataclass
class Context:
    """What every workload receives: run options, the measured bandwidth and a logger.

    Attributes:
        quick: ``--quick`` was given.
        repeats: ``--repeats K`` (None: each workload's default).
        bandwidth: bytes/s measured at the start of the run.
        retries: re-measurements of an implementation disturbed by other processes.
        retry_wait_s: longest wait for a quiet machine before a re-measurement.
        disturbed: cores used by other processes above which a measurement is disturbed.
        notes: free-text notes collected during the run (written to the JSON).
        implementations: the implementations measured (None: all); the others give no row.
        sizes: the sizes this run measures, per workload name (set by ``benchmarks.run``; empty: each
            workload's own ``sizes_for(quick)``).
    """

    quick: bool
    repeats: int | None
    bandwidth: float
    retries: int = 1
    retry_wait_s: float = 300.0
    disturbed: float = 0.2
    notes: list[str] = field(default_factory=list)
    implementations: frozenset[str] | None = None
    sizes: dict[str, list[dict]] = field(default_factory=dict)
    _compile_times: dict = field(default_factory=dict, repr=False)

    def compile_s(self, key: Any, jitted: Any, *args: Any, **kwargs: Any) -> float:
        """Compile time of ``jitted`` at ``args`` (:func:`time_compile`), measured once per ``key``.

        A re-measurement (see :func:`guarded`) or a second row sharing the
        executable would otherwise find it in JAX's cache and report ~0 s.
        """
        if key not in self._compile_times:
            self._compile_times[key], _ = time_compile(jitted, *args, **kwargs)
        return self._compile_times[key]

    def wants(self, implementation: str) -> bool:
        """Whether this run measures ``implementation`` (every one unless ``implementations`` is set)."""
        return self.implementations is None or implementation in self.implementations

    def sizes_of(self, workload: Any) -> list[dict]:
        """The sizes this run measures for ``workload`` (a :class:`benchmarks.workloads.Workload`)."""
        return list(self.sizes.get(workload.name) or workload.sizes_for(self.quick))

    def reps(self, default: int) -> int:
        """Number of timed repeats: ``--repeats`` if given, else ``default``."""
        return self.repeats if self.repeats is not None else default

    def floor(self, nbytes: float) -> float:
        """Seconds to move ``nbytes`` once at the measured bandwidth."""
        return float(nbytes) / self.bandwidth

    def log(self, msg: str) -> None:
        print(msg, flush=True)

    def note(self, msg: str) -> None:
        if msg not in self.notes:
            self.notes.append(msg)
            self.log(f"  note: {msg}")


# ---------------------------------------------------------------------------
# other processes' CPU use (the benchmark machine is shared)


def _system_busy_and_self() -> tuple[float, float]:
    """(CPU-seconds all cores spent busy since boot, CPU-seconds this process used)."""
    tick = os.sysconf("SC_CLK_TCK")
    with open("/proc/stat") as f:
        fields = [int(v) for v in f.readline().split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    busy = sum(fields[:8]) - idle  # user nice system idle iowait irq softirq steal
    with open("/proc/self/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    own = int(parts[11]) + int(parts[12])  # utime + stime (all threads)
    return busy / tick, own / tick


class CpuMonitor:
    """Average number of cores kept busy by *other* processes while a block ran.

    ``(system busy CPU-seconds − this process's CPU-seconds) / wall seconds``
    from ``/proc/stat`` and ``/proc/self/stat``; ``None`` where /proc is
    missing. Above ~0.2 the timings of that block are likely disturbed.
    """

    def __enter__(self):
        try:
            self._start = _system_busy_and_self()
        except (OSError, ValueError, IndexError):
            self._start = None
        self._t0 = time.perf_counter()
        self.other_cores = None
        return self

    def __exit__(self, *exc):
        wall = time.perf_counter() - self._t0
        if self._start is None or wall <= 0:
            return
        try:
            busy, own = _system_busy_and_self()
        except (OSError, ValueError, IndexError):
            return
        self.other_cores = round(max(0.0, ((busy - self._start[0]) - (own - self._start[1])) / wall), 3)


def wait_for_quiet(max_wait_s: float, threshold: float = 0.15, window_s: float = 3.0) -> float | None:
    """Wait (at most ``max_wait_s``) until other processes use < ``threshold`` cores for ``window_s``.

    Returns the last measured load of other processes (cores), None without /proc.
    """
    deadline = time.perf_counter() + max_wait_s
    load = None
    while True:
        with CpuMonitor() as mon:
            time.sleep(window_s)
        load = mon.other_cores
        if load is None or load < threshold or time.perf_counter() >= deadline:
            return load
        print(f"  machine busy ({load:.2f} cores used by other processes); waiting …", flush=True)


# ---------------------------------------------------------------------------
# machine and versions


def measure_bandwidth(nbytes: int = 256 * 2**20, repeats: int = 7) -> dict:
    """Copy bandwidth of a large float64 NumPy array: (bytes read + bytes written) / best time.

    ``np.copyto`` is single-threaded; both buffers are touched before timing
    so no page fault lands in the timed copies.
    """
    n = nbytes // 8
    src = np.ones(n, dtype=np.float64)
    dst = np.zeros(n, dtype=np.float64)
    samples = []
    with _GcOff():
        for _ in range(repeats):
            t0 = time.perf_counter()
            np.copyto(dst, src)
            samples.append(time.perf_counter() - t0)
    best = min(samples)
    moved = 2 * n * 8
    return {
        "bandwidth_bytes_per_s": moved / best,
        "bandwidth_GB_per_s": moved / best / 1e9,
        "method": f"np.copyto of a {n * 8 / 2**20:.0f} MiB float64 array, (read + write) / best of {repeats}",
        "copy_best_s": best,
        "copy_median_s": float(statistics.median(samples)),
    }


def measure_device_bandwidth(nbytes: int | None = None, repeats: int = 10) -> dict:
    """Memory bandwidth of JAX's default device, measured with jitted passes over a large float32 array.

    ``copy``: ``x + 1`` (reads and writes the array: 2 · ``nbytes`` moved), ``reduce``: ``sum(x)``
    (reads it once); each compiled, called twice untimed, then timed ``repeats`` times with
    ``block_until_ready``; bytes moved / best time. ``nbytes`` defaults to 1 GiB on an accelerator
    (so that one call lasts long against its launch, ~10 µs) and 256 MiB on a CPU. The copy's
    bandwidth is the one the run's floors use (``bandwidth_bytes_per_s``).
    """
    import jax
    import jax.numpy as jnp

    device = jax.devices()[0]
    if nbytes is None:
        nbytes = 256 * 2**20 if device.platform == "cpu" else 2**30
    n = nbytes // 4
    x = jax.block_until_ready(jnp.ones((n,), jnp.float32))
    passes = {
        "copy": (jax.jit(lambda a: a + 1.0), 2 * n * 4),
        "reduce": (jax.jit(lambda a: jnp.sum(a)), n * 4),
    }
    out: dict = {}
    for name, (fn, moved) in passes.items():
        best = time_calls(lambda fn=fn, x=x: jax.block_until_ready(fn(x)), repeats=repeats, warmup=2).min_s
        out[f"{name}_GB_per_s"] = moved / best / 1e9
        out[f"{name}_best_s"] = best
    del x
    return {
        "bandwidth_bytes_per_s": out["copy_GB_per_s"] * 1e9,
        "bandwidth_GB_per_s": out["copy_GB_per_s"],
        **out,
        "method": (
            f"measured: jitted x + 1 (read + write) and sum(x) (read) of a {n * 4 / 2**20:.0f} MiB float32 array "
            f"on {device.platform}:{device.id}, bytes moved / best of {repeats} after 2 warm-up calls"
        ),
    }


def device_info() -> dict:
    """JAX's default device: ``kind`` (``device_kind``), ``platform``, the number of devices and, where
    ``memory_stats()`` reports it, ``memory_bytes``: the allocator's ``bytes_limit`` (on a GPU JAX
    preallocates 75 % of the card by default, so this is what JAX may use, not the card's size);
    None where the backend reports nothing (XLA:CPU)."""
    import jax

    device = jax.devices()[0]
    try:
        stats = device.memory_stats()
    except Exception:  # not implemented on every backend
        stats = None
    limit = (stats or {}).get("bytes_limit")
    return {
        "kind": device.device_kind,
        "platform": device.platform,
        "count": len(jax.devices()),
        "memory_bytes": int(limit) if limit is not None else None,
        "memory_source": "memory_stats()['bytes_limit']" if limit is not None else "memory_stats() reports none",
    }


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _mem_total_gb() -> float | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def machine_info(bandwidth: dict) -> dict:
    import jax

    info = {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "memory_GiB": _mem_total_gb(),
        "platform": platform.platform(),
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "jax_enable_x64": bool(jax.config.jax_enable_x64),
        "load_average_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
    info.update(bandwidth)
    return info


def _version(module: str) -> str | None:
    try:
        mod = __import__(module)
    except Exception:  # optional peer not installed (or broken)
        return None
    return getattr(mod, "__version__", "unknown")


def jaxnav_source_state() -> dict:
    """Git commit of the jaxnav checkout and whether ``jaxnav/`` has uncommitted changes."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

    def git(*args: str) -> str | None:
        try:
            r = subprocess.run(["git", *args], capture_output=True, text=True, cwd=root, timeout=10)
        except Exception:
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    status = git("status", "--porcelain", "--", "jaxnav")
    return {"jaxnav_git": git("rev-parse", "--short", "HEAD"), "jaxnav_dirty": None if status is None else bool(status)}


def import_all_jaxnav() -> None:
    """Import every jaxnav module now, so that the whole run times one version of the code
    even if the source changes while it runs (modules are imported once per process)."""
    import importlib
    import pkgutil

    import jaxnav

    for info in pkgutil.walk_packages(jaxnav.__path__, "jaxnav."):
        try:
            importlib.import_module(info.name)
        except Exception:  # an optional module (e.g. a CLI needing extras) must not stop the run
            pass


def versions() -> dict:
    out = {"python": sys.version.split()[0]}
    for name in ("jax", "jaxlib", "numpy", "filterpy", "particles", "numba", "blackjax", "matplotlib", "jaxnav"):
        out[name] = _version(name)
    out.update(jaxnav_source_state())
    return out


# ---------------------------------------------------------------------------
# output


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    return x


def write_json(path: str, payload: dict) -> None:
    """Write ``payload`` atomically (a temporary file renamed over ``path``): a run killed while
    writing leaves the previous file whole."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        json.dump(_jsonable(payload), f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def size_label(size: dict) -> str:
    return ",".join(f"{k}={_fmt_num(v)}" for k, v in size.items())


def _fmt_num(v: Any) -> str:
    if isinstance(v, (int, np.integer)) and v >= 1000 and v % 10 ** int(math.log10(v)) == 0:
        return f"1e{int(math.log10(v))}" if v // 10 ** int(math.log10(v)) == 1 else str(v)
    return str(v)


def fmt_time(s: float | None) -> str:
    if s is None:
        return "—"
    if s < 1e-3:
        return f"{s * 1e6:.1f} µs"
    if s < 1.0:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def is_peer(implementation: str) -> bool:
    """Peers are the public libraries and the plain NumPy version (not jaxnav, not baselines)."""
    return not (implementation.startswith("jaxnav") or implementation.startswith("jax-"))


def _ratio_key(r: dict) -> tuple:
    # Rows that name a ``scheme`` (W1: systematic, stratified, …) are compared within their scheme only.
    return (r["workload"], json.dumps(r["size"], sort_keys=True), r.get("scheme"))


def annotate_ratios(rows: Iterable[dict]) -> None:
    """Add ``ratio_to_fastest_peer`` and ``ratio_to_floor`` to every timed row (in place).

    The fastest peer is the smallest ``median_s`` among peer rows (any mode,
    any dtype) of the same workload, size and, where rows carry one, ``scheme``.
    """
    rows = list(rows)
    best: dict[tuple, float] = {}
    for r in rows:
        if r.get("median_s") is None or not is_peer(r["implementation"]):
            continue
        key = _ratio_key(r)
        best[key] = min(best.get(key, math.inf), r["median_s"])
    for r in rows:
        if r.get("median_s") is None:
            continue
        key = _ratio_key(r)
        if key in best:
            r["ratio_to_fastest_peer"] = r["median_s"] / best[key]
        if r.get("floor_s"):
            r["ratio_to_floor"] = r["median_s"] / r["floor_s"]


def variant_label(r: dict, with_dtype: bool = False) -> str:
    """What tells a row from its neighbours of the same size, implementation and mode: its
    ``method`` (S1, S2, W5), ``scheme`` (W1), and its ``dtype`` where the row has a ``scheme``
    or ``with_dtype`` (a workload timed in several precisions, W4); ``""`` when none applies."""
    parts = [r.get("method"), r.get("scheme")]
    if "scheme" in r or with_dtype:
        parts.append(r.get("dtype"))
    return " ".join(str(v) for v in parts if v)


def format_table(rows: Sequence[dict]) -> str:
    """Compact terminal table: workload, size, implementation, mode, median, ×fastest peer, ×floor.

    A ``variant`` column after ``mode`` shows :func:`variant_label` where any row has one.
    """
    dtypes: dict[str, set] = {}
    for r in rows:
        dtypes.setdefault(r["workload"], set()).add(r.get("dtype"))
    mixed = {w for w, d in dtypes.items() if len(d) > 1}
    labels = [variant_label(r, r["workload"] in mixed) for r in rows]
    with_variant = any(labels)
    header = (
        ("workload", "size", "implementation", "mode")
        + (("variant",) if with_variant else ())
        + ("median", "×fastest peer", "×floor")
    )
    lead = len(header) - 3
    lines = []
    for r, label in zip(rows, labels):
        first = (r["workload"], size_label(r["size"]), r["implementation"], r["mode"]) + (
            (label,) if with_variant else ()
        )
        if r.get("median_s") is None:
            lines.append(first + ("skipped", "", ""))
            continue
        rp = r.get("ratio_to_fastest_peer")
        rf = r.get("ratio_to_floor")
        lines.append(
            first
            + (
                fmt_time(r["median_s"]),
                f"{rp:.3g}" if rp is not None else "",
                f"{rf:.3g}" if rf is not None else "",
            )
        )
    widths = [max(len(h), *(len(l[i]) for l in lines)) if lines else len(h) for i, h in enumerate(header)]
    out = ["  ".join(h.ljust(w) for h, w in zip(header, widths))]
    out.append("  ".join("-" * w for w in widths))
    prev = None
    for l in lines:
        if prev is not None and (l[0], l[1]) != prev:
            out.append("")
        prev = (l[0], l[1])
        out.append("  ".join(c.ljust(w) if i < lead else c.rjust(w) for i, (c, w) in enumerate(zip(l, widths))))
    skipped = [r for r in rows if r.get("median_s") is None]
    for r in skipped:
        variant = variant_label(r, r["workload"] in mixed)
        out.append(
            f"  skipped: {r['workload']} {size_label(r['size'])} {r['implementation']} {r['mode']}"
            f"{' ' + variant if variant else ''}: {r.get('skipped')}"
        )
    return "\n".join(out)
