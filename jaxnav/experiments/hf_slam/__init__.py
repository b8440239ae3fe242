"""[W] ch. 3–4 reproduced: HF-RFID SLAM on simulated tag carpets (PF-SLAM, PS-SLAM, FastSLAM).

* :mod:`~jaxnav.experiments.hf_slam.simulation`: one method on one setting:
  simulate, filter, score like [W], draw (re-exported here).
* :mod:`~jaxnav.experiments.hf_slam.tables`: [W]'s error Tables 3.1, 3.2, 4.1, 4.2.
* :mod:`~jaxnav.experiments.hf_slam.figures`: [W]'s Figs. 3.5, 3.7, 4.4 and the kidnapping of Fig. 3.12.

The tables and figures are listed in :mod:`jaxnav.experiments.catalog` and
run by name with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.hf_slam.simulation import (
    COLUMN_HEADS,
    ERROR_COLUMNS,
    METHODS,
    NOTHING_MAPPED,
    TAG_COLUMNS,
    TRAJECTORIES,
    Errors,
    HFSetting,
    MethodRun,
    World,
    dead_reckoning,
    detection_counts,
    error_cell,
    fastslam_parallel_slots,
    filter_world,
    format_errors,
    make_world,
    plot_run,
    reachable_tags,
    run_method,
    run_once,
    score,
)

__all__ = [
    "METHODS",
    "TRAJECTORIES",
    "HFSetting",
    "World",
    "MethodRun",
    "Errors",
    "ERROR_COLUMNS",
    "COLUMN_HEADS",
    "TAG_COLUMNS",
    "NOTHING_MAPPED",
    "make_world",
    "reachable_tags",
    "run_method",
    "fastslam_parallel_slots",
    "filter_world",
    "score",
    "run_once",
    "error_cell",
    "dead_reckoning",
    "detection_counts",
    "format_errors",
    "plot_run",
]
