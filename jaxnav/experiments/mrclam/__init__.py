"""Classical filters on real data: UTIAS MRCLAM dataset 7, robots 1–3.

:mod:`~jaxnav.experiments.mrclam.evaluation` runs dead reckoning, EKF, UKF,
MCL, EKF-SLAM and FastSLAM 1.0/2.0 on a robot's log and scores them against
the Vicon ground truth (re-exported here).
"""

from jaxnav.experiments.mrclam.evaluation import (
    ALGORITHMS,
    NOTHING_MAPPED,
    AlgorithmResult,
    MRCLAMSettings,
    format_table,
    plot_robot,
    run_algorithm,
    run_robot,
)

__all__ = [
    "ALGORITHMS",
    "MRCLAMSettings",
    "AlgorithmResult",
    "run_algorithm",
    "run_robot",
    "format_table",
    "plot_robot",
    "NOTHING_MAPPED",
]
