"""jaxnav benchmark harness (the workloads and how they are timed: ``benchmarks/README.md``).

Run ``python -m benchmarks.run [--only W1,W2] [--quick] [--out FILE] [--repeats K]``.

Layout
------
* :mod:`benchmarks.harness` — timing (medians after warm-up, ``block_until_ready``,
  compile time apart), machine description, memory bandwidth, versions, rows, JSON,
  the terminal table.
* :mod:`benchmarks.workloads` — the registry; every module in that package
  registers one :class:`~benchmarks.workloads.Workload` (W1–W5, W2b, S1, S2,
  U1) and the runner discovers them without being edited.
* :mod:`benchmarks.peers` — the non-jaxnav implementations (NumPy, filterpy, particles).
* :mod:`benchmarks.plot` — one log-log PNG per workload beside the JSON.
* :mod:`benchmarks.profile_w2` — a breakdown of jaxnav's W2 step into its parts.
"""
