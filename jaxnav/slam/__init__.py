"""SLAM filters: EKF-SLAM ([A] Alg. 4), FastSLAM 1.0 and 2.0 ([A] Alg. 5)."""

from jaxnav.slam import ekf_slam as ekf_slam
from jaxnav.slam import fastslam as fastslam
