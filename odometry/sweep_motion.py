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

from dataclasses import dataclass

import cv2
import numpy as np

from odometry.features import Features, detect, match
from odometry.mono_motion import rotation_parallax, sampson_px
from odometry.mono_vo import relative_motion


@dataclass
class ImagesMotion:
    """What two images say of the camera's motion between them: rotation and direction of travel (4 x 4,
    unit translation; None where the essential matrix failed) and the matches it was read from."""

    motion: np.ndarray | None
    uv0: np.ndarray
    uv1: np.ndarray


class SweepMotion:
    """`images_motion` over a sequence, each image's features detected once (kept for the next call)."""

    def __init__(self, n_features: int = 2000) -> None:
        self.n_features = n_features
        self._feats: dict[int, Features] = {}

    def __call__(
        self, index: int, image: np.ndarray, next_index: int, next_image: np.ndarray, K: np.ndarray
    ) -> ImagesMotion:
        a = self._feats.pop(index, None) or detect(image, self.n_features)
        b = detect(next_image, self.n_features)
        self._feats = {next_index: b}
        return images_motion(a, b, K)


def images_motion(a: Features, b: Features, K: np.ndarray) -> ImagesMotion:
    """The motion between the images of features `a` and `b`: ORB matches, essential matrix (USAC_ACCURATE);
    the part of `sweep_motion` that does not depend on the last step, so it can run ahead of it."""
    ia, ib = match(a, b)
    uv0, uv1 = a.uv[ia].astype(np.float64), b.uv[ib].astype(np.float64)
    motion, inl = relative_motion(uv0, uv1, K, method=cv2.USAC_ACCURATE)
    return ImagesMotion(motion if motion is not None and inl.sum() >= 20 else None, uv0, uv1)


def sweep_motion(
    seen: ImagesMotion, K: np.ndarray, velocity: np.ndarray | None, agree_px: float = 1.0, margin: float = 1.5
) -> np.ndarray | None:
    """Pose of the camera at the next image in the camera at this one (4 x 4), to deskew this frame's
    sweep: the images' motion `seen` (its length from `velocity`, the last estimated step in the same
    convention; rotation only when None) or `velocity` itself, whichever `margin` times more ORB matches
    between the images agree with. Where it keeps the last step it returns the `velocity` object itself:
    callers tell an overruled step by identity (KISS-ICP's prediction in `leovr refine`)."""
    if seen.motion is None:
        return velocity
    out = np.eye(4)
    out[:3, :3] = seen.motion[:3, :3]
    if velocity is None:
        return out
    step = velocity[:3, 3]
    t = seen.motion[:3, 3]
    direction = t if t @ step >= 0 else -t  # sign: movers can carry its vote
    out[:3, 3] = float(np.linalg.norm(step)) * direction
    uv0, uv1 = seen.uv0, seen.uv1
    return out if _agree(out, uv0, uv1, K, agree_px) > margin * _agree(velocity, uv0, uv1, K, agree_px) else velocity


def _agree(T: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray, px: float) -> int:
    """How many matches the motion T explains: epipolar distance under `px`, or, standing (no translation
    to tell apart), the rotation's own mapping within 3 `px`."""
    if np.linalg.norm(T[:3, 3]) < 1e-6:
        return int(np.sum(rotation_parallax(uv0, uv1, T[:3, :3].T, K) < 3 * px))
    return int(np.sum(sampson_px(T, uv0, uv1, K) < px))
