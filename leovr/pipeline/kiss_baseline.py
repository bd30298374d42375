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


def kiss_icp_trajectory(
    seq: Sequence, indices: list[int], ccfg: CompleteConfig, progress: bool = False, deskew: bool = True
) -> np.ndarray | None:
    """Camera poses (N x 4 x 4, in the first frame's camera) from KISS-ICP on each frame's cheap input;
    None when the sequence has no LiDAR. `deskew`: KISS-ICP deskews scans that carry point times."""
    runs = kiss_icp_trajectories(seq, indices, ccfg, (deskew,), progress)
    return None if runs is None else runs[deskew]


def kiss_icp_trajectories(
    seq: Sequence, indices: list[int], ccfg: CompleteConfig, deskews: tuple[bool, ...], progress: bool = False
) -> dict[bool, np.ndarray] | None:
    """`kiss_icp_trajectory` for each deskew setting in `deskews`, every frame read and its cheap input
    simulated once for all of them; None when the sequence has no LiDAR. A scan too sparse to register keeps
    the constant-velocity prediction."""
    from odometry.initial_pose import LidarOdometry

    sensor = parse_input(ccfg.input)
    odos: dict[bool, LidarOdometry] = {}
    poses: dict[bool, list[np.ndarray]] = {d: [] for d in deskews}
    desc = {(True,): "kiss_icp baseline", (False,): "kiss_icp baseline (no deskew)"}.get(
        deskews, "kiss_icp baselines (with and without its deskew)"
    )
    for i in tqdm(indices, desc=desc, unit="frame", disable=not progress):
        f = seq[i]
        if f.points is None:
            return None
        timed = f.point_times is not None and len(f.point_times) == len(f.points)
        pts = np.column_stack([f.points, f.point_times]) if timed else f.points
        kept = simulate_cheap_sensor(pts, sensor, f.index, ccfg.seed, f.K, f.T_cam_lidar, f.shape).kept
        for d, run in poses.items():
            if d not in odos:
                odos[d] = LidarOdometry(f.T_cam_lidar, deskew=d)
            T = odos[d].register(kept[:, :3], kept[:, -1] if timed else None)
            if T is None:
                T = run[-1] @ invert_T(run[-2]) @ run[-1] if len(run) > 1 else (run[-1] if run else np.eye(4))
            run.append(T)
    return {d: np.stack(run) for d, run in poses.items()} if indices else None
