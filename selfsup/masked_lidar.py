"""The masked-LiDAR task of self-supervised training: hide part of the user's own LiDAR input and predict it.

The held-back returns must lie where the scored pixels of a real evaluation lie: between the rings
of a spinning LiDAR at every position within a gap, and outside the area a Livox-like cone covers.
- Ring scans (a spinning LiDAR, or a VLP-16 simulated from one): hide one ring in `k`, k drawn from
  {2, 3, 4}, at a random phase; each hidden ring lies between two kept ones. The thinner input keeps
  50-75 % of the rings: close to the density the network meets at inference. (Keeping only one ring
  in k, so that hidden rings sit at every position of a wide gap, over-corrects: the network learns the
  correction of a far sparser input and applies it to the full one; decision 0017.)
- Scans without rings (a rosette): keep 60-90 % of the returns inside a cone shrunk to a random
  fraction of the input's angular radius, so that hidden returns lie both between kept ones and
  beyond the edge of the input, where a Mid-40's evaluation error comes from.
Only the user's input is read: never held-out evaluation points, never ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leovr.eval.heldout import parallax_filter
from leovr.lidar.projection import sparse_depth

MIN_RINGS = 8  # fewer rings found: treat the scan as ring-less


@dataclass
class MaskedSplit:
    """Sparse maps of one split: what the network sees and the hidden returns it is scored on."""

    sparse: np.ndarray  # H x W metres, 0 = none
    target: np.ndarray  # H x W metres, 0 = none (parallax-filtered against every input return)


def stored_rings(points: np.ndarray) -> np.ndarray | None:
    """Ring index per point of a scan stored ring after ring (KITTI, the simulator's spinning sensors):
    a ring ends where the azimuth wraps around. None for scans without that structure (a rosette)."""
    az = np.arctan2(points[:, 1], points[:, 0])
    wraps = np.nonzero(np.diff(az) < -np.pi)[0]
    if len(wraps) < MIN_RINGS - 1:
        return None
    ids = np.zeros(len(points), np.int64)
    ids[wraps + 1] = 1
    return np.cumsum(ids)


def _ring_split(rings: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    k = int(rng.integers(2, 5))
    return (rings % k) != int(rng.integers(0, k))


def _cone_split(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    xyz = points[:, :3].astype(np.float64)
    axis = xyz.mean(0)
    axis /= max(np.linalg.norm(axis), 1e-9)
    cosang = (xyz @ axis) / np.maximum(np.linalg.norm(xyz, axis=1), 1e-9)
    ang = np.arccos(np.clip(cosang, -1.0, 1.0))
    inner = ang <= np.quantile(ang, 1.0) * rng.uniform(0.55, 0.9)
    return inner & (rng.random(len(points)) < rng.uniform(0.6, 0.9))


def ring_gap_px(depth: np.ndarray) -> int:
    """Median vertical distance (pixels) between consecutive returns of one image column: a ring
    scanner's ring spacing in the image (0 without two returns in any column)."""
    rows, cols = np.nonzero(depth > 0)
    order = np.lexsort((rows, cols))
    r, c = rows[order], cols[order]
    gaps = np.diff(r)[(np.diff(c) == 0)]
    gaps = gaps[gaps > 1]
    return int(np.median(gaps)) if len(gaps) else 0


def masked_split(
    points: np.ndarray,
    K: np.ndarray,
    T_cam_lidar: np.ndarray,
    shape: tuple[int, int],
    rng: np.random.Generator,
    window: int = 7,
    rel: float = 0.15,
    span_rings: bool = False,
    every: np.ndarray | None = None,
) -> MaskedSplit:
    """Split the input scan `points` (N x >=3, LiDAR frame) into a thinner input and hidden targets.

    Hidden returns the camera may not see are dropped by the evaluation's parallax filter (a return
    within `window` px nearer by `rel`). With `span_rings`, a ring scan's window reaches one ring
    above and below (the evaluation's 7 px reach the next rings of a 64-ring scan; in a sparser
    user scan they would find only the hidden ring's own neighbours and keep points behind edges).
    `every`: the whole scan's sparse map when the caller has it (the same for every split of a frame)."""
    rings = stored_rings(points)
    keep = _ring_split(rings, rng) if rings is not None else _cone_split(points, rng)
    if keep.all() or not keep.any():  # too few points to split: hide a random half
        keep = rng.random(len(points)) < 0.5
    sparse = sparse_depth(points[keep], K, T_cam_lidar, shape)
    hidden = sparse_depth(points[~keep], K, T_cam_lidar, shape)
    every = sparse_depth(points, K, T_cam_lidar, shape) if every is None else every
    size: int | tuple[int, int] = window
    if span_rings and rings is not None:
        size = (max(window, 2 * ring_gap_px(every) + 1), window)
    return MaskedSplit(sparse.astype(np.float32), parallax_filter(hidden, every, size, rel).astype(np.float32))
