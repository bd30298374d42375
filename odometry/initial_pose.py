"""Initial pose of each new frame: KISS-ICP on the LiDAR scan, or PnP + RANSAC on features whose 3D
position is known, whichever explains more of the frame's feature matches (a Mid-40 cone is often too
narrow for ICP; a textureless or dark image too poor for PnP)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from leovr.data.io import MIN_SCAN_POINTS
from leovr.geometry import invert_T


@dataclass
class PoseGuess:
    T_world_cam: np.ndarray
    source: str  # "icp", "pnp", "constant_velocity" or "first"
    inliers: int


class LidarOdometry:
    """KISS-ICP on raw scans (deskew off: our scans are deskewed before, or carry no times), reported
    as camera poses in the world frame of the first camera."""

    def __init__(self, T_cam_lidar: np.ndarray, max_range: float = 100.0) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        cfg = KISSConfig()
        cfg.data.deskew = False
        cfg.data.max_range = max_range
        cfg.data.min_range = 1.0
        cfg.mapping.voxel_size = max_range / 100.0
        self.icp = KissICP(cfg)
        self.T_cl = T_cam_lidar
        self.frames = 0

    def register(self, points: np.ndarray) -> np.ndarray | None:
        """Camera pose (camera to world) after registering this scan, or None when it has too few points."""
        xyz = np.ascontiguousarray(points[:, :3], np.float64)
        if len(xyz) < MIN_SCAN_POINTS:
            return None
        self.icp.register_frame(xyz, np.array([]))
        self.frames += 1
        T_l0_l = self.icp.last_pose
        return self.T_cl @ T_l0_l @ invert_T(self.T_cl)


def pnp_pose(obj: np.ndarray, img: np.ndarray, K: np.ndarray, reproj_px: float = 2.0) -> tuple[np.ndarray | None, np.ndarray]:
    """Camera pose (camera to world) from world points and their pixels; also the inlier mask."""
    mask = np.zeros(len(obj), bool)
    if len(obj) < 8:
        return None, mask
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj.astype(np.float64), img.astype(np.float64), K, None,
                                             iterationsCount=200, reprojectionError=reproj_px,
                                             confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or inl is None or len(inl) < 6:
        return None, mask
    mask[inl.ravel()] = True
    R, _ = cv2.Rodrigues(rvec)
    T_cw = np.eye(4)
    T_cw[:3, :3], T_cw[:3, 3] = R, tvec.ravel()
    return invert_T(T_cw), mask


def reprojection_inliers(T_world_cam: np.ndarray, obj: np.ndarray, img: np.ndarray, K: np.ndarray,
                         reproj_px: float = 2.0) -> np.ndarray:
    """Which world points project within `reproj_px` of their pixel from this pose."""
    if len(obj) == 0:
        return np.zeros(0, bool)
    T_cw = invert_T(T_world_cam)
    P = obj @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = P[:, 2]
    uv = (P @ K.T)[:, :2] / np.where(z > 1e-6, z, 1e-6)[:, None]
    return (z > 0.1) & (np.linalg.norm(uv - img, axis=1) < reproj_px)


def choose_pose(candidates: dict[str, np.ndarray | None], obj: np.ndarray, img: np.ndarray, K: np.ndarray,
                reproj_px: float = 2.0) -> PoseGuess | None:
    """The candidate with the most reprojection inliers (ties: the order given)."""
    best = None
    for name, T in candidates.items():
        if T is None:
            continue
        n = int(reprojection_inliers(T, obj, img, K, reproj_px).sum())
        if best is None or n > best.inliers:
            best = PoseGuess(T, name, n)
    return best
