"""Earlier scans of a narrow-cone LiDAR carried into the current frame's generator input.

A Livox Mid-40 sees a 38.4-degree cone, less than half a wide camera's view, and its rosette covers
different directions from scan to scan. Driving forward moves what the cone saw a moment ago out to the
sides of the image, so the returns of the last few frames, placed with the graph's poses, add depth where
this frame's scan has none (LeoVR, Sec. V-C2, also accumulates the Mid-40's sampling points). A spinning LiDAR
already spans the image; on the development drives its accumulated returns made the generator worse
(docs/benchmarks.md), so `refine` keeps this for non-spinning sensors.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from leovr.geometry import invert_T
from leovr.lidar.projection import project_points


@dataclass
class ScanHistory:
    """The cheap input of the last `frames` frames, each in its own camera frame."""

    frames: int
    scans: deque = field(default_factory=deque)  # (frame index, N x 3 camera-frame points)
    sensor_known: bool = False  # whether the sensor was judged (cone or spinning) on a scan with enough returns

    def add(self, index: int, points_lidar: np.ndarray | None, T_cam_lidar: np.ndarray) -> None:
        if self.frames <= 0 or points_lidar is None or not len(points_lidar):
            return
        xyz = np.asarray(points_lidar, np.float64)[:, :3]
        self.scans.append((index, xyz @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]))
        while len(self.scans) > self.frames:
            self.scans.popleft()

    def gather(self, poses: Mapping[int, np.ndarray], T_world_cam: np.ndarray) -> np.ndarray:
        """The stored returns in the camera at `T_world_cam` (camera to world), each scan placed by its
        frame's pose in `poses`; scans of frames without a pose are left out. M x 3."""
        T_cam_world = invert_T(T_world_cam)
        out = []
        for index, pts in self.scans:
            if index in poses:
                T = T_cam_world @ poses[index]
                out.append(pts @ T[:3, :3].T + T[:3, 3])
        return np.concatenate(out) if out else np.zeros((0, 3))


def with_history(sparse: np.ndarray, points_cam: np.ndarray, K: np.ndarray, cell: int = 4) -> np.ndarray:
    """The frame's own sparse depth plus earlier returns (camera frame) in the `cell` x `cell` pixel cells
    it leaves empty, one per cell (the nearest): the classical prior's triangulation grows with the
    number of returns (27k unthinned on a Mid-40 city drive: 10x the prior's time)."""
    if not len(points_cam):
        return sparse
    h, w = sparse.shape
    cols = -(-w // cell)
    earlier = project_points(points_cam, K, np.eye(4), sparse.shape)  # the nearest return per pixel
    cell_of = (earlier.v // cell) * cols + earlier.u // cell
    v, u = np.nonzero(sparse > 0)
    own = np.zeros(-(-h // cell) * cols, bool)
    own[(v // cell) * cols + u // cell] = True
    order = np.lexsort((earlier.depth, cell_of))  # by cell, nearest first
    _, first = np.unique(cell_of[order], return_index=True)
    pick = order[first][~own[cell_of[order[first]]]]
    out = np.array(sparse, np.float32)
    out[earlier.v[pick], earlier.u[pick]] = earlier.depth[pick]
    return out
