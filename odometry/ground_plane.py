"""Metric scale from the road: a camera mounted at a known height above the road sees the road as a
plane at that distance. Corners on the road, triangulated with a unit-length step, lie on a plane at
distance `h_unit`; the step's metric length is then `camera_height / h_unit`. This is the classical
scale source of monocular driving VO (libviso2's mono odometry, Song and Chandraker's ground-plane
scale) and needs no learnt depth, so it is free of the generator's bias.

The road is found as the mode of the triangulated points' heights below the camera among the nearer
half of the points (the road is the largest set of points at one height; kerbs, cars and walls are
not), then refined by a plane fit to the points near that mode."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np


@dataclass
class GroundFit:
    """The road plane of one step, in the first camera's frame at unit step length: n . X = height."""

    height: float  # distance from the camera centre to the road plane (unit-step scale)
    normal: np.ndarray  # unit normal pointing from the camera down to the road
    inliers: int  # corners on the plane


def road_corners(
    image: np.ndarray,
    K: np.ndarray,
    camera_height: float,
    max_corners: int = 600,
    corridor_m: float = 2.5,
    horizon_margin: float = 0.08,
) -> np.ndarray:
    """Corners of a gray image where a level camera sees the road in its own corridor: below the horizon
    (the principal point's row plus a margin) and within `corridor_m` of the camera's track sideways,
    a triangle from the vanishing point. Neighbouring lanes' vehicles stay mostly outside it. A low
    quality threshold: road texture is faint, and it is the only texture that gives the scale."""
    mask = _corridor_mask(
        image.shape[:2], tuple(np.asarray(K, float).ravel()), camera_height, corridor_m, horizon_margin
    )
    p = cv2.goodFeaturesToTrack(image, maxCorners=max_corners, qualityLevel=0.001, minDistance=5, mask=mask)
    return np.zeros((0, 2)) if p is None else p.reshape(-1, 2).astype(np.float64)


@lru_cache(maxsize=8)
def _corridor_mask(
    shape: tuple[int, int], K: tuple[float, ...], camera_height: float, corridor_m: float, horizon_margin: float
) -> np.ndarray:
    """The corridor of `road_corners` as an 8-bit mask; the same for every frame of a sequence, so built once."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w]
    below = v - K[5]
    inside = (below > horizon_margin * h) & (np.abs(u - K[2]) * camera_height <= below * corridor_m * K[0] / K[4])
    return inside.astype(np.uint8) * 255


def height_mode(h: np.ndarray, rel_band: float, second_share: float = 0.5) -> float:
    """The height with the most other heights within +-rel_band of it (h > 0, sorted search). The road
    is the lowest surface in view: a second cluster further down with at least `second_share` of the
    first's support wins (the first is then a car body or a low wall)."""
    hs = np.sort(h)

    def support(x: np.ndarray) -> np.ndarray:
        return np.searchsorted(hs, x * (1 + rel_band), "right") - np.searchsorted(hs, x * (1 - rel_band), "left")

    count = support(hs)
    best = int(np.argmax(count))
    lower = hs > hs[best] * (1 + 2 * rel_band)
    if lower.any():
        alt = int(np.argmax(np.where(lower, count, -1)))
        if count[alt] >= second_share * count[best]:
            best = alt
    return float(hs[best])


def fit_ground(
    X: np.ndarray, rel_band: float = 0.05, near_share: float = 0.6, max_tilt_deg: float = 10.0, min_inliers: int = 8
) -> GroundFit | None:
    """The road plane among unit-step triangulated points `X` (N x 3, first camera frame), or None
    when too few points lie on one. The camera is taken as level (image y pointing down to the road);
    the fitted normal may tilt from that by at most `max_tilt_deg` (the vehicle pitches and rolls a
    little, a wall or a car side is far off)."""
    n0 = np.array([0.0, 1.0, 0.0])
    X = X[np.isfinite(X).all(1) & (X[:, 2] > 0)]
    if len(X) < min_inliers:
        return None
    X = X[X[:, 2] <= np.quantile(X[:, 2], near_share)]  # far points are triangulated poorly
    h = X @ n0
    X, h = X[h > 0], h[h > 0]
    if len(X) < min_inliers:
        return None
    mode = height_mode(h, rel_band)
    on = np.abs(h - mode) < rel_band * mode
    if on.sum() < min_inliers:
        return None
    P = X[on]
    c = P.mean(0)
    normal = np.linalg.svd(P - c)[2][-1]
    normal = normal if normal @ n0 > 0 else -normal
    if normal @ n0 < np.cos(np.radians(max_tilt_deg)):  # the points near the mode are not a plane: keep the prior
        normal = n0
    height = float(normal @ c)
    return GroundFit(height, normal, int(on.sum())) if height > 0 else None
