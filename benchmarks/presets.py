"""Presets of ``python -m benchmarks.run``: a named plan of workloads, sizes and implementations.

``--preset gpu`` measures, on JAX's default device, the workloads whose size axis a GPU extends:

=========  ==============================  =================================================
workload   size axis                       sizes
=========  ==============================  =================================================
W1         particles N                     10⁶, 10⁷, 10⁸
W2         particles N                     10⁵, 10⁶, 10⁷
W2b        runs R of N = 1,000 particles   10², 10³, 10⁴ (10⁴ × 10³: W2's largest N in runs)
W5         runs R in one vmapped call      10², 10³, 10⁴
S2         tags in the map (500 robot      10, 10³, 10⁵
           particles)
=========  ==============================  =================================================

Only the implementations that run on the device are measured (``jaxnav``, ``jaxnav-nocheck``,
``jaxnav-plain``, ``jax-baseline``, ``blackjax``): the NumPy, filterpy and particles peers run on the
host's CPU whatever the device, and at these sizes they alone would take longer than the plan
(W1's NumPy and particles rows at 10⁸ take 2–8 s a call on a CPU). The floors use the device's
bandwidth, measured at the start of the run (:func:`benchmarks.harness.measure_device_bandwidth`).

``--scale-down`` divides every size by :attr:`Preset.scale_factor` (1,000), keeps at least the
workload's :attr:`Preset.minimum` (W1 and W2: N = 1,000; S2: 10 tags, the size its ratios are taken
against; W2b and W5: one run) and drops the sizes that fall together, so that the same plan runs on
a small CPU: W1 N = 10³, 10⁴, 10⁵; W2 N = 10³, 10⁴; W2b R = 1, 10; W5 R = 1, 10; S2 10, 100 tags.

Time on one NVIDIA H200: about 7.6 minutes estimated, most of it compilation (not measured; see
:data:`GPU_ESTIMATE_S`). The run budget, :attr:`Preset.budget_s` = 480 s, keeps ``benchmarks.run`` from
starting a size once it is spent (:func:`benchmarks.run.budget_reason`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ["Preset", "PRESETS", "GPU", "GPU_ESTIMATE_S"]


@dataclass(frozen=True)
class Preset:
    """A plan for ``benchmarks.run``.

    Attributes:
        name: the ``--preset`` value.
        sizes: workload name → its sizes, in increasing order (the run order of the workloads is the
            registry's).
        scaled: workload name → the size key ``--scale-down`` divides (the other keys stay).
        minimum: workload name → the smallest value a divided size keeps.
        implementations: the implementations measured; the others give no row.
        budget_s: seconds of the whole run after which no further size starts (a size already started
            runs to its end).
        scale_factor: what ``--scale-down`` divides every size by.
    """

    name: str
    sizes: Mapping[str, Sequence[dict]]
    scaled: Mapping[str, str]
    minimum: Mapping[str, int]
    implementations: frozenset[str]
    budget_s: float
    scale_factor: int

    def plan(self, scale_down: bool = False) -> dict[str, list[dict]]:
        """Workload name → sizes; with ``scale_down`` each divided by :attr:`scale_factor` (rounded, at
        least :attr:`minimum`), sizes that fall together kept once."""
        out: dict[str, list[dict]] = {}
        for name, sizes in self.sizes.items():
            kept: list[dict] = []
            for size in sizes:
                size = dict(size)
                if scale_down:
                    key = self.scaled[name]
                    size[key] = max(self.minimum[name], round(size[key] / self.scale_factor))
                if size not in kept:
                    kept.append(size)
            out[name] = kept
        return out


GPU = Preset(
    name="gpu",
    sizes={
        "W1": [{"N": 10**k} for k in (6, 7, 8)],
        "W2": [{"N": 10**k} for k in (5, 6, 7)],
        "W2b": [{"R": 10**k, "N": 1000} for k in (2, 3, 4)],
        "W5": [{"runs": 10**k} for k in (2, 3, 4)],
        "S2": [{"robot_particles": 500, "tags": t} for t in (10, 1000, 100_000)],
    },
    scaled={"W1": "N", "W2": "N", "W2b": "R", "W5": "runs", "S2": "tags"},
    minimum={"W1": 1000, "W2": 1000, "W2b": 1, "W5": 1, "S2": 10},
    implementations=frozenset({"jaxnav", "jaxnav-nocheck", "jaxnav-plain", "jax-baseline", "blackjax"}),
    budget_s=480.0,
    scale_factor=1000,
)

GPU_ESTIMATE_S = {"W1": 110.0, "W2": 60.0, "W2b": 84.0, "W5": 64.0, "S2": 120.0, "start and plots": 20.0}
"""Estimated seconds of :data:`GPU` on one H200, 458 s in all (not measured). Compilation: the seconds the
quiet 2-core CPU's runs took to compile the same programs (``results/w1.json``, ``latest.json``,
``hf_slam.json``; W2b and W5 from the scaled-down run, on a busy CPU), assumed the same on XLA:GPU: W1 84,
W2 39, W2b 39, W5 48, S2 109. Execution: the CPU's time for the same calls, linear in N past the sizes it measured, / 100
(the H200's nominal 4.8 TB/s is 180–460 times those CPUs' 10–27 GB/s), plus host work (W1's 10⁸ weights,
ancestors copied back for checking, S2's maps)."""

PRESETS = {GPU.name: GPU}
