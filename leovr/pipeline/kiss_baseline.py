"""The `kiss_icp` trajectory baseline: KISS-ICP alone on the run's LiDAR input, as a user would run it.

It registers the same cheap input the run gives leovr (`--input`), raw: by default KISS-ICP deskews each
scan itself from the point times with its own last motion, as its pipeline does, never with leovr's motion
(the baseline must not borrow from the system it is compared against); `deskew=False` registers the scans
as they are (on KITTI raw drives KISS-ICP's own deskew starts from an undeskewed first scan and its steps
swing by up to 50 % for a dozen frames, so a user is better off without it). Its poses are scored as it
reports them: they refer to the middle of each sweep (with no point times, to the scan as a whole).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig
from leovr.data.sequence import Sequence
from leovr.geometry import invert_T
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor


def kiss_icp_trajectory(seq: Sequence, indices: list[int], ccfg: CompleteConfig, progress: bool = False,
                        deskew: bool = True) -> np.ndarray | None:
    """Camera poses (N x 4 x 4, in the first frame's camera) from KISS-ICP on each frame's cheap input;
    None when the sequence has no LiDAR. A scan too sparse to register keeps the constant-velocity
    prediction. `deskew`: KISS-ICP deskews scans that carry point times."""
    from odometry.initial_pose import LidarOdometry

    sensor = parse_input(ccfg.input)
    odo: LidarOdometry | None = None
    poses: list[np.ndarray] = []
    desc = "kiss_icp baseline" + ("" if deskew else " (no deskew)")
    for i in tqdm(indices, desc=desc, unit="frame", disable=not progress):
        f = seq[i]
        if f.points is None:
            return None
        odo = odo or LidarOdometry(f.T_cam_lidar, deskew=deskew)
        timed = f.point_times is not None and len(f.point_times) == len(f.points)
        pts = np.column_stack([f.points, f.point_times]) if timed else f.points
        kept = simulate_cheap_sensor(pts, sensor, f.index, ccfg.seed, f.K, f.T_cam_lidar, f.shape).kept
        T = odo.register(kept[:, :3], kept[:, -1] if timed else None)
        if T is None:
            T = poses[-1] @ invert_T(poses[-2]) @ poses[-1] if len(poses) > 1 else (poses[-1] if poses else np.eye(4))
        poses.append(T)
    return np.stack(poses) if poses else None
