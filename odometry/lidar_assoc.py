"""Associate image features with projected LiDAR points (LeoVR eqs. 9-10): the nearest projected
point within 5 px, rejected when the points around it disagree in depth (a depth discontinuity,
where the nearest point may belong to the background or a foreground edge)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def associate(
    uv: np.ndarray, lidar_uv: np.ndarray, lidar_depth: np.ndarray, radius_px: float = 5.0, max_rel_spread: float = 0.1
) -> np.ndarray:
    """Depth (metres) per feature from its nearest projected LiDAR point, NaN where none is within
    `radius_px` or where the points within the radius spread by more than `max_rel_spread` of it."""
    out = np.full(len(uv), np.nan)
    if len(uv) == 0 or len(lidar_uv) == 0:
        return out
    tree = cKDTree(lidar_uv)
    dist, idx = tree.query(uv, k=1, distance_upper_bound=radius_px)
    hit = np.isfinite(dist)
    if not hit.any():
        return out
    d0 = lidar_depth[idx[hit]]
    # every (feature, LiDAR point) pair within the radius, then the depth range per feature
    pairs = cKDTree(uv[hit]).sparse_distance_matrix(tree, radius_px, output_type="ndarray")
    lo, hi = np.full(len(d0), np.inf), np.full(len(d0), -np.inf)
    np.minimum.at(lo, pairs["i"], lidar_depth[pairs["j"]])
    np.maximum.at(hi, pairs["i"], lidar_depth[pairs["j"]])
    ok = (hi - lo) <= max_rel_spread * d0
    vals = np.where(ok, d0, np.nan)
    out[np.nonzero(hit)[0]] = vals
    return out
