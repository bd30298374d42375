"""Depth outside a cone LiDAR's reach from the images: a coarse photometric correction of a frame's refined depth.

Outside a Mid-40's cone the correction field of the window graph has almost nothing to go by (a few motion
stereo corners), and the generator guesses from one image. With the graph's poses, the frame's neighbours
tell which depth is right: warped into the frame with the right depth, a textured patch matches. For every
node of a coarse grid left without LiDAR returns, a plane sweep over a log-depth offset (a few candidates
around the refined depth) sums the patches' ZNCC cost over the node's pixels (bilinear weights), in every
neighbour; the best candidate (sub-step by a parabola) is kept when it lowers the cost by MIN_GAIN against
no change and against a depth far beyond the span (what a vehicle driving along with the camera looks like).
The kept offsets are upsampled bilinearly and multiply the refined depth. Nodes with LiDAR
returns keep the graph's depth (there the returns are better, and the photometric choice made them worse on
the development drives), and they check the poses and the images: most of them (MIN_BACKED_SHARE) must have a
clear valley, and there they should choose no change; otherwise, or when their median choice is off by more than
MAX_BIAS_LOG, the frame keeps the graph's depth (on the real KITTI clip a quarter of them had a clear valley,
their choice read the depth 5-40 % too far, and the sweep made 35 of the 38 development frames worse). Run when a
frame leaves the window, with the poses it leaves with (final before it, the window's after it). Settings
chosen on development data only: the simulator's Mid-40 validation drives and the KITTI clip's frames 0-37
(docs/decisions/0007-photometric-field-cone-only.md). `refine.photometric` turns it on and sets the neighbours;
the rest are the constants below.
"""

from __future__ import annotations

import cv2
import numpy as np

from odometry.depth_field import CorrectionGrid

# Settings chosen on development data only (docs/decisions/0007-photometric-field-cone-only.md, the figures in
# docs/decisions/0011-tuned-settings.md): fixed here, not a user's to tune.
ROWS, COLS = 16, 28  # the correction's grid (nodes), corner to corner, finer than the graph's 8 x 14
# candidates: log offsets in [-SPAN_LOG, SPAN_LOG], 0.2 apart (odd count: 0 is one); a parabola through the best
# and its neighbours refines it
SPAN_LOG = 0.8
CANDIDATES = 9
PATCH_PX = 2  # ZNCC window half size, at the working scale
MIN_TEXTURE = 4.0  # gray-level variance in the window: flatter patches do not vote
MIN_PIXELS = 30  # a node needs this much (bilinear) weight of voting pixels for every candidate
MIN_GAIN = 0.05  # a node moves only when its best candidate's mean ZNCC cost is this much below no change
MIN_DEPTH_M = 0.5  # pixels nearer than this (m) do not vote
MIN_BACKED = 5  # nodes with returns and a clear choice needed to check the poses ...
# ... and this share of the seen nodes with returns: where the images pin the depth at few of the nodes whose
# depth is known, the check rests on little and the sweep's choices elsewhere are no better
MIN_BACKED_SHARE = 0.5
MAX_BIAS_LOG = 0.1  # their median choice may be this far from 0 (a step length read wrong, a turn misread)
# the sweep runs on images made smaller by the integer factor that brings them nearest this many pixels (448 x
# 256: 2, KITTI's 1242 x 375: 4; the patch size is at that scale)
SWEEP_PIXELS = 30000
# a far candidate (depth x e^FAR_LOG, ~20x: as good as infinity) that a moved node's best must beat by FAR_GAIN:
# a vehicle driving along with the camera matches best at infinity, and without this test its nodes were pushed
# to the span's far end; 0: off
FAR_LOG = 3.0
FAR_GAIN = 0.05


def _box(x: np.ndarray, k: int) -> np.ndarray:
    return cv2.boxFilter(x, -1, (2 * k + 1, 2 * k + 1), borderType=cv2.BORDER_REFLECT)


class _Votes:
    """Per-node sums of the pixels' costs and weights, as sparse bilinear weights of a fixed image size."""

    def __init__(self, grid: CorrectionGrid) -> None:
        u, v = np.meshgrid(np.arange(grid.width, dtype=np.float64), np.arange(grid.height, dtype=np.float64))
        self.BT = grid.sparse_weights(u.ravel(), v.ravel()).T.tocsr()

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Per node, the weighted sum of each column of P x C pixel values (P = H x W, row by row)."""
        return self.BT @ values


_votes_cache: dict[CorrectionGrid, _Votes] = {}


def _working_scale(
    depth: np.ndarray,
    gray: np.ndarray,
    neighbours: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """Depth, images and intrinsics at the sweep's working resolution (about SWEEP_PIXELS pixels): the depth
    sampled at the pixel centres, the images area-averaged."""
    f = max(int(round(np.sqrt(depth.size / SWEEP_PIXELS))), 1)
    if f > 1:  # pixel centres: (x + 0.5) / f - 0.5

        def small(im: np.ndarray) -> np.ndarray:
            return cv2.resize(im, (im.shape[1] // f, im.shape[0] // f), interpolation=cv2.INTER_AREA)

        depth = depth[f // 2 :: f, f // 2 :: f][: depth.shape[0] // f, : depth.shape[1] // f]
        gray, neighbours = small(gray), [(small(im), T) for im, T in neighbours]
        K = np.array(
            [[K[0, 0] / f, 0, (K[0, 2] + 0.5) / f - 0.5], [0, K[1, 1] / f, (K[1, 2] + 0.5) / f - 0.5], [0, 0, 1]]
        )
    return depth, gray, neighbours, K


def _reflected(x: np.ndarray, n: int) -> np.ndarray:
    """Coordinates (float32) where cv2.remap with BORDER_REFLECT samples what it samples at `x` along an axis of
    `n` pixels: the reflection repeats every 2n pixels, and OpenCV finds a coordinate far outside (a point behind
    the camera lands 1e5-1e8 px out) by reflecting it back one period at a time, 0.6 ms a 448 x 256 warp
    against 0.05. Exact below 2^31 px; beyond, OpenCV's integer pixel overflows and its own sample is garbage."""
    far = (x < -n) | (x >= 2 * n)
    if not far.any():
        return x
    x = x.copy()
    X = x[far].astype(np.float64)  # in float32 the period count would be rounded
    x[far] = X - 2.0 * n * np.floor(X / (2.0 * n))
    return x


def _sweep_costs(
    depth: np.ndarray,
    gray: np.ndarray,
    neighbours: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
) -> tuple[CorrectionGrid, np.ndarray, np.ndarray, np.ndarray]:
    """The grid, the candidate log offsets (the far candidate last when FAR_LOG) and, per candidate and
    node, the summed patch cost (1 - ZNCC with each neighbour's image warped by the scaled depth) and the
    number of pixels that saw it."""
    h, w = depth.shape
    grid = CorrectionGrid(ROWS, COLS, h, w)
    votes = _votes_cache.setdefault(grid, _Votes(grid))
    k = PATCH_PX
    a = gray.astype(np.float32)
    ma = _box(a, k)
    va = _box(a * a, k) - ma * ma
    fx, fy, cx, cy = (np.float32(K[r, c]) for r, c in ((0, 0), (1, 1), (0, 2), (1, 2)))
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    rays = np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones_like(uu)], -1) * depth[..., None].astype(np.float32)
    cands = np.linspace(-SPAN_LOG, SPAN_LOG, CANDIDATES)
    if FAR_LOG:
        cands = np.append(cands, FAR_LOG)
    nc = len(cands)
    cost = np.zeros((nc, grid.size))
    weight = np.zeros((nc, grid.size))
    inner = (uu > k) & (uu < w - 1 - k) & (vv > k) & (vv < h - 1 - k)
    textured = (va > MIN_TEXTURE) & (depth > 0) & inner
    for img, T in neighbours:
        b_img = img.astype(np.float32)
        A = rays @ T[:3, :3].T.astype(np.float32)  # rotated rays x depth; the candidates only scale them
        Ax, Ay, Az = (np.ascontiguousarray(A[..., c]) for c in range(3))
        t = T[:3, 3].astype(np.float32)
        per_pixel = np.empty((h * w, 2 * nc))  # per candidate: the pixels' costs, then whether each saw it
        for n, c in enumerate(cands):
            e = np.float32(np.exp(c))
            z = Az * e + t[2]
            zs = np.maximum(z, 1e-3)
            u2 = fx * (Ax * e + t[0]) / zs + cx
            v2 = fy * (Ay * e + t[1]) / zs + cy
            b = cv2.remap(b_img, _reflected(u2, w), _reflected(v2, h), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            ok = textured & (z > MIN_DEPTH_M) & (u2 > k) & (u2 < w - 1 - k) & (v2 > k) & (v2 < h - 1 - k)
            mb = _box(b, k)
            vb = _box(b * b, k) - mb * mb
            cab = _box(a * b, k) - ma * mb
            zncc = cab / np.sqrt(np.maximum(va * vb, 1e-6))
            ok &= vb > 1e-3
            per_pixel[:, n] = np.where(ok, 1.0 - zncc, 0.0).ravel()
            per_pixel[:, nc + n] = ok.ravel()
        summed = votes(per_pixel)
        cost += summed[:, :nc].T
        weight += summed[:, nc:].T
    return grid, cands, cost, weight


def photometric_offsets(
    depth: np.ndarray,
    gray: np.ndarray,
    neighbours: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
    free: np.ndarray,
    stats: dict | None = None,
) -> np.ndarray:
    """Per-node log offsets (grid ROWS x COLS, flat) for a frame's depth (H x W, 0 = unknown).
    `gray`: the frame's image (H x W); `neighbours`: (image, T_j_i) pairs, T_j_i mapping this camera's
    coordinates into neighbour j's; `free`: per node, whether it may move (no LiDAR returns). Nodes
    without enough textured, visible pixels or a clear minimum stay at 0, and so does every node when the
    nodes with returns disagree with the depth (see below). `stats` receives the check's figures."""
    out = np.zeros(ROWS * COLS)
    if not neighbours or not free.any() or free.all():
        return out
    depth, gray, neighbours, K = _working_scale(depth, gray, neighbours, K)
    grid, cands, cost, weight = _sweep_costs(depth, gray, neighbours, K)
    mean = cost / np.maximum(weight, 1e-9)
    if FAR_LOG:
        far_mean, far_weight = mean[-1], weight[-1]
        cands, cost, weight, mean = cands[:-1], cost[:-1], weight[:-1], mean[:-1]
    nodes = np.arange(grid.size)
    best = np.argmin(mean, 0)
    inner_best = np.clip(best, 1, len(cands) - 2)
    y0, y1, y2 = mean[inner_best - 1, nodes], mean[inner_best, nodes], mean[inner_best + 1, nodes]
    curve = y0 - 2 * y1 + y2
    step = np.where((best == inner_best) & (curve > 1e-9), 0.5 * (y0 - y2) / np.maximum(curve, 1e-9), 0.0)
    chosen = cands[best] + np.clip(step, -0.5, 0.5) * (cands[1] - cands[0])
    lowest = mean[best, nodes]
    # a node votes when enough pixels saw every candidate (its best may lie at the span's end: the generator
    # is often that far off outside the cone; requiring a valley inside the span cost accuracy on the real drives)
    seen = weight.min(0) >= MIN_PIXELS
    # the nodes with returns check the sweep: the graph's depth is right there, so where their cost has a
    # clear valley they should choose no change; a median choice far from it (poses off: a step length
    # wrong, a turn misread) or too few such nodes, and the frame keeps the graph's depth
    backed = seen & ~free & (np.minimum(mean[0], mean[-1]) - lowest > MIN_GAIN)
    bias = float(np.median(chosen[backed])) if backed.any() else np.inf
    eligible = int((seen & ~free).sum())
    if stats is not None:
        stats.update(backed=int(backed.sum()), bias=bias, eligible=eligible)
    if backed.sum() < max(MIN_BACKED, MIN_BACKED_SHARE * eligible) or abs(bias) > MAX_BIAS_LOG:
        return out
    keep = free & seen & (mean[len(cands) // 2] - lowest > MIN_GAIN)
    if FAR_LOG:
        keep &= (far_weight < MIN_PIXELS) | (far_mean - lowest > FAR_GAIN)
    out[keep] = chosen[keep]
    return out


def free_nodes(sparse: np.ndarray) -> np.ndarray:
    """Per node of the photometric grid: True where the nearest-node cell holds no LiDAR return."""
    grid = CorrectionGrid(ROWS, COLS, *sparse.shape)
    counts = grid.cell_means(np.where(sparse > 0, 1.0, 0.0))  # share of pixels with a return
    return ~(np.nan_to_num(counts) > 0)


def photometric_correction(depth: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The depth times the upsampled offsets (0 stays 0)."""
    if not np.any(offsets):
        return depth
    grid = CorrectionGrid(ROWS, COLS, *depth.shape)
    return np.where(depth > 0, depth * np.exp(grid.upsample(offsets)), 0.0)
