"""The generator's depth corrected towards motion stereo's triangulated corners (`odometry.motion_stereo`): each
corner's log ratio to the generator spread over the pixels around it that lie on the same surface, fading where
the corners are few, so that a few wrong corners cannot move a whole region.
"""

from __future__ import annotations

import numpy as np

# Settings chosen on development data only (the clip's frames 0-37 and the simulator's Mid-40 validation drives;
# docs/decisions/0011-tuned-settings.md): fixed here, not a user's to tune.
# corrected_depth: the corners' log ratio to the generator spread with sigma = SPREAD x focal length (px), over
# pixels whose generator depth is within about RANGE_LOG (log) of the corner's, fading where their summed weight
# is small against SUPPORT corners' worth; each ratio taken against the generator depth within EDGE_PX (px) that
# matches the corner best
SPREAD = 0.06
SUPPORT = 1.0
RANGE_LOG = 0.2
EDGE_PX = 2


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
