"""Project LiDAR points into the image as a sparse depth map (nearest return wins per pixel)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_DEPTH_M = 0.1


@dataclass
class Projection:
    """The points that won a pixel: pixel coordinates, camera-frame depth and index into the input."""

    u: np.ndarray  # column, int
    v: np.ndarray  # row, int
    depth: np.ndarray  # metres
    index: np.ndarray  # index of the winning point in the input array
    shape: tuple[int, int]

    def to_map(self) -> np.ndarray:
        """H x W float32 depth map, 0 where no point landed."""
        out = np.zeros(self.shape, np.float32)
        out[self.v, self.u] = self.depth
        return out


def project_points(
    points: np.ndarray,
    K: np.ndarray,
    T_cam_lidar: np.ndarray,
    shape: tuple[int, int],
    min_depth: float = MIN_DEPTH_M,
) -> Projection:
    """Project N x >=3 LiDAR points; pixel (u, v) is the nearest integer to K [x/z, y/z, 1].

    Points behind the camera, nearer than `min_depth` or outside the image are dropped; when several
    points fall on one pixel the nearest wins.
    """
    u, v, z, idx = image_pixels(points, K, T_cam_lidar, shape, min_depth)
    lin = v * shape[1] + u
    order = np.lexsort((z, lin))  # by pixel, nearest first
    _, first = np.unique(lin[order], return_index=True)
    win = order[first]
    return Projection(u=u[win], v=v[win], depth=z[win].astype(np.float32), index=idx[win], shape=shape)


def image_pixels(
    points: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray, shape: tuple[int, int], min_depth: float = MIN_DEPTH_M
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (u, v), depth and input index of every point in front of the camera (beyond `min_depth`)
    and inside the image, rounded as `project_points` rounds them, several per pixel allowed."""
    h, w = shape
    xyz = np.asarray(points, np.float64)[:, :3]
    cam = xyz @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    z = cam[:, 2]
    front = np.nonzero(z > min_depth)[0]
    cam, z = cam[front], z[front]
    uv = cam @ K.T
    u = np.floor(uv[:, 0] / z + 0.5).astype(np.int64)
    v = np.floor(uv[:, 1] / z + 0.5).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return u[inside], v[inside], z[inside], front[inside]


def sparse_depth(points: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """H x W float32 sparse depth map of the points (0 = no return)."""
    return project_points(points, K, T_cam_lidar, shape).to_map()
