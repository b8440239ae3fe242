"""[A] reproduced: UHF-RFID tag localization from RSSI and phase ([A] Alg. 6), simulated and real.

* :mod:`~jaxnav.experiments.uhf.localization`: one simulated run of [A] §5.2
  (settings, simulate, fit the anchor, filter) and the RMSE summaries
  (re-exported here).
* :mod:`~jaxnav.experiments.uhf.figures`: [A]'s Figs. 5.3, 5.5, 5.6 and ours (``uhf-refresh``).
* :mod:`~jaxnav.experiments.uhf.real`: Alg. 6 on the AdaRF real reads.

The figures are listed in :mod:`jaxnav.experiments.catalog` and run by name
with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.uhf import localization as _localization
from jaxnav.experiments.uhf.localization import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_localization.__all__)
