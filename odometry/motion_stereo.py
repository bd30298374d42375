"""Motion stereo: depth of image corners triangulated over the frames before and after, where a narrow
LiDAR never looks, and the generator's depth corrected towards them.

A cone LiDAR (Livox Mid-40, 38 degrees) covers half of an 81-degree camera; outside its cone the
generator only has one image to guess from, and on the real KITTI clip it put 40-60 m hedges at 7-10 m.
Over a recording the camera moves, so corners of frame i tracked into frames i +- offsets can be
triangulated. Each pair's rotation and direction come from the essential matrix of the tracks (the
graph's poses are not needed: on that clip a Mid-40 scan locks onto the car ahead and the graph's steps
are a quarter of the true length); its length is set by the frame's own LiDAR returns at the tracked
corners (`odometry.frame_tracks`). A corner is kept when it has enough views and parallax, a small multi-view
reprojection error and neighbours that agree with it, and only where no LiDAR return lies near (the returns are
better there). The generator's depth then moves towards the corners around them (`odometry.corner_correction`).
Given to the network as extra input instead, the corners helped the real clip more but made the simulator's
drives worse: a few wrong corners move whole regions there. Settings were chosen on development data
only, the clip's frames 0-37 and the simulator's Mid-40 validation drives; on with a cone LiDAR only
(docs/decisions/0005-motion-stereo-cone-only.md). `refine.motion_stereo` turns it on and sets the neighbours;
the rest are the constants below and those of the two modules named.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from odometry.frame_tracks import FrameTracks, GrayImages, displacement_px, nearest_returns

# Settings chosen on development data only (the clip's frames 0-37 and the simulator's Mid-40 validation drives;
# docs/decisions/0011-tuned-settings.md): fixed here, not a user's to tune.
MIN_VIEWS = 4  # views a corner needs, frame i included
MAX_RMS_PX = 0.7  # multi-view reprojection error (px), at most
MIN_PARALLAX_PX = 8.0  # the largest displacement against a point at infinity, over the views (px), at least
LIDAR_GAP_PX = 8.0  # a corner joins the input only this far from any LiDAR return (px)
MIN_DEPTH_M, MAX_DEPTH_M = 1.5, 150.0  # corners kept between these depths (m)
# a corner is kept when at least MIN_NEIGHBOURS other kept corners lie within NEIGHBOUR_RADIUS x focal length (px)
# and their median depth is within MAX_LOG_DIFF of its own (log): lone corners and outliers go
MIN_NEIGHBOURS = 2
NEIGHBOUR_RADIUS = 0.05
MAX_LOG_DIFF = 0.15


def triangulate(
    c: np.ndarray, views: list[tuple[np.ndarray, np.ndarray, np.ndarray]], K: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points (frame i) from corners c seen in frame i and in `views` ([R | t], pixels, tracked), by the
    linear multi-view method on normalised coordinates; with each point's reprojection RMS (px), largest
    parallax (px) and number of views."""
    Ki = np.linalg.inv(K)
    Ps = np.stack([np.eye(3, 4)] + [v[0] for v in views])  # V x 3 x 4
    px = np.stack([c] + [v[1] for v in views], 1).astype(np.float64)  # n x V x 2
    ok = np.stack([np.ones(len(c), bool)] + [v[2] for v in views], 1)
    xn = np.concatenate([px, np.ones(px.shape[:2] + (1,))], 2) @ Ki.T
    rows = np.concatenate(
        [xn[:, :, 0:1] * Ps[None, :, 2] - Ps[None, :, 0], xn[:, :, 1:2] * Ps[None, :, 2] - Ps[None, :, 1]], 1
    )
    A = rows * np.concatenate([ok, ok], 1)[..., None]
    X = np.linalg.svd(A)[2][:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = X[:, :3] / X[:, 3:4]
    err = np.zeros(ok.shape)
    par = np.zeros(ok.shape)
    front = np.ones(len(c), bool)
    for k in range(len(Ps)):
        uv, par[:, k] = displacement_px(Ps[k], X, K)
        err[:, k] = np.linalg.norm(uv - px[:, k], axis=1)
        with np.errstate(all="ignore"):
            front &= ~ok[:, k] | ((X @ Ps[k, :, :3].T + Ps[k, :, 3])[:, 2] > 0)
    nv = ok.sum(1)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt((np.where(ok, np.nan_to_num(err, nan=np.inf), 0.0) ** 2).sum(1) / nv)
    rms = np.where(front & np.isfinite(rms), rms, np.inf)
    return X, rms, np.where(ok, np.nan_to_num(par), 0.0).max(1), nv


@dataclass
class Corners:
    """Triangulated corners of one frame: pixel, depth (m), reprojection RMS (px), parallax (px), views."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    rms: np.ndarray
    parallax: np.ndarray
    views: np.ndarray

    def __len__(self) -> int:
        return len(self.z)

    def take(self, sel: np.ndarray) -> "Corners":
        return Corners(*(x[sel] for x in (self.u, self.v, self.z, self.rms, self.parallax, self.views)))


def triangulated_corners(
    i: int,
    neighbours: list[int],
    images: GrayImages,
    K: np.ndarray,
    own: np.ndarray,
    tracks: FrameTracks | None = None,
) -> Corners:
    """Frame i's corners tracked into its neighbours and triangulated; all of them, before the tests."""
    none = Corners(*(np.zeros(0, t) for t in (int, int, float, float, float, int)))
    if not neighbours:
        return none
    tracks = FrameTracks(i, images, K, own, neighbours) if tracks is None else tracks
    views = [found for found in map(tracks.pair, neighbours) if found is not None]
    if not views:
        return none
    c = tracks.corners
    X, rms, par, nv = triangulate(c, views, K)
    u, v = np.round(c[:, 0]).astype(int), np.round(c[:, 1]).astype(int)
    inside = (u >= 0) & (u < own.shape[1]) & (v >= 0) & (v < own.shape[0])
    return Corners(u, v, X[:, 2], rms, par, nv).take(inside)


def agree_with_neighbours(c: Corners, radius_px: float, min_neighbours: int, max_log_diff: float) -> np.ndarray:
    """Which corners have min_neighbours others within radius_px whose median log depth is near their own."""
    if min_neighbours <= 0:
        return np.ones(len(c), bool)
    if len(c) <= min_neighbours:
        return np.zeros(len(c), bool)
    xy = np.column_stack([c.u, c.v]).astype(float)
    _, idx = cKDTree(xy).query(xy, k=min(9, len(c)), distance_upper_bound=radius_px)
    lz = np.append(np.log(c.z), np.nan)
    nb = lz[idx[:, 1:]]  # idx == len(c): no neighbour
    count = np.isfinite(nb).sum(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: no neighbour at all
        med = np.nanmedian(nb, axis=1)
    return (count >= min_neighbours) & (np.abs(lz[:-1] - med) < max_log_diff)


def motion_stereo_depth(
    i: int,
    neighbours: list[int],
    images: GrayImages,
    K: np.ndarray,
    own: np.ndarray,
    seen: np.ndarray | None = None,
    tracks: FrameTracks | None = None,
) -> np.ndarray:
    """Frame i's triangulated corners that pass the tests, as a sparse depth map (0 = none), only where no
    LiDAR return of `seen` (default: `own`, the frame's own returns, which set each pair's length) lies
    within LIDAR_GAP_PX. `tracks`: frame i's, to share with the pair motions."""
    out = np.zeros(own.shape, np.float32)
    c = triangulated_corners(i, neighbours, images, K, own, tracks)
    if not len(c):
        return out
    with np.errstate(invalid="ignore"):
        keep = (
            (c.views >= MIN_VIEWS)
            & (c.rms < MAX_RMS_PX)
            & (c.parallax > MIN_PARALLAX_PX)
            & (c.z > MIN_DEPTH_M)
            & (c.z < MAX_DEPTH_M)
        )
    c = c.take(keep)
    c = c.take(agree_with_neighbours(c, NEIGHBOUR_RADIUS * float(K[0, 0]), MIN_NEIGHBOURS, MAX_LOG_DIFF))
    far = nearest_returns(own if seen is None else seen, np.column_stack([c.u, c.v]))[0] > LIDAR_GAP_PX
    out[c.v[far], c.u[far]] = c.z[far]
    return out


def neighbour_frames(i: int, selected: list[int], offsets: list[int], causal: bool = False) -> list[int]:
    """The frames i - o and i + o of the run's selection (i - o only, `causal`), nearest first."""
    have = set(selected)
    return [j for o in offsets for j in ((i - o,) if causal else (i - o, i + o)) if j in have]
