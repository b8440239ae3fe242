"""Range-only SLAM among unknown beacons, simulated: PF-SLAM and PS-SLAM against FastSLAM.

:mod:`~jaxnav.experiments.range_slam.simulation` holds the world, the methods, the registered
experiment ``range-only-slam`` and the figure of landmark clouds collapsing (re-exported here).
"""

from jaxnav.experiments.range_slam import simulation as _simulation
from jaxnav.experiments.range_slam.simulation import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_simulation.__all__)
