"""jaxnav: vectorised JAX particle filters for indoor robot localization and SLAM.

Sub-packages: :mod:`jaxnav.core` (log-weights, resampling, ring buffers,
batch Monte Carlo), :mod:`jaxnav.models` (motion and sensor models),
:mod:`jaxnav.sim` (simulators), :mod:`jaxnav.localization` (filters).
"""

from jaxnav._version import __version__ as __version__
from jaxnav import core as core, localization as localization, models as models, sim as sim
