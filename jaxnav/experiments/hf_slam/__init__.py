"""[W] ch. 3–4 reproduced: HF-RFID SLAM on simulated tag carpets (PF-SLAM, PS-SLAM, FastSLAM).

* :mod:`~jaxnav.experiments.hf_slam.simulation`: one method on one setting:
  simulate, filter, score like [W], draw (re-exported here).
* :mod:`~jaxnav.experiments.hf_slam.tables`: [W]'s error Tables 3.1, 3.2, 4.1, 4.2.
* :mod:`~jaxnav.experiments.hf_slam.figures`: [W]'s Figs. 3.5, 3.7, 4.4 and the kidnapping of Fig. 3.12.

The tables and figures are listed in :mod:`jaxnav.experiments.catalog` and
run by name with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.hf_slam import simulation as _simulation
from jaxnav.experiments.hf_slam.simulation import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_simulation.__all__)
