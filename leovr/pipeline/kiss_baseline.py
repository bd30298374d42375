"""The `kiss_icp` trajectory baseline: KISS-ICP alone on the run's LiDAR input, as a user would run it.

It registers the same cheap input the run gives leovr (`--input`), raw: KISS-ICP deskews each scan
itself from the point times with its own last motion, as its pipeline does, never with leovr's motion
(the baseline must not borrow from the system it is compared against). Its poses are scored as it
reports them, the way users score KISS-ICP: they refer to the end of each sweep (with no point times,
to the scan as a whole), up to a frame interval after the camera's time.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig
from leovr.data.sequence import Sequence
from leovr.geometry import invert_T
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor


def kiss_icp_trajectory(seq: Sequence, indices: list[int], ccfg: CompleteConfig, progress: bool = False) -> np.ndarray | None:
    """Camera poses (N x 4 x 4, in the first frame's camera) from KISS-ICP on each frame's cheap input;
    None when the sequence has no LiDAR. A scan too sparse to register keeps the constant-velocity
    prediction."""
    from odometry.initial_pose import LidarOdometry

    sensor = parse_input(ccfg.input)
    odo: LidarOdometry | None = None
    poses: list[np.ndarray] = []
    for i in tqdm(indices, desc="kiss_icp baseline", unit="frame", disable=not progress):
        f = seq[i]
        if f.points is None:
            return None
        odo = odo or LidarOdometry(f.T_cam_lidar, deskew=True)
        timed = f.point_times is not None and len(f.point_times) == len(f.points)
        pts = np.column_stack([f.points, f.point_times]) if timed else f.points
        kept = simulate_cheap_sensor(pts, sensor, f.index, ccfg.seed, f.K, f.T_cam_lidar, f.shape).kept
        T = odo.register(kept[:, :3], kept[:, -1] if timed else None)
        if T is None:
            T = poses[-1] @ invert_T(poses[-2]) @ poses[-1] if len(poses) > 1 else (poses[-1] if poses else np.eye(4))
        poses.append(T)
    return np.stack(poses) if poses else None
