"""Geometric validation of a loop candidate: ORB matches between the two frames, their 3D points in
each camera (LiDAR-backed or from depth), a rigid transform by RANSAC + Umeyama, accepted on the
inlier count and the inliers' reprojection error."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odometry.features import Features, match


@dataclass
class LoopCheck:
    accepted: bool
    inliers: int
    reprojection_px: float
    T_j_i: np.ndarray | None  # camera i expressed in camera j (the loop measurement)


def umeyama(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid T (4 x 4) minimising |T src - dst|^2 (Umeyama 1991, no scale)."""
    ms, md = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - md).T @ (src - ms))
    S = np.eye(3)
    S[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ S @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, md - R @ ms
    return T


def ransac_rigid(src: np.ndarray, dst: np.ndarray, thresh_rel: float = 0.05, thresh_abs: float = 0.3,
                 iters: int = 200, seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
    """Rigid transform src -> dst by 3-point RANSAC; inlier when the residual is under
    max(thresh_abs, thresh_rel * depth). Returns (T refit on inliers, inlier mask)."""
    n = len(src)
    if n < 3:
        return None, np.zeros(n, bool)
    rng = np.random.default_rng(seed)
    tol = np.maximum(thresh_abs, thresh_rel * np.linalg.norm(dst, axis=1))
    best = np.zeros(n, bool)
    for _ in range(iters):
        pick = rng.choice(n, 3, replace=False)
        T = umeyama(src[pick], dst[pick])
        inl = np.linalg.norm(src @ T[:3, :3].T + T[:3, 3] - dst, axis=1) < tol
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 3:
        return None, best
    return umeyama(src[best], dst[best]), best


def validate_loop(fi: Features, pts_i: np.ndarray, fj: Features, pts_j: np.ndarray, K: np.ndarray,
                  min_inliers: int = 20, max_reproj_px: float = 3.0) -> LoopCheck:
    """`pts_*` are the features' 3D points in their own camera (NaN rows where unknown)."""
    ia, ib = match(fi, fj)
    ok = np.isfinite(pts_i[ia]).all(1) & np.isfinite(pts_j[ib]).all(1)
    ia, ib = ia[ok], ib[ok]
    T, inl = ransac_rigid(pts_i[ia], pts_j[ib])
    if T is None:
        return LoopCheck(False, int(inl.sum()), float("inf"), None)
    # reprojection of frame j's inlier points into frame i through the estimated transform
    P = (pts_j[ib][inl] - T[:3, 3]) @ T[:3, :3]  # T^-1 applied: camera j -> camera i
    uv = (P @ K.T)[:, :2] / np.maximum(P[:, 2:3], 1e-6)
    err = float(np.sqrt(np.mean(np.sum((uv - fi.uv[ia][inl]) ** 2, 1)))) if inl.any() else float("inf")
    n = int(inl.sum())
    return LoopCheck(n >= min_inliers and err <= max_reproj_px, n, err, T)
