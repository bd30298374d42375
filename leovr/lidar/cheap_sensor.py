"""Simulate a cheap LiDAR from a dense scan: the kept input and the held-out remainder.

- `vlp16`: 16 of the 64 rings of an HDL-64 scan (every 4th ring by elevation);
- `mid40`: a Livox Mid-40-like scan, a 38.4-degree circular cone sampled along a rosette drawn by
  two counter-rotating prisms, about 10k samples per 0.1 s, a pattern that never repeats;
- `ratio:R`: a uniform fraction R of the projected pixels (SLIM's injection ratio, R in [0.005, 0.30]);
- `full`: everything kept (dense input, for checks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from leovr.lidar.projection import project_points

# Mid-40: 38.4 deg circular FoV, ~100k points/s. The prism rates are incommensurate so the
# rosette keeps filling the cone when frames are integrated over time.
MID40_FOV_DEG = 38.4
MID40_RATE_HZ = 100_000.0
MID40_PRISM_HZ = (121.0 * np.sqrt(2.0) / 1.4, -77.0 * np.sqrt(3.0) / 1.7)
RATIO_RANGE = (0.005, 0.30)


@dataclass(frozen=True)
class CheapSensor:
    """Which cheap input to simulate."""

    kind: str  # vlp16 | mid40 | ratio | full
    ratio: float = 0.0

    def __str__(self) -> str:
        return f"ratio:{self.ratio:g}" if self.kind == "ratio" else self.kind


def parse_input(text: str) -> CheapSensor:
    """Parse 'vlp16', 'mid40', 'full' or 'ratio:R'."""
    t = text.strip().lower()
    if t in ("vlp16", "mid40", "full"):
        return CheapSensor(t)
    if t.startswith("ratio:"):
        try:
            r = float(t.split(":", 1)[1])
        except ValueError:
            raise ValueError(f"bad injection ratio in '{text}'") from None
        if not RATIO_RANGE[0] <= r <= RATIO_RANGE[1]:
            raise ValueError(f"injection ratio {r} outside [{RATIO_RANGE[0]}, {RATIO_RANGE[1]}]")
        return CheapSensor("ratio", r)
    raise ValueError(f"unknown input '{text}' (choose vlp16, mid40, full or ratio:R)")


@dataclass
class ScanSplit:
    """Points given to the method (`kept`) and points held out for evaluation (`heldout`): the scan's points at
    `kept_index` and `heldout_index`, so that the same returns can be taken from the scan deskewed another way."""

    kept: np.ndarray
    heldout: np.ndarray
    kept_index: np.ndarray
    heldout_index: np.ndarray


def ring_ids(points: np.ndarray, n_rings: int = 64) -> np.ndarray:
    """Ring index per point.

    Scans stored ring after ring (KITTI) are split where the azimuth wraps around; otherwise the
    points are binned into `n_rings` equal-count elevation bins, top ring first.
    """
    az = np.arctan2(points[:, 1], points[:, 0])
    step = np.diff(az)
    # a ring ends where the azimuth wraps forward; a deskewed scan can also cross the seam and come back
    # (+179.9, -179.9, +179.95 degrees), a wrap undone by the next step: each cancels the other
    turns = np.r_[0, (step < -np.pi).astype(np.int64) - (step > np.pi).astype(np.int64)]
    if n_rings // 2 <= turns.sum() <= 2 * n_rings:  # about one wrap per ring: stored ring after ring
        return np.maximum.accumulate(np.cumsum(turns))
    el = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
    rank = np.argsort(np.argsort(-el, kind="stable"), kind="stable")
    return rank * n_rings // max(len(points), 1)


def vlp16_mask(points: np.ndarray, every: int = 4) -> np.ndarray:
    """Keep every `every`-th ring (16 of 64), skipping the partial ring a KITTI scan starts with."""
    ids = ring_ids(points)
    return (ids % every) == (every // 2)


def rosette_directions(
    t0: float,
    duration: float = 0.1,
    rate_hz: float = MID40_RATE_HZ,
    fov_deg: float = MID40_FOV_DEG,
    prism_hz: tuple[float, float] = MID40_PRISM_HZ,
) -> np.ndarray:
    """Unit beam directions (M x 3, sensor frame, x forward) of a rosette scan over [t0, t0 + duration).

    The two prisms each deflect the beam by a quarter of the FoV; their sum traces rose petals
    that reach the cone's edge (LeoVR Fig. 1(b)).
    """
    n = max(int(round(duration * rate_hz)), 1)
    t = t0 + np.arange(n) / rate_hz
    half = np.radians(fov_deg) / 2.0
    z = 0.5 * half * (np.exp(2j * np.pi * prism_hz[0] * t) + np.exp(2j * np.pi * prism_hz[1] * t))
    rho, phi = np.abs(z), np.angle(z)
    return np.stack([np.cos(rho), np.sin(rho) * np.cos(phi), np.sin(rho) * np.sin(phi)], 1)


def mid40_mask(points: np.ndarray, frame_index: int, sweep_s: float = 0.1, tol_deg: float = 0.25) -> np.ndarray:
    """Keep, for each rosette beam of this frame, the dense point nearest its direction (within tol)."""
    xyz = points[:, :3].astype(np.float64)
    r = np.linalg.norm(xyz, axis=1)
    dirs = xyz / np.maximum(r, 1e-9)[:, None]
    cone = np.nonzero((r > 0) & (dirs[:, 0] >= np.cos(np.radians(MID40_FOV_DEG) / 2 + np.radians(tol_deg))))[0]
    keep = np.zeros(len(points), bool)
    if len(cone) == 0:
        return keep
    beams = rosette_directions(frame_index * sweep_s, sweep_s)
    dist, nn = cKDTree(dirs[cone]).query(beams, distance_upper_bound=2 * np.sin(np.radians(tol_deg) / 2))
    keep[cone[nn[np.isfinite(dist)]]] = True
    return keep


def simulate_cheap_sensor(
    points: np.ndarray,
    sensor: CheapSensor,
    frame_index: int = 0,
    seed: int = 0,
    K: np.ndarray | None = None,
    T_cam_lidar: np.ndarray | None = None,
    shape: tuple[int, int] | None = None,
) -> ScanSplit:
    """Split a dense scan into the cheap sensor's input and the held-out rest.

    `ratio` works on pixels, so it needs the camera (K, T_cam_lidar, shape) and returns only points
    that win a pixel; it is seeded by (seed, frame_index) so runs are repeatable.
    """
    if sensor.kind == "full":
        return ScanSplit(points, points[:0], np.arange(len(points)), np.zeros(0, np.int64))
    if sensor.kind == "vlp16":
        m = vlp16_mask(points)
        return ScanSplit(points[m], points[~m], np.flatnonzero(m), np.flatnonzero(~m))
    if sensor.kind == "mid40":
        m = mid40_mask(points, frame_index)
        return ScanSplit(points[m], points[~m], np.flatnonzero(m), np.flatnonzero(~m))
    if sensor.kind == "ratio":
        if K is None or T_cam_lidar is None or shape is None:
            raise ValueError("ratio input needs the camera intrinsics, extrinsic and image shape")
        proj = project_points(points, K, T_cam_lidar, shape)
        rng = np.random.default_rng([seed, frame_index])
        chosen = rng.random(len(proj.index)) < sensor.ratio
        kept, held = proj.index[chosen], proj.index[~chosen]
        return ScanSplit(points[kept], points[held], kept, held)
    raise ValueError(f"unknown sensor kind {sensor.kind}")
