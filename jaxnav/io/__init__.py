"""Dataset loaders and log formats.

* :mod:`jaxnav.io.mrclam` — UTIAS MRCLAM Dataset 7 (real range-bearing
  landmark data with Vicon ground truth), discretised into filter steps.
"""

from jaxnav.io import mrclam as mrclam
