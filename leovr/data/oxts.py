"""OXTS GPS/IMU packets (KITTI raw) to IMU poses.

Orientation is the packet's roll, pitch and yaw. Position: the GPS fix (Mercator, as KITTI's devkit) smoothed
with the unit's own velocities, each weighted by the accuracy the packet states. In differential mode (not RTK) a
fix is good to 0.15-0.2 m and wanders by as much over seconds, while the velocities hold to about 3 cm/s; on
drive 0013 the fixes swing +-0.5 m sideways against the integrated velocities, and a camera-only and a
LiDAR-only trajectory both follow the velocities there (docs/decisions/0012-kitti-raw-reference.md). The fixes
keep the smoothed track from drifting over a long drive.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from leovr.errors import DataError
from leovr.geometry import invert_T

EARTH_RADIUS_M = 6378137.0
# packet fields (KITTI raw oxts/dataformat.txt, 0-based)
LAT, LON, ALT, ROLL, PITCH, YAW, VN, VE = range(8)
VU = 10
POS_ACCURACY, VEL_ACCURACY = 23, 24
REFERENCE_NOTE = (
    "KITTI raw poses: the OXTS GPS fixes smoothed with its velocities, each weighted by the accuracy it states"
    " (the fixes alone, as KITTI's devkit reads them, swing +-0.5 m sideways on drive 0013: ATE against them in"
    " `ate_gps_fixes_m`)"
)


def read_packets(files: list[Path]) -> np.ndarray:
    """Packets (F x K): every packet its first six values at least (lat lon alt roll pitch yaw); all packets
    cut to the shortest one's length."""
    packets = []
    for f in files:
        try:
            values = np.array(f.read_text().split(), float)
        except (OSError, ValueError) as exc:
            raise DataError(f, f"unreadable OXTS packet: {exc}") from exc
        if len(values) < 6:
            raise DataError(f, "OXTS packet has fewer than 6 values (lat lon alt roll pitch yaw)")
        packets.append(values)
    width = min(len(p) for p in packets)
    return np.stack([p[:width] for p in packets])


def smoothed_positions(fixes: np.ndarray, velocities: np.ndarray, times: np.ndarray, fix_sigma, vel_sigma):
    """Positions (F x 3) that best fit both the fixes (sigma `fix_sigma` m each) and the steps the velocities
    give between packets (trapezoid, sigma `vel_sigma` m/s times the interval): linear least squares, each
    axis alone."""
    n = len(fixes)
    dt = np.diff(times)
    step_sigma = 0.5 * (vel_sigma[1:] + vel_sigma[:-1]) * dt
    steps = 0.5 * (velocities[1:] + velocities[:-1]) * dt[:, None]
    diff = sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    A = sp.vstack([sp.diags(1.0 / fix_sigma), sp.diags(1.0 / step_sigma) @ diff]).tocsc()
    normal = (A.T @ A).tocsc()
    out = np.empty_like(fixes)
    for axis in range(3):
        b = np.concatenate([fixes[:, axis] / fix_sigma, steps[:, axis] / step_sigma])
        out[:, axis] = spsolve(normal, A.T @ b)
    return out


def oxts_poses(o: np.ndarray, times: np.ndarray | None = None) -> np.ndarray:
    """IMU poses (F x 4 x 4, relative to the first) from OXTS packets (`read_packets`). With the packets'
    times and their velocities and stated accuracies (fields 7-11, 24-25), positions are the fixes smoothed
    with the velocities; otherwise (or `times` None) the fixes alone, as KITTI's devkit reads them."""
    lat, lon, alt = o[:, LAT], o[:, LON], o[:, ALT]
    scale = np.cos(np.radians(lat[0]))
    east = scale * EARTH_RADIUS_M * np.radians(lon)
    north = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0))
    fixes = np.stack([east - east[0], north - north[0], alt - alt[0]], 1)
    position = fixes
    if times is not None and len(o) > 1 and o.shape[1] > VEL_ACCURACY:
        fix_sigma, vel_sigma = o[:, POS_ACCURACY], o[:, VEL_ACCURACY]
        if (fix_sigma > 0).all() and (vel_sigma > 0).all() and (np.diff(times) > 0).all():
            velocities = np.stack([o[:, VE], o[:, VN], o[:, VU]], 1)
            position = smoothed_positions(fixes, velocities, times, fix_sigma, vel_sigma)
    from scipy.spatial.transform import Rotation

    T = np.tile(np.eye(4), (len(o), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("ZYX", o[:, [YAW, PITCH, ROLL]]).as_matrix()
    T[:, :3, 3] = position
    return invert_T(T[0]) @ T
