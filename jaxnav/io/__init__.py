"""Dataset loaders and log formats.

* :mod:`jaxnav.io.mrclam` — UTIAS MRCLAM Dataset 7 (real range-bearing
  landmark data with Vicon ground truth), discretised into filter steps.
* :mod:`jaxnav.io.adarf` — AdaRF real UHF-RFID reads (RSSI and phase over 8
  channels at 50 antenna positions, three tags with known positions), as
  :class:`~jaxnav.models.uhf_reads.UHFReads` filter steps.

Both find their dataset in ``root``, the environment variable ``JAXNAV_DATA`` or ``../shared/data``
relative to the repository root of a source checkout (never relative to the current directory), and
raise :class:`DataNotFoundError` (a ``FileNotFoundError``) naming the folders tried and the download page
when it is in none of them.
"""

from jaxnav.io import adarf as adarf
from jaxnav.io import mrclam as mrclam
from jaxnav.io._data import ENV_VAR, DataNotFoundError

__all__ = ["adarf", "mrclam", "ENV_VAR", "DataNotFoundError"]
