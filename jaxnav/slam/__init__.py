"""SLAM filters: EKF-SLAM ([A] Alg. 4), FastSLAM 1.0 and 2.0 ([A] Alg. 5), PF-SLAM ([W] Alg. 1), PS-SLAM ([W] Alg. 2)."""

from jaxnav.slam import ekf_slam as ekf_slam
from jaxnav.slam import fastslam as fastslam
from jaxnav.slam import pf_slam as pf_slam
from jaxnav.slam import ps_slam as ps_slam
