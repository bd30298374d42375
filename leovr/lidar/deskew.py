"""Motion compensation of a LiDAR sweep by interpolating the sensor pose over the sweep
(LeoVR Sec. III-C-2, linear interpolation as in LOAM)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from leovr.data.records import Frame
from leovr.geometry import interpolate_poses, invert_T, move_along


def deskew(
    points: np.ndarray,
    times: np.ndarray,
    T_w_start: np.ndarray,
    T_w_end: np.ndarray,
    sweep_s: float,
    t_ref: float | None = None,
) -> np.ndarray:
    """Express every point in the sensor frame at time `t_ref` (default: end of sweep).

    `points` (N x >=3, extra columns kept) were each measured in the sensor frame at its own time
    `times` (seconds from sweep start); `T_w_start` and `T_w_end` are the sensor poses (sensor to
    world) at the start and end of the sweep, interpolated in between.
    """
    if len(points) == 0:
        return points.copy()
    if sweep_s <= 0:
        raise ValueError("sweep_s must be positive")
    t_ref = sweep_s if t_ref is None else t_ref
    T_rel = invert_T(T_w_start) @ T_w_end  # end pose in the start frame
    T_ref_inv = invert_T(interpolate_poses(np.eye(4), T_rel, np.array(t_ref / sweep_s)))
    xyz = move_along(T_rel, np.asarray(times, np.float64) / sweep_s, points[:, :3])
    out = np.array(points, copy=True)
    out[:, :3] = xyz @ T_ref_inv[:3, :3].T + T_ref_inv[:3, 3]
    return out


def deskew_frame(f: Frame, motion_cam: np.ndarray | None, frame_dt: float) -> Frame:
    """The frame with its scan motion-compensated to the camera time (LeoVR Sec. III-C-2): each point
    moved by the camera motion predicted over its offset from the image's time (`point_times`, before or
    after it), at constant velocity (`motion_cam`: the motion over one frame interval, interpolated and
    extrapolated on the geodesic). Unchanged without point times or motion."""
    if f.points is None or f.point_times is None or motion_cam is None or not len(f.points):
        return f
    T_cl = f.T_cam_lidar
    motion_lidar = invert_T(T_cl) @ motion_cam @ T_cl  # per frame interval, LiDAR frame
    out = np.array(f.points, copy=True)
    out[:, :3] = move_along(motion_lidar, np.asarray(f.point_times, np.float64) / frame_dt, f.points[:, :3])
    return replace(f, points=out)
