"""jaxnav: vectorised JAX particle filters for indoor robot localization and SLAM.

Sub-packages: :mod:`jaxnav.core` (log-weights, resampling, ring buffers,
batch Monte Carlo), :mod:`jaxnav.models` (motion and sensor models),
:mod:`jaxnav.sim` (simulators), :mod:`jaxnav.localization` (filters with a
known map), :mod:`jaxnav.slam` (EKF-SLAM, FastSLAM), :mod:`jaxnav.io`
(dataset loaders), :mod:`jaxnav.metrics` (scoring) and
:mod:`jaxnav.experiments` (real-data and reproduction studies; imported on demand).
"""

from jaxnav import (
    core as core,
)
from jaxnav import (
    io as io,
)
from jaxnav import (
    localization as localization,
)
from jaxnav import (
    metrics as metrics,
)
from jaxnav import (
    models as models,
)
from jaxnav import (
    sim as sim,
)
from jaxnav import (
    slam as slam,
)
from jaxnav._version import __version__ as __version__
