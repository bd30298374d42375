"""The camera motion over a LiDAR sweep, for deskewing it, read from the images at both ends.

A simulated (and a Velodyne-style) sweep of frame k lasts from frame k's camera time to frame k+1's. A
constant-velocity guess (the last estimated step, k-1 -> k) is wrong exactly where it matters: where the
vehicle starts or ends a turn, at 80 km/h up to 13 degrees of yaw within one sweep. In a recorded sequence
the next image is already on disk, so the sweep's rotation can come from the ORB matches between images k
and k+1 (ORB survives large rotations where Lucas-Kanade tracks do not).

The essential matrix of those matches gives the rotation, but not the direction of travel: with a narrow
view and a forward motion a small yaw mimics a sideways step, and on a straight real drive more matches can
agree with a sideways direction than with the true one.
A car does not move sideways: it drives along an arc, and the chord of an arc turning by a rotation R points
along the heading turned by half of R. So the direction of travel is the last step's, taken back to the
heading by half the last step's rotation and turned by half the new one; the rotation is fitted to the
matches with that direction held (robust Sampson distance), starting from the essential matrix's; the step
length, which one image pair cannot give, stays the last step's. Where the last step's direction is itself wrong
(the first step, from two raw scans) the fitted rotation bends with it, and the essential matrix's own motion,
which then clearly more matches agree with, takes over. A cone LiDAR's sweep keeps the last step (or the
essential matrix's motion where clearly more matches agree with it): on the real drive the arc did not help it
(docs/decisions/0018-sweep-motion-on-an-arc.md)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from odometry.features import Features, detect, match
from odometry.mono_motion import rotation_parallax, sampson_px
from odometry.mono_vo import relative_motion


AGREE_PX = 1.0  # a match agrees with a motion within this epipolar (Sampson) distance
ESSENTIAL_MARGIN = 1.5  # how many times more matches the essential matrix's motion needs to take over from the arc's
MIN_ARC_STEP_M = 0.1  # a last step shorter than this (pulling away from a stop) has no reliable direction to hold


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
    seen: ImagesMotion, K: np.ndarray, velocity: np.ndarray | None, along_arc: bool = True
) -> np.ndarray | None:
    """Pose of the camera at the next image in the camera at this one (4 x 4), to deskew this frame's sweep.
    `velocity`: the last estimated step (same convention). With `along_arc` (a spinning LiDAR) the images'
    rotation with the direction of travel on the last step's arc and its length, else (a cone) the last step
    itself (so is a step under `MIN_ARC_STEP_M`); either way the essential matrix's own motion, at the last step's
    length (standing: its rotation alone), where `ESSENTIAL_MARGIN` times more matches agree with it. The rotation
    alone when there is no last step. Where the images give no motion, or the last step is kept, it returns the
    `velocity` object itself: callers tell a sweep motion read from the images by identity (KISS-ICP's prediction
    in `leovr refine`)."""
    if seen.motion is None:
        return velocity
    essential = np.eye(4)
    essential[:3, :3] = seen.motion[:3, :3]
    if velocity is None:
        return essential
    length = float(np.linalg.norm(velocity[:3, 3]))
    t = seen.motion[:3, 3]
    essential[:3, 3] = length * (t if t @ velocity[:3, 3] >= 0 else -t)
    # a step too short to have a direction of its own (pulling away) holds no arc
    base = on_arc(seen, K, velocity) if along_arc and length >= MIN_ARC_STEP_M else velocity
    agree = [_agree(T, seen.uv0, seen.uv1, K) for T in (essential, base)]
    return essential if agree[0] > ESSENTIAL_MARGIN * agree[1] else base


def on_arc(seen: ImagesMotion, K: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The images' rotation, fitted with the direction of travel held on the arc of the last step `velocity`
    (heading: its direction turned back by half its rotation; the new direction: the heading turned by half the
    new rotation), at the last step's length."""
    length = float(np.linalg.norm(velocity[:3, 3]))
    heading = half_rotation(velocity[:3, :3]).T @ (velocity[:3, 3] / length)
    R = seen.motion[:3, :3]
    for _ in range(2):  # the direction turns with half the fitted rotation: fit again with it
        R = rotation_along(R, half_rotation(R) @ heading, seen.uv0, seen.uv1, K)
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = length * (half_rotation(R) @ heading)
    return out


def _agree(T: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray) -> int:
    """How many matches the motion T explains: epipolar distance under `AGREE_PX`, or, standing (no translation
    to tell apart), the rotation's own mapping within 3 `AGREE_PX`."""
    if np.linalg.norm(T[:3, 3]) < 1e-6:
        return int(np.sum(rotation_parallax(uv0, uv1, T[:3, :3].T, K) < 3 * AGREE_PX))
    return int(np.sum(sampson_px(T, uv0, uv1, K) < AGREE_PX))


def half_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation by half the angle of R about the same axis."""
    return Rotation.from_rotvec(Rotation.from_matrix(R).as_rotvec() / 2).as_matrix()


def rotation_along(
    R0: np.ndarray, direction: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray
) -> np.ndarray:
    """The rotation (from R0) whose motion along the unit `direction` the matches agree with best: least squares
    on their Sampson distance, Cauchy-robust at 1 px (movers and bad matches fall out)."""
    T = np.eye(4)
    T[:3, 3] = direction

    def residuals(w: np.ndarray) -> np.ndarray:
        T[:3, :3] = Rotation.from_rotvec(w).as_matrix() @ R0
        return sampson_px(T, uv0, uv1, K)

    fit = least_squares(residuals, np.zeros(3), loss="cauchy", f_scale=1.0)
    return Rotation.from_rotvec(fit.x).as_matrix() @ R0
