"""Corners of a frame tracked into nearby frames of the recording, and each pair's motion read from them: the
essential matrix's rotation and direction, its length from the frame's own LiDAR returns at the corners. Shared
by motion stereo (`odometry.motion_stereo`: the corners triangulated) and the window graph's pair factors
(`pair_motions`), so that one frame's corners are tracked into each neighbour once.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from odometry.mono_vo import recover_pose

# Settings chosen on development data only (the clip's frames 0-37 and the simulator's Mid-40 validation drives;
# docs/decisions/0011-tuned-settings.md): fixed here, not a user's to tune.
MAX_CORNERS = 4000  # Shi-Tomasi corners per frame, at most ...
CORNER_QUALITY = 0.003  # ... their quality level (share of the strongest corner's) ...
CORNER_DISTANCE_PX = 4  # ... and distance apart (px), at least
LK_WINDOW_PX = 11  # pyramidal Lucas-Kanade: window (px) ...
LK_LEVELS = 3  # ... pyramid levels
LK_ITERATIONS = 20  # ... iterations
TRACK_CHECK_PX = 0.5  # forward-backward optical-flow agreement (px)
SCALE_RADIUS_PX = 2.0  # a tracked corner takes the LiDAR depth of a return this near, for a pair's length (px)
SCALE_MIN_POINTS = 10  # a pair with fewer LiDAR-backed corners (parallax > 2 px) is dropped


class GrayImages:
    """Grayscale images by frame index, read once through `load` and kept while they may still be needed.
    `load` returns None for an image it cannot read: that neighbour is left out here, and the frame's own
    turn in the run reports the file."""

    def __init__(self, load: Callable[[int], np.ndarray | None], keep: int) -> None:
        self.load, self.keep = load, keep
        self.images: OrderedDict[int, np.ndarray | None] = OrderedDict()

    def put(self, i: int, image: np.ndarray | None) -> None:
        self.images[i] = image if image is None or image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        self.images.move_to_end(i)
        while len(self.images) > self.keep:
            self.images.popitem(last=False)

    def __getitem__(self, i: int) -> np.ndarray | None:
        if i not in self.images:
            self.put(i, self.load(i))
        self.images.move_to_end(i)
        return self.images[i]


def track(g0: np.ndarray, g1: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corners of g0 in g1 (pyramidal Lucas-Kanade) and which of them came back within TRACK_CHECK_PX."""
    lk = dict(
        winSize=(LK_WINDOW_PX, LK_WINDOW_PX),
        maxLevel=LK_LEVELS,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, LK_ITERATIONS, 0.01),
    )
    if not len(corners):
        return corners.copy(), np.zeros(0, bool)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(g0, g1, corners, None, **lk)
    p0, st0, _ = cv2.calcOpticalFlowPyrLK(g1, g0, p1, None, **lk)
    ok = (st1[:, 0] == 1) & (st0[:, 0] == 1) & (np.linalg.norm(p0 - corners, axis=1) < TRACK_CHECK_PX)
    return p1, ok


def displacement_px(Rt: np.ndarray, X: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of points X (frame i) in the other view, and their distance from where a point at infinity
    in the same direction lands (the parallax the depth is read from)."""
    with np.errstate(all="ignore"):  # points at infinity (the linear solution's last coordinate near 0)
        p = (X @ Rt[:, :3].T + Rt[:, 3]) @ K.T
        q = (X @ Rt[:, :3].T) @ K.T
        uv, uv_inf = p[:, :2] / p[:, 2:3], q[:, :2] / q[:, 2:3]
    return uv, np.linalg.norm(uv - uv_inf, axis=1)


def essential_motion(c: np.ndarray, p: np.ndarray, ok: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """Frame i -> j as [R | t] (3 x 4, unit t) from the essential matrix of the tracked corners (c in i, p in j,
    `ok`: tracked); None with under 20 tracks or no essential matrix."""
    if ok.sum() < 20:
        return None
    E, inl = cv2.findEssentialMat(c[ok], p[ok], K, cv2.USAC_ACCURATE, 0.999, 0.5)
    if E is None or E.shape != (3, 3):
        return None
    _, R, t, _ = recover_pose(E, c[ok], p[ok], K, inl.ravel() > 0)
    return np.hstack([R, t / max(np.linalg.norm(t), 1e-12)])


def scaled_motion(
    Rt: np.ndarray,
    c: np.ndarray,
    p: np.ndarray,
    ok: np.ndarray,
    K: np.ndarray,
    lidar: np.ndarray,
) -> np.ndarray | None:
    """Frame i -> j as [R | t] (3 x 4): the essential matrix's rotation and direction `Rt` (`essential_motion`),
    its length from the LiDAR depths at the corners (`lidar`: one per corner, 0 = none; `returns_at`); None
    with too few LiDAR-backed corners."""
    Xh = cv2.triangulatePoints(K @ np.eye(3, 4), K @ Rt, c[ok].T.astype(np.float64), p[ok].T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = Xh[2] / Xh[3]
        X = (Xh[:3] / Xh[3]).T
    _, par = displacement_px(Rt, X, K)
    d = lidar[ok]
    use = (d > 0) & (z > 0) & (par > 2.0) & np.isfinite(z)
    if use.sum() < SCALE_MIN_POINTS:
        return None
    out = Rt.copy()
    out[:, 3] *= float(np.median(d[use] / z[use]))
    return out


def nearest_returns(sparse: np.ndarray, c: np.ndarray, radius_px: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel c (N x 2, rounded): the distance (px) to the nearest return of `sparse` and its depth,
    (inf, 0) when none lies within radius_px. A k-d tree on the returns: a distance transform of the whole
    image cost 26 ms a KITTI frame."""
    rv, ru = np.nonzero(sparse > 0)
    dist, depth = np.full(len(c), np.inf), np.zeros(len(c))
    if not len(rv) or not len(c):
        return dist, depth
    q = np.round(c).astype(np.float64)
    bound = radius_px + 1e-9 if np.isfinite(radius_px) else np.inf
    dist, k = cKDTree(np.column_stack([ru, rv]).astype(np.float64)).query(q, distance_upper_bound=bound)
    hit = np.isfinite(dist)
    depth[hit] = sparse[rv[k[hit]], ru[k[hit]]]
    return dist, depth


def returns_at(sparse: np.ndarray, c: np.ndarray, radius_px: float) -> np.ndarray:
    """The depth of the return nearest each pixel c (N x 2, rounded) when one lies within radius_px, else 0."""
    return nearest_returns(sparse, c, radius_px)[1]


def detect_corners(g0: np.ndarray) -> np.ndarray | None:
    """N x 2 float32 corners of a grayscale image (Shi-Tomasi), None when it has none."""
    found = cv2.goodFeaturesToTrack(g0, MAX_CORNERS, CORNER_QUALITY, CORNER_DISTANCE_PX)
    return None if found is None else found.reshape(-1, 2).astype(np.float32)


class FrameTracks:
    """Frame i's corners, the LiDAR depth at each and their tracks into neighbours with each pair's motion,
    computed once per neighbour: motion stereo and the pair motions both track into frame i - 2.

    Along the `ladder` (motion stereo's neighbours), a neighbour tracks only the corners that its rung before
    on the same side (the next nearer neighbour) tracked: a corner lost two frames away is rarely found again
    sixteen away, and the forward-backward check throws such a track out anyway. On both KITTI raw drives
    (Mid-40-like, every third frame) this halves the Lucas-Kanade time (223 -> 113 and 176 -> 109 ms a frame)
    with as many corners kept (609 -> 590, 455 -> 462) and the same error against the full scan. The nearest
    rung on each side and the neighbours off the ladder (the pair motions' frames i - 1, i - 3) track every
    corner."""

    def __init__(
        self,
        i: int,
        images: GrayImages,
        K: np.ndarray,
        own: np.ndarray | None,
        ladder: list[int] | tuple[int, ...] = (),
    ) -> None:
        self.i, self.images, self.K, self.ladder = i, images, K, tuple(ladder)
        g0 = images[i]
        self.g0 = g0
        self.corners = None if g0 is None else detect_corners(g0)
        self.lidar: np.ndarray | None = None
        # each rung's previous one: the next nearer ladder neighbour on the same side of frame i
        self.below: dict[int, int] = {}
        for side in (-1, 1):
            rungs = sorted((j for j in set(ladder) if (j - i) * side > 0), key=lambda j: abs(j - i))
            self.below.update(zip(rungs[1:], rungs[:-1]))
        self._tracked: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}  # j -> pixels in j, tracked
        self._motions: dict[int, np.ndarray | None] = {}  # j -> the essential matrix's [R | t], unit t
        self._pairs: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray] | None] = {}
        if own is not None:
            self.set_returns(own)

    def set_returns(self, own: np.ndarray) -> None:
        """The frame's own returns (sparse depth): the LiDAR depth at each corner, each pair's length. A frame
        without any has no pair length and no corner to triangulate."""
        if not (own > 0).any():
            self.corners = None
        self.lidar = None if self.corners is None else returns_at(own, self.corners, SCALE_RADIUS_PX)
        self._pairs = {}

    def track_into(self, neighbours: list[int]) -> None:
        """Track the corners into each neighbour and read each pair's rotation and direction: what needs only
        the images, so it can run before the frame's returns are known (`set_returns`)."""
        if self.corners is not None:
            for j in neighbours:
                self._motion(j)

    def _candidates(self, j: int) -> np.ndarray | None:
        """The corners neighbour j tracks (a boolean mask), None for every corner: those its nearest rung
        below with an image tracked."""
        k = self.below.get(j)
        while k is not None:
            found = self._track(k)
            if found is not None:
                return found[1]
            k = self.below.get(k)
        return None

    def _track(self, j: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The corners' pixels in frame j and which of them tracked; None when its image is missing."""
        if j not in self._tracked:
            g1 = self.images[j]
            found = None
            if g1 is not None and g1.shape == self.g0.shape:
                cand = self._candidates(j)
                if cand is None:
                    found = track(self.g0, g1, self.corners)
                else:
                    p, ok = self.corners.copy(), np.zeros(len(self.corners), bool)
                    p[cand], ok[cand] = track(self.g0, g1, self.corners[cand])
                    found = p, ok
            self._tracked[j] = found
        return self._tracked[j]

    def _motion(self, j: int) -> np.ndarray | None:
        """The essential matrix's [R | t] (unit t) of frame i -> j from the tracks; None without one."""
        if j not in self._motions:
            tracked = self._track(j)
            self._motions[j] = None if tracked is None else essential_motion(self.corners, *tracked, self.K)
        return self._motions[j]

    def pair(self, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """([R | t] of frame i -> j, the corners' pixels in j, which tracked), or None when the image is
        missing or the motion cannot be had (`essential_motion`, `scaled_motion`). Needs `set_returns`."""
        if self.corners is None:
            return None
        if self.lidar is None:
            raise ValueError("FrameTracks.pair needs the frame's returns (set_returns)")
        if j not in self._pairs:
            Rt = self._motion(j)
            found = None
            if Rt is not None:
                p, ok = self._tracked[j]
                Rt = scaled_motion(Rt, self.corners, p, ok, self.K, self.lidar)
                found = None if Rt is None else (Rt, p, ok)
            self._pairs[j] = found
        return self._pairs[j]


def pair_motions(
    i: int,
    neighbours: list[int],
    images: GrayImages,
    K: np.ndarray,
    own: np.ndarray,
    tracks: FrameTracks | None = None,
) -> dict[int, np.ndarray]:
    """Frame i's motion to each neighbour j as a 4 x 4 T_j_i (camera i's points into camera j): rotation and
    direction from the essential matrix of the tracked corners, length from the frame's own LiDAR returns
    (`essential_motion`, `scaled_motion`). Neighbours where either fails are left out. For the window graph: on the
    simulator's
    Mid-40 validation drives the essential matrix's rotation is 5x nearer the truth than the graph's own
    (median 0.03 against 0.14-0.34 degrees; docs/decisions/0006-pair-factors-cone-only.md). `tracks`: frame i's, to
    share with motion
    stereo (built here when None)."""
    if not neighbours:
        return {}
    tracks = FrameTracks(i, images, K, own) if tracks is None else tracks
    out = {}
    for j in neighbours:
        found = tracks.pair(j)
        if found is not None:
            out[j] = np.vstack([found[0], [0.0, 0.0, 0.0, 1.0]])
    return out
