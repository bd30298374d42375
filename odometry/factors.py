"""Factors of the sliding-window graph (LeoVR Sec. III-C).

- visual reprojection (eq. 8): gtsam's built-in projection factor with a Huber kernel;
- LiDAR point (eq. 10): the associated LiDAR point as a bearing + range measurement of the landmark
  from the camera pose (built-in bearing-range factor);
- depth geometric consistency (eqs. 11-13): one vectorized custom factor per frame pair over a sample
  of pixels inside the trusted region, resampled before every smoother update;
- the generator's depth as a prior on each frame's correction field (noise from its predicted sigma),
  and the frame's own LiDAR returns as a linear factor on that field.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from odometry.depth_field import CorrectionGrid, bilinear, bilinear_taps

HUBER_K = 1.345


def huber(sigma: float | np.ndarray, dim: int = 1, k: float = HUBER_K):
    base = (
        gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma))
        if np.isscalar(sigma)
        else gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, float))
    )
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k), base)


def projection_factor(uv: np.ndarray, pose_key: int, point_key: int, cal: gtsam.Cal3_S2, sigma_px: float):
    return gtsam.GenericProjectionFactorCal3_S2(np.asarray(uv, float), huber(sigma_px, 2), pose_key, point_key, cal)


def lidar_point_factor(
    p_cam: np.ndarray, pose_key: int, point_key: int, sigma_bearing_rad: float, sigma_range_m: float
):
    """The landmark seen from the camera at `p_cam` (camera frame, metres), i.e. theta_i P_k = L_k."""
    rng = float(np.linalg.norm(p_cam))
    noise = huber(np.array([sigma_bearing_rad, sigma_bearing_rad, sigma_range_m]))
    return gtsam.BearingRangeFactor3D(pose_key, point_key, gtsam.Unit3(np.asarray(p_cam, float)), rng, noise)


def _robust_scale(r: np.ndarray, k: float = HUBER_K) -> np.ndarray:
    """Per-residual square-root Huber weights for whitened residuals (IRLS inside one vector factor)."""
    a = np.abs(r)
    return np.sqrt(np.where(a <= k, 1.0, k / np.maximum(a, 1e-12)))


@dataclass
class FrameDepth:
    """What the graph knows of one frame's depth: generator log-depth and its gradient, the grid."""

    log_depth: np.ndarray  # H x W, log metres
    grid: CorrectionGrid
    maps: np.ndarray = field(init=False)  # 3 x (H * W): log depth, its u and v gradients, flat for sampling

    def __post_init__(self) -> None:
        grad_v, grad_u = np.gradient(self.log_depth)
        self.maps = np.stack([self.log_depth, grad_u, grad_v]).reshape(3, -1).astype(np.float64)


class DepthConsistency:
    """E_depth(D_i, D_j) over sampled pixels p of frame i (eqs. 11-13), in log depth:
    r = log z_j(P) - log D_j(pi(T_ji P)),  P = D_i(p) K^-1 p,
    i.e. the depth frame j should see at the reprojected pixel. Pixels leaving image j contribute 0.
    What depends only on the sample (rays, frame i's map and grid weights there) is computed once per
    sample, not at every evaluation: gtsam evaluates the factor many times per update."""

    def __init__(self, di: FrameDepth, dj: FrameDepth, K: np.ndarray, sigma_log: float) -> None:
        self.di, self.dj, self.K, self.sigma = di, dj, K, sigma_log
        self.Kinv = np.linalg.inv(K)
        self.set_samples(np.zeros(0), np.zeros(0))
        self.dim = 0

    def set_samples(self, u: np.ndarray, v: np.ndarray) -> None:
        """Pixels of frame i to evaluate (a fresh sample each smoother update); the count stays fixed."""
        if getattr(self, "dim", 0) and len(u) != self.dim:
            raise ValueError("sample count must stay the same once the factor exists")
        self.u, self.v, self.dim = np.asarray(u, float), np.asarray(v, float), len(u)
        self.ray = self.Kinv @ np.stack([self.u, self.v, np.ones_like(self.u)])  # 3 x M
        taps, wts = bilinear_taps(self.di.log_depth.shape, self.u, self.v)
        self.base_i = (self.di.maps[0][taps] * wts).sum(1)
        self.idx_i, self.w_i = self.di.grid.weights(self.u, self.v)
        self.B_i = None  # frame i's dense grid weights, built at the first Jacobian

    def _residual(self, Ti: np.ndarray, Tj: np.ndarray, ci: np.ndarray, cj: np.ndarray, parts: bool = False):
        h, w = self.dj.log_depth.shape
        D = np.exp(self.base_i + (np.asarray(ci)[self.idx_i] * self.w_i).sum(1))
        T_ji = np.linalg.inv(Tj) @ Ti
        Rray = T_ji[:3, :3] @ self.ray
        Pj = Rray * D + T_ji[:3, 3][:, None]
        z = Pj[2]
        ok = z > 0.1
        zs = np.where(ok, z, 1.0)
        qu = self.K[0, 0] * Pj[0] / zs + self.K[0, 2]
        qv = self.K[1, 1] * Pj[1] / zs + self.K[1, 2]
        ok &= (qu >= 0) & (qu <= w - 1) & (qv >= 0) & (qv <= h - 1)
        taps, wts = bilinear_taps((h, w), qu, qv)
        idx_j, w_j = self.dj.grid.weights(qu, qv)
        log_dj = (self.dj.maps[0][taps] * wts).sum(1) + (np.asarray(cj)[idx_j] * w_j).sum(1)
        r = np.where(ok, (np.log(zs) - log_dj) / self.sigma, 0.0)
        if not parts:
            return r
        return r, dict(ok=ok, D=D, Rray=Rray, zs=zs, Pj=Pj, T_ji=T_ji, taps=taps, wts=wts, idx_j=idx_j, w_j=w_j)

    def evaluate(self, Ti, Tj, ci, cj, jacobians: bool, poses: bool = False):
        """Robustly weighted residuals, the Jacobians (or None) and the per-pixel weights.
        Jacobians: (field i, field j), or with `poses` (pose i, pose j, field i, field j), the pose
        blocks in gtsam's right-perturbation chart [omega, v]: T -> T Exp(xi)."""
        r, p = self._residual(Ti, Tj, ci, cj, parts=True)
        s = _robust_scale(r)
        if not jacobians:
            return s * r, None, s
        ok, D, Rray, zs, Pj = (p[k] for k in ("ok", "D", "Rray", "zs", "Pj"))
        # image gradient of log D_j (generator map plus correction field) where Pj projects
        gu, gv = (self.dj.maps[1:][:, p["taps"]] * p["wts"]).sum(2)
        fu, fv = self.dj.grid.offset_gradient(cj, p["idx_j"], p["w_j"])
        gu, gv = gu + fu, gv + fv
        # d r / d Pj: log z_j minus log D_j at the pixel Pj projects to (pinhole Jacobian times gradient)
        fx, fy = self.K[0, 0], self.K[1, 1]
        w = np.where(ok, s / self.sigma, 0.0)
        # 3 x M
        dr_dP = np.stack([-gu * fx / zs, -gv * fy / zs, 1.0 / zs + (gu * fx * Pj[0] + gv * fy * Pj[1]) / zs**2]) * w
        if self.B_i is None:
            self.B_i = self.di.grid.dense(self.idx_i, self.w_i)
        # d r / d log D_i: Pj moves along R ray * D
        J_ci = (dr_dP * (Rray * D)).sum(0)[:, None] * self.B_i
        J_cj = -w[:, None] * self.dj.grid.dense(p["idx_j"], p["w_j"])
        if not poses:
            return s * r, (J_ci, J_cj), s
        # pose i: Pj = R_ji (P + omega x P + v) + t_ji, with P = D ray the point in frame i
        R = p["T_ji"][:3, :3]
        b = R.T @ dr_dP
        J_Ti = np.c_[np.cross((self.ray * D).T, b.T), b.T]
        # pose j: Pj -> Pj - omega x Pj - v
        J_Tj = np.c_[np.cross(dr_dP.T, Pj.T), -dr_dP.T]
        return s * r, (J_Ti, J_Tj, J_ci, J_cj), s


class LidarDepth:
    """The frame's own LiDAR returns on its correction field: r = (log G(p) + B(p) c - log z) / sigma."""

    def __init__(self, fd: FrameDepth, u: np.ndarray, v: np.ndarray, z: np.ndarray, sigma_log: float) -> None:
        self.B = fd.grid.dense_weights(u, v)
        self.b = (np.log(z) - bilinear(fd.log_depth, u, v)) / sigma_log
        self.B = self.B / sigma_log

    def factor(self, key: int):
        def err(this, values, H):
            c = values.atVector(this.keys()[0])
            r = self.B @ c - self.b
            s = _robust_scale(r)
            if H is not None:
                H[0] = s[:, None] * self.B
            return s * r

        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(self.b)), [key], err)


def consistency_factor(dc: DepthConsistency, keys: list[int]):
    """gtsam custom factor on (pose_i, pose_j, field_i, field_j); all four Jacobian blocks analytic, so
    one residual evaluation per linearisation (finite differences through Pose3.retract took 13)."""

    def err(this, values, H):
        ki, kj, kci, kcj = this.keys()
        Ti, Tj = values.atPose3(ki).matrix(), values.atPose3(kj).matrix()
        r, J, _ = dc.evaluate(Ti, Tj, values.atVector(kci), values.atVector(kcj), H is not None, poses=True)
        if H is not None:
            H[0], H[1], H[2], H[3] = J
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(dc.dim), keys, err)
