"""Records shared by every reader: one frame of synchronized sensor data and a sequence summary."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Frame:
    """One synchronized camera + LiDAR sample.

    Conventions: `image` is H x W x 3 RGB uint8 or H x W gray uint8; `points` are N x 3 or N x 4
    (x, y, z[, intensity]) float32 in the LiDAR frame; `point_times` are seconds relative to
    `timestamp` (or None); `T_cam_lidar` maps LiDAR coordinates into the camera frame; `T_world_cam`
    is the ground-truth camera pose (camera to world) when the dataset has one; `depth` is
    ground-truth depth in metres with 0 where unknown.
    """

    index: int
    timestamp: float
    image: np.ndarray
    K: np.ndarray
    T_cam_lidar: np.ndarray = field(default_factory=lambda: np.eye(4))
    points: np.ndarray | None = None
    point_times: np.ndarray | None = None
    T_world_cam: np.ndarray | None = None
    depth: np.ndarray | None = None
    moving_mask: np.ndarray | None = None

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width


@dataclass
class SequenceInfo:
    """What `leovr info` prints: which reader, how much data and which optional parts exist."""

    reader: str
    path: str
    frames: int
    width: int
    height: int
    channels: int
    rate_hz: float
    has_lidar: bool
    points_per_scan: int
    has_point_times: bool
    has_poses: bool
    has_depth: bool

    def as_dict(self) -> dict:
        return dict(self.__dict__)
