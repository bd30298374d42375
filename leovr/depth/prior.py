"""The classical prior the depth generator refines: a dense map interpolated from the sparse input.

Inside the convex hull of the projected returns, depth is interpolated linearly in *inverse* depth
over a Delaunay triangulation of the returns' pixels: the inverse depth of a plane is affine in pixel
coordinates, so ground, walls and car sides between two LiDAR rings come out exact, where a nearest
fill is off by up to half the ring gap. Outside the hull (above the top ring, outside a Mid-40 cone)
each pixel takes the nearest return, and so does every pixel of a triangle whose corner depths differ
by a factor of EDGE_RATIO or more (it spans a depth edge: blending foreground and background would
invent flying pixels). Measured pixels keep their value.

With the camera image, a pixel of such an edge triangle takes the corner whose depth is nearest (in log)
to an edge-aware interpolation of the returns: OpenCV's EdgeAwareInterpolator (EpicFlow's geodesic
locally-affine fit, Revaud et al. 2015), whose geodesic distances grow across image edges, so a pixel
takes the side of the depth edge that the image puts it on. Where that interpolation lies strictly
between the triangle's nearest and farthest corner and the corners differ by less than a factor of
EDGE_GUIDE_MAX_RATIO, the pixel takes its value instead: such a triangle mostly spans a steep continuous
surface (the road between two far rings, the side of a truck seen at a grazing angle), which the geodesic
fit follows and a corner does not. Without the image, the nearest return.
"""

from __future__ import annotations

import os
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from leovr.depth.classical import nearest_fill
from leovr.threads import Worker

# Chosen on the simulator's validation split: the lowest mean MAE relative to the nearest fill over Mid-40,
# VLP-16 and uniform-ratio inputs (docs/decisions/0011-tuned-settings.md).
EDGE_RATIO = 1.5

# The edge-aware interpolation's settings (neighbours, edge weight of the geodesic distance, weight decay),
# chosen on the KITTI raw clip's development frames (docs/decisions/0011-tuned-settings.md).
EDGE_AWARE_K = 64
EDGE_AWARE_LAMBDA = 999.0
EDGE_AWARE_SIGMA = 0.05
# The largest depth ratio across a guide edge: chosen on development data, the lowest prior MAE on every set
# (docs/decisions/0011-tuned-settings.md).
EDGE_GUIDE_MAX_RATIO = 3.0
MIN_EDGE_AWARE_RETURNS = 16  # fewer returns than this: the nearest return (the fit needs neighbours)
MAX_EDGE_AWARE_RETURNS = 32000  # OpenCV's interpolator takes fewer than 32767 matches: denser inputs are strided
# The guide's time grows with its returns (a KITTI HDL-64 scan puts about 15-18k in view). Above
# DENSE_RETURNS it takes the returns within EDGE_NEIGHBOURHOOD_PX of a depth edge (a return with one EDGE_RATIO
# nearer or farther inside that window: where the guide is read, with the neighbours its local fits use) and
# every DENSE_REST_STRIDE-th other return: the same MAE in less time (docs/decisions/0011-tuned-settings.md).
DENSE_RETURNS = 8000
EDGE_NEIGHBOURHOOD_PX = 41
DENSE_REST_STRIDE = 4


def _uint8_image(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    image = np.asarray(image)
    if image.shape[:2] != shape:
        raise ValueError(f"image of {image.shape[1]}x{image.shape[0]} px for a sparse map of {shape[1]}x{shape[0]} px")
    if image.dtype != np.uint8:
        image = np.clip(np.round(image * 255.0 if image.max() <= 1.0 else image), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(image)


def near_depth_edges(sparse: np.ndarray, window: int = EDGE_NEIGHBOURHOOD_PX, ratio: float = EDGE_RATIO) -> np.ndarray:
    """H x W bool: pixels within a `window` x `window` box of a return that has, in such a box around it, a
    return `ratio` times nearer or farther (a depth edge)."""
    import cv2

    sparse = np.asarray(sparse, np.float32)
    box = np.ones((window, window), np.uint8)
    valid = sparse > 0
    hi = cv2.dilate(sparse, box)
    lo = cv2.erode(np.where(valid, sparse, np.float32(1e9)), box)
    edge = valid & (hi >= ratio * lo)
    return cv2.dilate(edge.astype(np.uint8), box) > 0


def edge_aware_log_depth(sparse: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Log depth interpolated from the returns of `sparse` along geodesic paths over the image's edges
    (H x W float32). It picks the side at depth edges; as depth it is used only inside moderate edges and
    only where it lies strictly between the triangle's corners (its locally affine fit can overshoot)."""
    import cv2

    v, u = np.nonzero(sparse > 0)
    if len(u) > DENSE_RETURNS:
        keep = near_depth_edges(sparse)[v, u]
        keep[::DENSE_REST_STRIDE] = True
        v, u = v[keep], u[keep]
    if len(u) > MAX_EDGE_AWARE_RETURNS:  # an evenly strided subset guides the side choice just as well
        keep = np.linspace(0, len(u) - 1, MAX_EDGE_AWARE_RETURNS).astype(np.int64)
        v, u = v[keep], u[keep]
    pts = np.ascontiguousarray(np.stack([u, v], 1), dtype=np.float32)
    # the value rides on the horizontal displacement of a "match" (x5: the scale the settings were chosen at)
    shift = np.zeros_like(pts)
    shift[:, 0] = 5.0 * np.log(sparse[v, u])
    interp = cv2.ximgproc.createEdgeAwareInterpolator()
    interp.setK(min(EDGE_AWARE_K, len(u)))
    interp.setLambda(EDGE_AWARE_LAMBDA)
    interp.setSigma(EDGE_AWARE_SIGMA)
    interp.setUsePostProcessing(False)
    img = _uint8_image(image, sparse.shape)
    return interp.interpolate(img, pts, img, pts + shift)[..., 0] / 5.0


def hilbert_order(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The order of the pixels (u, v) (non-negative integers) along a Hilbert curve over their extent."""
    x, y = np.asarray(u, np.int64).copy(), np.asarray(v, np.int64).copy()
    side = 1 << max(int(max(x.max(initial=0), y.max(initial=0))).bit_length(), 1)
    d = np.zeros_like(x)
    s = side >> 1
    while s > 0:
        rx, ry = (x & s) > 0, (y & s) > 0
        d += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        # rotate the quadrant so the curve runs on inside it
        flip = ~ry & rx
        x, y = np.where(flip, s - 1 - x, x), np.where(flip, s - 1 - y, y)
        x, y = np.where(ry, x, y), np.where(ry, y, x)
        s >>= 1
    return np.argsort(d, kind="stable")


def delaunay_triangles(u: np.ndarray, v: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The Delaunay triangles of distinct pixels (u, v) in an H x W map, as T x 3 indices into them.

    OpenCV's Subdiv2D (2.5-4x faster than Qhull on LiDAR returns). It starts from a triangle around its bounding box and
    drops every triangle that keeps a corner of it; ten image sizes out, no hull triangle is lost to it."""
    import cv2

    if len(u) < 3:
        return np.zeros((0, 3), np.int64)
    h, w = shape
    subdiv = cv2.Subdiv2D((-10 * w, -10 * h, 21 * w, 21 * h))
    # inserted along a Hilbert curve: each point lands next to the last, so the search for its triangle is
    # short (docs/decisions/0011-tuned-settings.md)
    order = hilbert_order(u, v)
    subdiv.insert(np.stack([u[order], v[order]], 1).astype(np.float32))
    corners = np.rint(np.asarray(subdiv.getTriangleList(), np.float64).reshape(-1, 3, 2)).astype(np.int64)  # () if none
    inside = ((corners[..., 0] >= 0) & (corners[..., 0] < w) & (corners[..., 1] >= 0) & (corners[..., 1] < h)).all(1)
    corners = corners[inside]
    index = np.full(shape, -1, np.int64)
    index[v, u] = np.arange(len(u))
    return index[corners[..., 1], corners[..., 0]]


def triangle_map(corners: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """H x W map of the triangle (row of `corners`, T x 3 x 2 pixel (u, v)) that covers each pixel, -1
    where none does; pixels on a shared side go to the later triangle. Scanline rasterisation in numpy:
    per triangle and row the span between its long side and the other two."""
    h, w = shape
    out = np.full(h * w, -1, np.int64)
    xy = np.asarray(corners, np.float64)
    area2 = (xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1]) - (xy[:, 2, 0] - xy[:, 0, 0]) * (
        xy[:, 1, 1] - xy[:, 0, 1]
    )
    ids = np.nonzero(area2 != 0)[0]  # a flat triangle covers nothing its neighbours do not
    if not len(ids):
        return out.reshape(shape)
    xy = np.take_along_axis(xy[ids], np.argsort(xy[ids, :, 1], axis=1, kind="stable")[..., None], 1)
    (xa, ya), (xb, yb), (xc, yc) = xy[:, 0].T, xy[:, 1].T, xy[:, 2].T  # top, middle, bottom
    with np.errstate(divide="ignore", invalid="ignore"):
        slope_ac = (xc - xa) / (yc - ya)
        slope_ab = np.where(yb > ya, (xb - xa) / (yb - ya), 0.0)
        slope_bc = np.where(yc > yb, (xc - xb) / (yc - yb), 0.0)
    first = np.ceil(ya).astype(np.int64)
    n = np.maximum(np.floor(yc).astype(np.int64) - first + 1, 0)
    t = np.repeat(np.arange(len(ids)), n)
    y = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + first[t]
    yf = y.astype(np.float64)
    x_long = xa[t] + (yf - ya[t]) * slope_ac[t]
    x_short = np.where(
        yf <= yb[t],
        np.where(yb[t] > ya[t], xa[t] + (yf - ya[t]) * slope_ab[t], xb[t]),
        xb[t] + (yf - yb[t]) * slope_bc[t],
    )
    x0 = np.maximum(np.ceil(np.minimum(x_long, x_short) - 1e-9), 0).astype(np.int64)
    x1 = np.minimum(np.floor(np.maximum(x_long, x_short) + 1e-9), w - 1).astype(np.int64)
    m = np.maximum(x1 - x0 + 1, 0)
    # the per-pixel arrays in int32 (an image has fewer than 2^31 pixels): half the memory traffic of int64
    m32 = m.astype(np.int32)
    flat = np.repeat((y * w + x0 - (np.cumsum(m) - m)).astype(np.int32), m32)
    flat += np.arange(len(flat), dtype=np.int32)
    out[flat] = np.repeat(ids[t].astype(np.int32), m32)
    return out.reshape(shape)


@dataclass
class TriangleLookup:
    """The pixels (rows, cols) in the Delaunay triangles of a sparse map's returns."""

    depth: np.ndarray  # per pixel: inverse-depth interpolation in smooth triangles, else the nearest return
    simplex: np.ndarray  # per pixel: its triangle (-1 outside the hull)
    edge: np.ndarray  # indices of the pixels in triangles that span a depth edge
    z: np.ndarray  # T x 3 corner depths (float64)
    g: np.ndarray  # T x 2 and T: each triangle's inverse depth is g . (u, v) + c (exact for a plane)
    c: np.ndarray


def triangle_lookup(
    sparse: np.ndarray, rows: np.ndarray, cols: np.ndarray, edge_ratio: float = EDGE_RATIO
) -> TriangleLookup:
    """Triangulate the returns of `sparse` (float32, 0 = none, at least one return) and look up the pixels
    (int64 rows, cols): a triangle whose corner depths differ by a factor of `edge_ratio` or more spans a
    depth edge and is not interpolated."""
    out = nearest_fill(sparse)[rows, cols]
    v, u = np.nonzero(sparse > 0)
    simplices = delaunay_triangles(u, v, sparse.shape)
    if not len(simplices):
        none = np.zeros((0, 3))
        return TriangleLookup(out, np.full(len(rows), -1), np.zeros(0, np.int64), none, none[:, :2], none[:, 0])
    z = sparse[v, u][simplices].astype(np.float64)  # T x 3 corner depths
    inv = 1.0 / z
    p = np.stack([u, v], 1).astype(np.float64)[simplices]  # T x 3 x 2
    d0, d1 = p[:, 0] - p[:, 2], p[:, 1] - p[:, 2]
    f0, f1 = inv[:, 0] - inv[:, 2], inv[:, 1] - inv[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        det = d0[:, 0] * d1[:, 1] - d1[:, 0] * d0[:, 1]
        g = np.stack([f0 * d1[:, 1] - f1 * d0[:, 1], d0[:, 0] * f1 - d1[:, 0] * f0], 1) / det[:, None]
    c = inv[:, 2] - (g * p[:, 2]).sum(1)
    smooth = (z.max(1) < edge_ratio * z.min(1)) & np.isfinite(g).all(1) & np.isfinite(c)
    # triangles spanning an edge are drawn first: a pixel on a side they share with a smooth one interpolates
    order = np.argsort(smooth, kind="stable")
    simplex = triangle_map(p[order], sparse.shape)[rows, cols]
    simplex[simplex >= 0] = order[simplex[simplex >= 0]]
    hit = simplex >= 0
    hit[hit] = smooth[simplex[hit]]
    idx = np.nonzero(hit)[0]
    s = simplex[idx]
    out[idx] = 1.0 / np.maximum(g[s, 0] * cols[idx] + g[s, 1] * rows[idx] + c[s], 1e-6)
    return TriangleLookup(out, simplex, np.nonzero((simplex >= 0) & ~hit)[0], z, g, c)


_WORKERS: dict[tuple[int, bool], Worker] = {}  # per process: a helper thread, and the in-line one


def _beside(fn, *args) -> Future:
    """`fn(*args)` in a helper thread when OpenCV may use more than one thread (cv2.setNumThreads: a batch
    task with one CPU sets 1), else here; the Future gives its result or raises its error. The thread is
    kept per process: a forked child (a data loader's worker) inherits the parent's pool without its
    thread, and a task given to it would never run."""
    import cv2

    key = os.getpid(), cv2.getNumThreads() > 1
    if any(pid != key[0] for pid, _ in _WORKERS):  # a forked child: its parent's threads are not in it
        _WORKERS.clear()
    if key not in _WORKERS:
        _WORKERS[key] = Worker("prior", threaded=key[1])
    return _WORKERS[key].submit(fn, *args)


def interpolated_at(
    sparse: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    edge_ratio: float = EDGE_RATIO,
    image: np.ndarray | None = None,
) -> np.ndarray:
    """The prior of `sparse` at the pixels (rows, cols) only (float32 metres; 0 where the map is empty).
    Triangles whose corner depths differ by a factor of `edge_ratio` or more span a depth edge: their
    pixels take one corner's depth instead of a blend of foreground and background, the one the image
    puts them with (`image`: H x W (x 3), uint8 or floats in [0, 1]), else the nearest return. With the
    image, a triangle whose corners differ by less than EDGE_GUIDE_MAX_RATIO gives its pixels the image
    guide's own depth where that lies strictly between the corners (a steep surface, not an edge)."""
    sparse = np.asarray(sparse, np.float32)
    valid = sparse > 0
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    if not valid.any():
        return np.zeros(len(rows), np.float32)
    guided = image is not None and valid.sum() >= MIN_EDGE_AWARE_RETURNS
    # the image guide (OpenCV, which leaves the interpreter lock) runs beside the triangle lookup (numpy)
    fit = _beside(edge_aware_log_depth, sparse, image) if guided else None
    tri = triangle_lookup(sparse, rows, cols, edge_ratio)
    out, edge = tri.depth, tri.edge
    if fit is not None and len(edge):
        guide = fit.result()[rows[edge], cols[edge]]
        edge = edge[np.isfinite(guide)]  # a degenerate fit keeps the nearest return
        guide = guide[np.isfinite(guide)]
        zc = tri.z[tri.simplex[edge]]
        cost = np.abs(np.log(zc) - guide[:, None])
        best = zc[np.arange(len(edge)), cost.argmin(1)]
        # the nearest return stays where it is at least as near the guide as the best corner
        switch = cost.min(1) < np.abs(np.log(out[edge]) - guide)
        out[edge[switch]] = best[switch]
        # a moderate edge whose fit runs between its corners: a steep surface, the fit's own depth
        lo, hi = np.log(zc.min(1)), np.log(zc.max(1))
        between = (guide > lo) & (guide < hi) & (hi - lo < np.log(EDGE_GUIDE_MAX_RATIO))
        out[edge[between]] = np.exp(guide[between])
    measured = valid[rows, cols]
    out[measured] = sparse[rows[measured], cols[measured]]
    return out


def interpolated_fill(
    sparse: np.ndarray, edge_ratio: float = EDGE_RATIO, image: np.ndarray | None = None
) -> np.ndarray:
    """Dense depth (metres, float32) from a sparse map (0 = no return); all zeros when it is empty.
    `image` (the frame, H x W (x 3)) picks the side of depth edges (module docstring)."""
    sparse = np.asarray(sparse, np.float32)
    h, w = sparse.shape
    gv, gu = np.mgrid[0:h, 0:w]
    return interpolated_at(sparse, gv.ravel(), gu.ravel(), edge_ratio, image).reshape(h, w)


def interpolated_fill_batch(sparse: np.ndarray, images: np.ndarray | None = None) -> np.ndarray:
    """`interpolated_fill` of each map of a B x H x W (or B x 1 x H x W) batch; `images`: B x H x W x 3."""
    maps = sparse.reshape(-1, *sparse.shape[-2:])
    return np.stack(
        [interpolated_fill(s, image=None if images is None else images[b]) for b, s in enumerate(maps)]
    ).reshape(sparse.shape)
