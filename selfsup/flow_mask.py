"""The motion-optical-flow mask (LeoVR eqs. 18-19): dense optical flow from frame i to frame j, the
fundamental matrix of the camera motion T_ji, and a pixel kept only when its flow end point lies
within `lambda` pixels of its epipolar line in frame j (static, Lambertian, unoccluded) and inside
frame j. Moving objects, occlusions and reflections break the epipolar constraint and are dropped."""

from __future__ import annotations

import cv2
import numpy as np

from leovr.geometry import fundamental


def gray(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def dense_flow(image_i: np.ndarray, image_j: np.ndarray, method: str = "dis") -> np.ndarray:
    """H x W x 2 flow (du, dv) taking frame i's pixels to frame j: OpenCV's DIS (medium preset) or
    Farneback."""
    a, b = gray(image_i), gray(image_j)
    if method == "dis":
        return cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(a, b, None)
    if method == "farneback":
        return cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 4, 21, 5, 7, 1.5, 0)
    raise ValueError(f"flow method must be 'dis' or 'farneback', not '{method}'")


def epipolar_distance(flow: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance (px) from each flow end point p_j = p_i + flow to the epipolar line F p_i."""
    h, w = flow.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    p_i = np.stack([u, v, np.ones_like(u)], -1)
    p_j = np.stack([u + flow[..., 0], v + flow[..., 1], np.ones_like(u)], -1)
    line = p_i @ F.T  # H x W x 3: a u + b v + c = 0 in frame j
    return np.abs((p_j * line).sum(-1)) / np.maximum(np.hypot(line[..., 0], line[..., 1]), 1e-12)


def flow_inside(flow: np.ndarray) -> np.ndarray:
    """H x W: the flow end point lies inside the image."""
    h, w = flow.shape[:2]
    v, u = np.mgrid[0:h, 0:w]
    uj, vj = u + flow[..., 0], v + flow[..., 1]
    return (uj >= 0) & (uj <= w - 1) & (vj >= 0) & (vj <= h - 1)


def epipolar_keep(
    flow: np.ndarray, T_j_i: np.ndarray, K: np.ndarray, lam_px: float = 1.0, min_baseline_m: float = 1e-3
) -> np.ndarray:
    """H x W: the flow end point lies within `lam_px` of its epipolar line (eq. 19); everything is kept
    without translation, where the epipolar geometry is undefined."""
    if np.linalg.norm(T_j_i[:3, 3]) < min_baseline_m:
        return np.ones(flow.shape[:2], bool)
    return epipolar_distance(flow, fundamental(T_j_i, K)) < lam_px


def motion_flow_mask(
    image_i: np.ndarray,
    image_j: np.ndarray,
    T_j_i: np.ndarray,
    K: np.ndarray,
    lam_px: float = 1.0,
    method: str = "dis",
    min_baseline_m: float = 1e-3,
) -> np.ndarray:
    """H x W bool confidence mask mu of eq. 19 for the pair (i, j). Without translation the epipolar
    geometry is undefined, so only the inside-the-image test applies."""
    flow = dense_flow(image_i, image_j, method)
    return flow_inside(flow) & epipolar_keep(flow, T_j_i, K, lam_px, min_baseline_m)
