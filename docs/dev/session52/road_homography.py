"""Metric step length from the road, read densely: the road seen by a camera at a known height is a plane,
and between two frames its pixels move by the plane-induced homography

    x0 ~ K (R + t_hat m^T) K^-1 x1,    m = s n1 / h,

where (R, t_hat) is the epipolar motion of the step (frame 1 in frame 0, unit direction), n1 the road's
normal in the second camera, h the camera height and s the step's metric length. With the rotation and the
direction known, the homography is linear in the 3-vector m; a photometric Gauss-Newton fit of m over the
textured pixels of the road corridor gives s = h |m| and the road's normal m / |m| (the direct ground-plane
scale of Song and Chandraker, CVPR 2014, "Robust scale estimation in real-time monocular SFM"). Every road
pixel with texture takes part, not only the corners that can be triangulated, and the road pixels of the
second frame were all visible, higher up, in the first.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class RoadAlignment:
    """One step's dense road reading."""

    log_length: float  # log of the step's metric length (m)
    sigma_log: float  # its standard deviation from the fit (residual-scaled, pixels taken as independent)
    normal: np.ndarray  # the road's unit normal in the second camera (pointing down to the road)
    pixels: int  # pixels that took part in the last iteration
    rms: float  # robust RMS of the photometric residual (gray levels, 0-255)


def _pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    out = [image.astype(np.float32)]
    for _ in range(levels - 1):
        out.append(cv2.pyrDown(out[-1]))
    return out


def _level_K(K: np.ndarray, level: int) -> np.ndarray:
    """Intrinsics at pyramid level `level` (pyrDown halves about pixel centres)."""
    f = 0.5**level
    Kl = np.asarray(K, float).copy()
    Kl[0, 0] *= f
    Kl[1, 1] *= f
    Kl[0, 2] = (Kl[0, 2] + 0.5) * f - 0.5
    Kl[1, 2] = (Kl[1, 2] + 0.5) * f - 0.5
    return Kl


def align_road(prev: np.ndarray, cur: np.ndarray, K: np.ndarray, motion: np.ndarray, camera_height: float,
               length0: float, mask: np.ndarray, normal0: np.ndarray | None = None, levels: int = 3,
               iterations: int = 10, max_pixels: int = 6000, max_range_m: float = 20.0,
               search_log: float = 0.7, auto_mask: bool = True) -> RoadAlignment | None:
    """Fit the road's plane-induced homography between `prev` and `cur` (gray, uint8) for the step `motion`
    (4x4, frame 1 in frame 0; only its rotation and the direction of its translation are used), starting from
    a step of `length0` metres over a road with normal `normal0` in the second camera (default: the image's
    y axis). `mask` (uint8, the size of `cur`) marks where the road is expected in `cur`. None when too few
    textured road pixels stay inside both images or the fit leaves the plausible range."""
    t = np.asarray(motion, float)[:3, 3]
    if not np.isfinite(t).all() or np.linalg.norm(t) < 1e-12 or length0 <= 0 or camera_height <= 0:
        return None
    t_hat = t / np.linalg.norm(t)
    R = np.asarray(motion, float)[:3, :3]
    n0 = np.array([0.0, 1.0, 0.0]) if normal0 is None else np.asarray(normal0, float) / np.linalg.norm(normal0)
    m = length0 * n0 / camera_height
    P0, P1 = _pyramid(prev, levels), _pyramid(cur, levels)
    masks = [cv2.resize(mask, (P.shape[1], P.shape[0]), interpolation=cv2.INTER_NEAREST) for P in P1]
    result = None
    searched = False
    for level in range(levels - 1, -1, -1):
        lv = _Level.build(P0[level], P1[level], masks[level], _level_K(K, level), R, t_hat, camera_height,
                          max_range_m, max_pixels)
        if lv is None:
            continue
        if not searched:  # a coarse search along the length first: GN alone can slide into a mover's minimum
            cands = [m * f for f in np.exp(np.linspace(-search_log, search_log, 15))]
            costs = [lv.cost(c) for c in cands]
            m = cands[int(np.argmin(costs))]
            searched = True
            if auto_mask:
                lv = lv.auto_masked(cands)
        elif auto_mask:
            lv = lv.auto_masked([m])
        if lv is None:
            continue
        for _ in range(iterations):
            out = lv.linearise(m)
            if out is None:
                return None
            r, J = out
            sigma = 1.4826 * float(np.median(np.abs(r))) + 1e-6
            c = 4.685 * sigma  # Tukey's biweight: movers and shadows that do not fit the road drop out
            wgt = np.where(np.abs(r) < c, (1.0 - (r / c) ** 2) ** 2, 0.0)
            H = (J * wgt[:, None]).T @ J
            g = (J * wgt[:, None]).T @ r
            try:
                delta = -np.linalg.solve(H + 1e-9 * np.trace(H) * np.eye(3), g)
            except np.linalg.LinAlgError:
                return None
            m = m + delta
            if not np.isfinite(m).all():
                return None
            if np.linalg.norm(delta) < 1e-5 * np.linalg.norm(m):
                break
        var_r = float(np.sum(wgt * r**2) / max(wgt.sum() - 3, 1.0))
        cov = var_r * np.linalg.pinv(H)
        grad_log = m / float(m @ m)
        result = (float(np.sqrt(max(grad_log @ cov @ grad_log, 0.0))), int((wgt > 0).sum()), float(np.sqrt(var_r)))
    if result is None:
        return None
    length = camera_height * float(np.linalg.norm(m))
    normal = m / np.linalg.norm(m)
    if not np.isfinite(length) or length <= 0 or normal[1] < np.cos(np.radians(20.0)):
        return None
    return RoadAlignment(float(np.log(length)), result[0], normal, result[1], result[2])


@dataclass
class _Level:
    """The road pixels of the second frame at one pyramid level and the first frame to warp them into."""

    I0: np.ndarray
    gx0: np.ndarray
    gy0: np.ndarray
    K: np.ndarray
    rays: np.ndarray  # 3 x N, the template pixels' rays (z = 1)
    Rp: np.ndarray  # R @ rays
    t_hat: np.ndarray
    template: np.ndarray  # the second frame's gray levels at those pixels

    @classmethod
    def build(cls, I0: np.ndarray, I1: np.ndarray, mask: np.ndarray, K: np.ndarray, R: np.ndarray,
              t_hat: np.ndarray, camera_height: float, max_range_m: float, max_pixels: int) -> "_Level | None":
        gx1 = cv2.Sobel(I1, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy1 = cv2.Sobel(I1, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        sel = (mask > 0) & (np.hypot(gx1, gy1) > 1.0)
        sel[: int(np.ceil(K[1, 2] + K[1, 1] * camera_height / max_range_m))] = False  # the road nearer than max_range_m
        v, u = np.nonzero(sel)
        if len(u) < 200:
            return None
        if len(u) > max_pixels:  # spread over the road, not only its strongest edges (a car's)
            keep = np.linspace(0, len(u) - 1, max_pixels).astype(int)
            v, u = v[keep], u[keep]
        rays = np.linalg.solve(K, np.stack([u, v, np.ones_like(u)]).astype(float))
        return cls(I0, cv2.Sobel(I0, cv2.CV_32F, 1, 0, ksize=3) / 8.0, cv2.Sobel(I0, cv2.CV_32F, 0, 1, ksize=3) / 8.0,
                   K, rays, R @ rays, t_hat, I1[v, u].astype(float))

    def _project(self, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        q = self.Rp + self.t_hat[:, None] * (m @ self.rays)[None, :]
        z = q[2]
        ok = z > 1e-6
        x = self.K[0, 0] * q[0] / np.where(ok, z, 1.0) + self.K[0, 2]
        y = self.K[1, 1] * q[1] / np.where(ok, z, 1.0) + self.K[1, 2]
        h, w = self.I0.shape
        ok &= (x > 1) & (x < w - 2) & (y > 1) & (y < h - 2)
        return q, x, y, ok

    def _sample(self, img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return cv2.remap(img, x.astype(np.float32)[None], y.astype(np.float32)[None], cv2.INTER_LINEAR).ravel().astype(float)

    def auto_masked(self, cands: list[np.ndarray], min_shift_px: float = 1.0) -> "_Level | None":
        """The level without the pixels that the rotation alone explains better than any candidate road
        (monodepth2's auto-mask): a car ahead at the camera's speed looks static, the road under it cannot.
        Pixels whose candidates move them by under `min_shift_px` from the rotation-only warp stay."""
        zero = np.zeros(3)
        _, x0, y0, ok0 = self._project(zero)
        r0 = np.full(len(ok0), np.inf)
        r0[ok0] = np.abs(self._sample(self.I0, x0[ok0], y0[ok0]) - self.template[ok0])
        best = np.full(len(ok0), np.inf)
        shift = np.zeros(len(ok0))
        for c in cands:
            _, x, y, ok = self._project(c)
            r = np.full(len(ok), np.inf)
            r[ok] = np.abs(self._sample(self.I0, x[ok], y[ok]) - self.template[ok])
            best = np.minimum(best, r)
            shift = np.maximum(shift, np.hypot(x - x0, y - y0))
        keep = (best <= r0) | (shift < min_shift_px)
        if keep.sum() < 200:
            return None
        return _Level(self.I0, self.gx0, self.gy0, self.K, self.rays[:, keep], self.Rp[:, keep], self.t_hat,
                      self.template[keep])

    def cost(self, m: np.ndarray, trunc_gray: float = 20.0) -> float:
        """Truncated mean absolute photometric residual (pixels leaving the image count as truncated)."""
        _, x, y, ok = self._project(m)
        if ok.sum() < 100:
            return np.inf
        r = self._sample(self.I0, x[ok], y[ok]) - self.template[ok]
        r -= np.median(r)
        return float((np.minimum(np.abs(r), trunc_gray).sum() + trunc_gray * (~ok).sum()) / len(ok))

    def linearise(self, m: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Residuals (first frame warped minus second, less their median: a global brightness change) and
        their Jacobian in m, over the pixels that stay inside the first frame; None when under 100 do."""
        q, x, y, ok = self._project(m)
        if ok.sum() < 100:
            return None
        xo, yo = x[ok], y[ok]
        r = self._sample(self.I0, xo, yo) - self.template[ok]
        r -= np.median(r)
        gx, gy = self._sample(self.gx0, xo, yo), self._sample(self.gy0, xo, yo)
        zq, qx, qy = q[2, ok], q[0, ok], q[1, ok]
        du = gx * self.K[0, 0] / zq  # d gray / d q, then d q / d m = t_hat p^T
        dv = gy * self.K[1, 1] / zq
        dz = -(gx * self.K[0, 0] * qx + gy * self.K[1, 1] * qy) / zq**2
        s = du * self.t_hat[0] + dv * self.t_hat[1] + dz * self.t_hat[2]
        return r, s[:, None] * self.rays[:, ok].T
