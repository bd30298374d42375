"""Motion stereo: depth of image corners triangulated over the frames before and after, where a narrow
LiDAR never looks, and the generator's depth corrected towards them.

A cone LiDAR (Livox Mid-40, 38 degrees) covers half of an 81-degree camera; outside its cone the
generator only has one image to guess from, and on the real KITTI clip it put 40-60 m hedges at 7-10 m.
Over a recording the camera moves, so corners of frame i tracked into frames i +- offsets can be
triangulated. Each pair's rotation and direction come from the essential matrix of the tracks (the
graph's poses are not needed: on that clip a Mid-40 scan locks onto the car ahead and the graph's steps
are a quarter of the true length); its length is set by the frame's own LiDAR returns at the tracked
corners. A corner is kept when it has enough views and parallax, a small multi-view reprojection error
and neighbours that agree with it, and only where no LiDAR return lies near (the returns are better
there). The generator's depth then moves towards the corners around them (`corrected_depth`). Given to
the network as extra input instead, the corners helped the real clip more but made the simulator's
drives worse: a few wrong corners move whole regions there. Settings were chosen on development data
only, the clip's frames 0-37 and the simulator's Mid-40 validation drives; on with a cone LiDAR only
(docs/decisions/0005-motion-stereo-cone-only.md). `refine.motion_stereo` turns it on and sets the neighbours;
the rest are the constants below.
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from dataclasses import dataclass
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
MIN_VIEWS = 4  # views a corner needs, frame i included
MAX_RMS_PX = 0.7  # multi-view reprojection error (px), at most
MIN_PARALLAX_PX = 8.0  # the largest displacement against a point at infinity, over the views (px), at least
LIDAR_GAP_PX = 8.0  # a corner joins the input only this far from any LiDAR return (px)
SCALE_RADIUS_PX = 2.0  # a tracked corner takes the LiDAR depth of a return this near, for a pair's length (px)
SCALE_MIN_POINTS = 10  # a pair with fewer LiDAR-backed corners (parallax > 2 px) is dropped
MIN_DEPTH_M, MAX_DEPTH_M = 1.5, 150.0  # corners kept between these depths (m)
# a corner is kept when at least MIN_NEIGHBOURS other kept corners lie within NEIGHBOUR_RADIUS x focal length (px)
# and their median depth is within MAX_LOG_DIFF of its own (log): lone corners and outliers go
MIN_NEIGHBOURS = 2
NEIGHBOUR_RADIUS = 0.05
MAX_LOG_DIFF = 0.15
# corrected_depth: the corners' log ratio to the generator spread with sigma = SPREAD x focal length (px), over
# pixels whose generator depth is within about RANGE_LOG (log) of the corner's, fading where their summed weight
# is small against SUPPORT corners' worth; each ratio taken against the generator depth within EDGE_PX (px) that
# matches the corner best
SPREAD = 0.06
SUPPORT = 1.0
RANGE_LOG = 0.2
EDGE_PX = 2


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


def corner_reference(
    log_depth: np.ndarray, v: np.ndarray, u: np.ndarray, log_z: np.ndarray, radius_px: int
) -> np.ndarray:
    """The generator's log depth within radius_px of each corner that is closest to the corner's own: a
    corner found on an edge in the image belongs to the surface on its side of the edge, and the
    generator's edge may lie a pixel or two off the image's."""
    h, w = log_depth.shape
    dy, dx = np.mgrid[-radius_px : radius_px + 1, -radius_px : radius_px + 1].reshape(2, -1)
    cand = log_depth[np.clip(v[:, None] + dy, 0, h - 1), np.clip(u[:, None] + dx, 0, w - 1)]
    return cand[np.arange(len(v)), np.argmin(np.abs(cand - log_z[:, None]), axis=1)]


def corrected_depth(
    depth: np.ndarray, corners: np.ndarray, sigma_px: float, support: float, range_log: float = np.inf, edge_px: int = 0
) -> np.ndarray:
    """`depth` scaled near the triangulated corners by their log ratio to it, spread by normalised Gaussian
    convolution (sigma_px) and only over pixels whose generator depth is within about range_log (log) of the
    corner's (a cross-bilateral weight: a corner's ratio stays on its own surface, never carried across a
    depth edge onto a surface 20x farther); the correction fades out where the corners' summed weight is small
    against `support` (so a lone corner moves its neighbourhood only, never a whole empty region). Each
    corner's ratio is taken against the generator depth within edge_px that matches it best."""
    v, u = np.nonzero((corners > 0) & (depth > 0))
    if not len(v):
        return depth
    ld = np.log(np.maximum(depth, 1e-3)).astype(np.float32)
    lz = np.log(corners[v, u]).astype(np.float32)
    ref = corner_reference(ld, v, u, lz, edge_px) if edge_px > 0 else ld[v, u]
    h, w = depth.shape
    rad = int(np.ceil(2 * sigma_px))
    g = np.exp(-0.5 * (np.arange(-rad, rad + 1, dtype=np.float32) / sigma_px) ** 2)
    rs = np.zeros(depth.shape, np.float32)
    ws = np.zeros(depth.shape, np.float32)
    for vc, uc, r, lref in zip(v, u, lz - ref, ref):  # one window per corner (tens to hundreds of them)
        y0, y1, x0, x1 = max(vc - rad, 0), min(vc + rad + 1, h), max(uc - rad, 0), min(uc + rad + 1, w)
        wt = np.outer(g[y0 - vc + rad : y1 - vc + rad], g[x0 - uc + rad : x1 - uc + rad])
        if np.isfinite(range_log):
            wt = wt * np.exp(-0.5 * ((ld[y0:y1, x0:x1] - lref) / range_log) ** 2)
        rs[y0:y1, x0:x1] += wt * r
        ws[y0:y1, x0:x1] += wt
    return (depth * np.exp(rs / (ws + support))).astype(depth.dtype)
