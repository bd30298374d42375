"""Per-point times of a spinning LiDAR's sweep, from each return's azimuth."""

from __future__ import annotations

import numpy as np


def azimuth_times(points: np.ndarray, sweep_s: float = 0.1) -> np.ndarray:
    """Per-point time from the start of the sweep for a spinning LiDAR that starts behind the car and turns
    clockwise seen from above (KITTI's HDL-64, Velodyne's default; forward at mid-sweep), as KISS-ICP times
    KITTI raw scans."""
    az = np.arctan2(points[:, 1], points[:, 0])
    return np.mod(np.pi - az, 2 * np.pi) / (2 * np.pi) * sweep_s
