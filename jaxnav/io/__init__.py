"""Dataset loaders and log formats.

* :mod:`jaxnav.io.mrclam` — UTIAS MRCLAM Dataset 7 (real range-bearing
  landmark data with Vicon ground truth), discretised into filter steps.
* :mod:`jaxnav.io.adarf` — AdaRF real UHF-RFID reads (RSSI and phase over 8
  channels at 50 antenna positions, three tags with known positions), as
  :class:`~jaxnav.models.uhf_rfid.UHFReads` filter steps.
"""

from jaxnav.io import adarf as adarf
from jaxnav.io import mrclam as mrclam
