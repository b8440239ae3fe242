"""[W] ch. 5 reproduced: IR emitter positioning with IR MCL ([W] Alg. 3, §5.4).

* :mod:`~jaxnav.experiments.ir.positioning`: one simulated drive: settings,
  simulate, filter, score, draw (re-exported here).
* :mod:`~jaxnav.experiments.ir.tables`: the experiments of [W] §5.4 (Tables 5.2,
  5.3; failure, speeds, rotation) and ours (installation error).

The tables are listed in :mod:`jaxnav.experiments.catalog` and run by name
with :func:`jaxnav.experiments.registry.run`.
"""

from jaxnav.experiments.ir import positioning as _positioning
from jaxnav.experiments.ir.positioning import *  # noqa: F403  (the study's module, re-exported)

__all__ = list(_positioning.__all__)
