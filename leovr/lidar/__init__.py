"""LiDAR utilities: projection into the image, motion compensation, cheap-sensor simulation."""

from leovr.lidar.cheap_sensor import (
    CheapSensor,
    ScanSplit,
    parse_input,
    simulate_cheap_sensor,
)
from leovr.lidar.deskew import deskew
from leovr.lidar.sweep import azimuth_times
from leovr.lidar.projection import Projection, project_points, sparse_depth

__all__ = [
    "CheapSensor",
    "Projection",
    "ScanSplit",
    "azimuth_times",
    "deskew",
    "parse_input",
    "project_points",
    "simulate_cheap_sensor",
    "sparse_depth",
]
