"""The textbook monocular visual odometry, kept as the named baseline `mono_vo` that leovr's poses
must beat: Shi-Tomasi corners tracked by pyramidal Lucas-Kanade into the next frame, the essential
matrix by RANSAC, the relative pose recovered from it, every step given unit length (monocular: the
scale is unknown, so trajectories are compared after a Sim(3) alignment). Nothing learnt, no LiDAR,
no depth: what a user could write in thirty lines of OpenCV."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


def gray(image: np.ndarray) -> np.ndarray:
    """8-bit single-channel image (RGB float in [0, 1] or uint8, or already gray)."""
    img = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    return img


def corners(image: np.ndarray, max_corners: int = 2000) -> np.ndarray:
    """Shi-Tomasi corners of a gray image (N x 2, float64)."""
    p = cv2.goodFeaturesToTrack(image, maxCorners=max_corners, qualityLevel=0.01, minDistance=7)
    return np.zeros((0, 2)) if p is None else p.reshape(-1, 2).astype(np.float64)


def follow(prev: np.ndarray, cur: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where pyramidal Lucas-Kanade finds the points `p0` of `prev` in `cur` (N x 2), and which it found."""
    if not len(p0):
        return np.zeros((0, 2)), np.zeros(0, bool)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        prev, cur, p0.astype(np.float32).reshape(-1, 1, 2), None, winSize=(21, 21), maxLevel=3
    )
    return p1.reshape(-1, 2).astype(np.float64), st.ravel() == 1


def track(prev: np.ndarray, cur: np.ndarray, max_corners: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Corners of `prev` and where Lucas-Kanade finds them in `cur` (N x 2 each, tracked ones only)."""
    p0 = corners(prev, max_corners)
    if len(p0) < 8:
        return np.zeros((0, 2)), np.zeros((0, 2))
    p1, ok = follow(prev, cur, p0)
    return p0[ok], p1[ok]


def relative_motion(
    p0: np.ndarray, p1: np.ndarray, K: np.ndarray, threshold_px: float = 1.0, method: int = cv2.RANSAC
) -> tuple[np.ndarray | None, np.ndarray]:
    """Pose of the camera of the second frame in the first (4 x 4, unit translation) from the
    essential matrix of the tracks, and the inliers of the pose it recovered; None when too few
    tracks or no essential matrix. `method`: plain RANSAC (the textbook) or an OpenCV USAC variant."""
    inl = np.zeros(len(p0), bool)
    if len(p0) < 8:
        return None, inl
    E, mask = cv2.findEssentialMat(p1, p0, K, method=method, prob=0.999, threshold=threshold_px)
    if E is not None and E.shape[0] > 3:  # several solutions: the first, as OpenCV ranks them
        E = E[:3]
    if E is None or E.shape != (3, 3):
        return None, inl
    # OpenCV's (R, t) change the basis from the first camera given (here the second frame) to the
    # other: x_0 = R x_1 + t, i.e. the pose of the second camera in the first
    n, R, t, inl = recover_pose(E, p1, p0, K, mask.ravel() > 0)
    if n < 8:
        return None, np.zeros(len(p0), bool)
    T_0_1 = np.eye(4)
    T_0_1[:3, :3], T_0_1[:3, 3] = R, t.ravel() / max(np.linalg.norm(t), 1e-12)
    return T_0_1, inl


def recover_pose(
    E: np.ndarray,
    p1: np.ndarray,
    p0: np.ndarray,
    K: np.ndarray,
    inliers: np.ndarray,
    sample: int = 300,
    distance: float = 50.0,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """cv2.recoverPose with an inlier mask, faster: the pose among E's four whose triangulated points lie in front
    of both cameras (nearer than `distance` baselines), chosen on `sample` inliers spread over them (on all where
    none has half of them in front), then the inliers in front for that pose alone; OpenCV triangulates every match
    for all four. The same test as OpenCV's, on the same normalised coordinates: (count, R, t, which matches
    pass)."""
    x1 = np.c_[(p1[:, 0] - K[0, 2]) / K[0, 0], (p1[:, 1] - K[1, 2]) / K[1, 1]]
    x0 = np.c_[(p0[:, 0] - K[0, 2]) / K[0, 0], (p0[:, 1] - K[1, 2]) / K[1, 1]]

    def in_front(R: np.ndarray, t: np.ndarray, rows: np.ndarray) -> np.ndarray:
        P = np.hstack([R, t])
        Q = cv2.triangulatePoints(np.eye(3, 4), P, x1[rows].T, x0[rows].T)
        ok = Q[2] * Q[3] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            Q = Q / Q[3]
        ok &= Q[2] < distance
        z = (P @ Q)[2]
        return ok & (z > 0) & (z < distance)

    R1, R2, t = cv2.decomposeEssentialMat(E)
    rows = np.flatnonzero(inliers)
    if not len(rows):
        return 0, R1, t, np.zeros(len(p1), bool)
    sub = rows[np.linspace(0, len(rows) - 1, min(len(rows), sample)).astype(int)]
    poses = [(R1, t), (R2, t), (R1, -t), (R2, -t)]  # OpenCV's order: the first of equal counts wins
    fronts = [in_front(R, t, sub) for R, t in poses]
    if max(f.sum() for f in fronts) < 0.5 * len(sub):  # no clear winner (the camera barely moves): every inlier decides
        sub, fronts = rows, [in_front(R, t, rows) for R, t in poses]
    best = int(np.argmax([f.sum() for f in fronts]))
    out = np.zeros(len(p1), bool)
    out[rows] = fronts[best] if sub is rows else in_front(*poses[best], rows)
    return int(out.sum()), *poses[best], out


@dataclass
class MonoVO:
    """Frame-by-frame textbook VO: `add(image)` returns the camera-to-world pose of that frame (the
    first frame is the world). A frame whose motion cannot be recovered repeats the last motion."""

    K: np.ndarray
    poses: list[np.ndarray] = field(default_factory=list)
    _prev: np.ndarray | None = None
    _last: np.ndarray = field(default_factory=lambda: np.eye(4))

    def add(self, image: np.ndarray) -> np.ndarray:
        cur = gray(image)
        if self._prev is None:
            self.poses.append(np.eye(4))
        else:
            p0, p1 = track(self._prev, cur)
            motion, _ = relative_motion(p0, p1, self.K)
            if motion is not None:
                self._last = motion
            self.poses.append(self.poses[-1] @ self._last)
        self._prev = cur
        return self.poses[-1]


def mono_vo_poses(images, K: np.ndarray) -> np.ndarray:
    """F x 4 x 4 camera-to-world poses of the textbook VO over an iterable of images."""
    vo = MonoVO(K)
    for img in images:
        vo.add(img)
    return np.stack(vo.poses)
