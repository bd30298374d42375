"""Classical depth completion from a sparse depth map: nearest-neighbour fill and IP-Basic.

IP-Basic follows Ku, Harakeh and Waslander, "In Defense of Classical Image Processing: Fast Depth
Completion on the CPU" (CRV 2018): invert depths so near wins under dilation, diamond dilation,
closing, small-hole fill, optional extrapolation to the top of the image, large-hole fill, median
and bilateral (or Gaussian) blur, and invert back. Written from the paper's description.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt

FULL_3 = np.ones((3, 3), np.uint8)
FULL_5 = np.ones((5, 5), np.uint8)
FULL_7 = np.ones((7, 7), np.uint8)
FULL_31 = np.ones((31, 31), np.uint8)
DIAMOND_5 = np.array([[0, 0, 1, 0, 0], [0, 1, 1, 1, 0], [1, 1, 1, 1, 1], [0, 1, 1, 1, 0], [0, 0, 1, 0, 0]], np.uint8)


def nearest_fill(sparse: np.ndarray) -> np.ndarray:
    """Give every pixel the depth of the nearest valid pixel (Euclidean in the image)."""
    valid = sparse > 0
    if not valid.any():
        return np.zeros_like(sparse, dtype=np.float32)
    iy, ix = distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return sparse[iy, ix].astype(np.float32)


@dataclass
class IPBasicConfig:
    max_depth: float = 100.0
    extrapolate: bool = True
    blur: str = "bilateral"  # bilateral | gaussian | none
    fill_remaining: bool = True  # nearest-fill holes IP-Basic leaves open (e.g. outside a Mid-40 cone)


def fill_top(depth: np.ndarray) -> np.ndarray:
    """Copy each column's topmost valid value up to the top row (vectorized)."""
    valid = depth > 0.1
    has = valid.any(axis=0)
    top = np.argmax(valid, axis=0)
    cols = np.nonzero(has)[0]
    rows = np.arange(depth.shape[0])[:, None]
    above = (rows < top[None, :]) & has[None, :]
    values = np.zeros(depth.shape[1], depth.dtype)
    values[cols] = depth[top[cols], cols]
    return np.where(above, values[None, :], depth)


def ipbasic(sparse: np.ndarray, cfg: IPBasicConfig | None = None) -> np.ndarray:
    """IP-Basic "fast" depth completion of a sparse metric depth map (0 = empty)."""
    cfg = cfg or IPBasicConfig()
    d = sparse.astype(np.float32).copy()
    valid = d > 0.1
    d[valid] = cfg.max_depth - np.minimum(d[valid], cfg.max_depth - 0.2)  # invert: near = large
    d = cv2.dilate(d, DIAMOND_5)
    d = cv2.morphologyEx(d, cv2.MORPH_CLOSE, FULL_5)
    empty = d < 0.1
    d[empty] = cv2.dilate(d, FULL_7)[empty]
    if cfg.extrapolate:
        d = fill_top(d)
    empty = d < 0.1
    d[empty] = cv2.dilate(d, FULL_31)[empty]
    valid = d > 0.1
    med = cv2.medianBlur(d, 5)
    d[valid] = med[valid]
    valid = d > 0.1
    if cfg.blur == "bilateral":
        blurred = cv2.bilateralFilter(d, 5, 1.5, 2.0)
        d[valid] = blurred[valid]
    elif cfg.blur == "gaussian":
        blurred = cv2.GaussianBlur(d, (5, 5), 0)
        d[valid] = blurred[valid]
    valid = d > 0.1
    d[valid] = cfg.max_depth - d[valid]
    d[~valid] = 0.0
    if cfg.fill_remaining and not valid.all():
        d = np.where(valid, d, nearest_fill(sparse))
    return d
