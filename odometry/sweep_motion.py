"""The camera motion over a LiDAR sweep, for deskewing it, read from the images at both ends.

A simulated (and a Velodyne-style) sweep of frame k lasts from frame k's camera time to frame k+1's. A
constant-velocity guess (the last estimated step, k-1 -> k) is wrong exactly where it matters: where the
vehicle starts or ends a turn, at 80 km/h up to 13 degrees of yaw within one sweep. In a recorded sequence
the next image is already on disk, so the sweep's rotation and direction of travel can come from the
essential matrix between images k and k+1 (ORB matches, which survive large rotations where Lucas-Kanade
tracks do not; USAC_ACCURATE); the step length, which one image pair cannot give, stays the last
estimated one. The constant-velocity guess and the images' motion are both candidates: the one that more
matches agree with (epipolar distance under `agree_px`) deskews the sweep."""

from __future__ import annotations

import cv2
import numpy as np

from odometry.features import Features, detect, match
from odometry.mono_motion import sampson_px
from odometry.mono_vo import relative_motion


class SweepMotion:
    """`sweep_motion` over a sequence, each image's features detected once (kept for the next call)."""

    def __init__(self, n_features: int = 2000, agree_px: float = 1.0, speed_steps: int = 1,
                 margin: float = 1.5) -> None:
        self.n_features, self.agree_px, self.speed_steps, self.margin = n_features, agree_px, speed_steps, margin
        self._feats: dict[int, Features] = {}
        self._lengths: list[float] = []

    def __call__(self, index: int, image: np.ndarray, next_index: int, next_image: np.ndarray, K: np.ndarray,
                 velocity: np.ndarray | None) -> np.ndarray | None:
        a = self._feats.pop(index, None) or detect(image, self.n_features)
        b = detect(next_image, self.n_features)
        self._feats = {next_index: b}
        if velocity is not None and self.speed_steps > 1:  # the step length, averaged over the last steps
            self._lengths = (self._lengths + [float(np.linalg.norm(velocity[:3, 3]))])[-self.speed_steps:]
            velocity = velocity.copy()
            velocity[:3, 3] *= np.mean(self._lengths) / max(self._lengths[-1], 1e-9)
        return sweep_motion(a, b, K, velocity, self.agree_px, self.margin)


def sweep_motion(a: Features, b: Features, K: np.ndarray, velocity: np.ndarray | None,
                 agree_px: float = 1.0, margin: float = 1.0) -> np.ndarray | None:
    """Pose of the camera at the next image in the camera at this one (4 x 4), to deskew this frame's
    sweep, from the two images' features `a` and `b`: the images' motion (its length from `velocity`, the
    last estimated step in the same convention; rotation only when None) or `velocity` itself, whichever
    more ORB matches between the images agree with."""
    ia, ib = match(a, b)
    uv0, uv1 = a.uv[ia].astype(np.float64), b.uv[ib].astype(np.float64)
    motion, inl = relative_motion(uv0, uv1, K, method=cv2.USAC_ACCURATE)
    if motion is None or inl.sum() < 20:
        return velocity
    seen = np.eye(4)
    seen[:3, :3] = motion[:3, :3]
    if velocity is None:
        return seen
    step = velocity[:3, 3]
    direction = motion[:3, 3] if motion[:3, 3] @ step >= 0 else -motion[:3, 3]  # sign: movers can carry its vote
    seen[:3, 3] = float(np.linalg.norm(step)) * direction
    if np.linalg.norm(step) < 1e-6:  # standing: only the rotation can be told apart
        return seen if _agree(seen, uv0, uv1, K, agree_px, rotation_only=True) > margin * _agree(
            velocity, uv0, uv1, K, agree_px, rotation_only=True) else velocity
    return seen if _agree(seen, uv0, uv1, K, agree_px) > margin * _agree(velocity, uv0, uv1, K, agree_px) else velocity


def _agree(T: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray, px: float, rotation_only: bool = False) -> int:
    """How many matches the motion T explains: epipolar distance under `px`, or with no translation the
    rotation's own mapping within `px`."""
    if rotation_only or np.linalg.norm(T[:3, 3]) < 1e-9:
        H = K @ T[:3, :3].T @ np.linalg.inv(K)
        p = np.c_[uv0, np.ones(len(uv0))] @ H.T
        return int(np.sum(np.linalg.norm(p[:, :2] / p[:, 2:3] - uv1, axis=1) < 3 * px))
    return int(np.sum(sampson_px(T, uv0, uv1, K) < px))
