"""Range-only localization and SLAM on real UWB ranges: the TU Chemnitz "Labyrinth" dataset.

:mod:`~jaxnav.experiments.uwb.evaluation` runs dead reckoning, MCL with the surveyed anchors
(Gaussian and Student-t ranges) and range-only PF-SLAM and PS-SLAM (anchors unknown) on the log and
scores them against the ground truth path and the surveyed anchors (re-exported here).
"""

from jaxnav.experiments.uwb import evaluation as _evaluation
from jaxnav.experiments.uwb.evaluation import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_evaluation.__all__)
