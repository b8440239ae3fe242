"""Classical filters on real data: UTIAS MRCLAM dataset 7, robots 1–3.

:mod:`~jaxnav.experiments.mrclam.evaluation` runs dead reckoning, EKF, UKF,
MCL, EKF-SLAM and FastSLAM 1.0/2.0 on a robot's log and scores them against
the Vicon ground truth (re-exported here).
"""

from jaxnav.experiments.mrclam import evaluation as _evaluation
from jaxnav.experiments.mrclam.evaluation import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_evaluation.__all__)
