"""Camera motion without LiDAR: the geometry of the textbook VO (`odometry.mono_vo`) with a metric
step length. Rotation and translation direction come from the essential matrix of Lucas-Kanade
tracks (USAC with local optimisation rather than the textbook's RANSAC); the step length comes from two sources fused by
a Kalman filter on its logarithm:

- relative scale: corners triangulated at the previous step, with metric depth, are tracked on;
  triangulating them again with a unit step gives the change of step length. With a vehicle's
  inertia as a second opinion on that change (the step length of a car at 10 Hz changes by a few
  per cent per frame);
- absolute scale from the road, when the camera's height above it is known (`odometry.ground_plane`):
  the height over the road plane of road corners triangulated with a unit step. Unbiased, and it
  also measures the generator's depth bias, which then corrects the generator's depth;
- absolute scale from the generator (noisy, unbiased over time only as far as the generator is): the
  generator's depth at the tracked corners divided by their unit-step triangulated depth, corrected
  by the bias the road measured. Used in frames where the road gives no reading.

Both are medians weighted by how well each corner's depth is known: the generator's predicted
uncertainty, and the triangulation's, which falls with the corner's parallax.

So the generator's depth fixes the scale only, averaged over frames, and never shapes the motion.
A step whose rotation-compensated parallax is too small to triangulate (the vehicle stands) keeps
the rotation and moves by nothing."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from leovr.geometry import fundamental, invert_T
from odometry.ground_plane import fit_ground, road_corners
from odometry.mono_vo import corners, follow, gray, relative_motion


@dataclass
class MonoStep:
    """One frame's motion from the previous frame (pose_cur = pose_prev @ T_rel)."""

    T_rel: np.ndarray
    inliers: int
    parallax_px: float
    scale_source: str  # "ground", "depth" (each "+tracks" when tracks gave the change), "standing" or "constant_speed"


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def triangulate(T_0_1: np.ndarray, p0: np.ndarray, p1: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Points (N x 3, in camera 0) seen at p0 in camera 0 and p1 in camera 1; T_0_1 = pose of 1 in 0."""
    T_1_0 = invert_T(T_0_1)
    X = cv2.triangulatePoints(K @ np.eye(3, 4), K @ T_1_0[:3], p0.T.astype(np.float64), p1.T.astype(np.float64))
    return (X[:3] / np.where(np.abs(X[3]) > 1e-12, X[3], 1e-12)).T


def sampson_px(T_rel: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray) -> np.ndarray:
    """First-order distance (pixels) of each match from the epipolar geometry of the motion T_rel
    (pose of the second camera in the first)."""
    F = fundamental(invert_T(T_rel), K)
    x0 = np.c_[uv0, np.ones(len(uv0))]
    x1 = np.c_[uv1, np.ones(len(uv1))]
    Fx0, Ftx1 = x0 @ F.T, x1 @ F
    num = np.sum(x1 * Fx0, axis=1) ** 2
    den = Fx0[:, 0] ** 2 + Fx0[:, 1] ** 2 + Ftx1[:, 0] ** 2 + Ftx1[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-12))


def in_front(T_0_1: np.ndarray, p0: np.ndarray, p1: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Per match: whether its triangulated point lies in front of both cameras (cheirality)."""
    X = triangulate(T_0_1, p0, p1, K)
    X1 = (X - T_0_1[:3, 3]) @ T_0_1[:3, :3]
    return (X[:, 2] > 0) & (X1[:, 2] > 0) & np.isfinite(X).all(axis=1)


def rotation_parallax(p0: np.ndarray, p1: np.ndarray, R_1_0: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel displacement left once the rotation is taken out (the part that carries depth)."""
    h = np.c_[p0, np.ones(len(p0))] @ (K @ R_1_0 @ np.linalg.inv(K)).T
    return np.linalg.norm(h[:, :2] / h[:, 2:3] - p1, axis=1)


@dataclass
class MonoMotion:
    """Frame-to-frame motion with a metric step length; `step(image, depth, log_sigma)` per frame,
    with the generator's depth and log-sigma of that frame."""

    K: np.ndarray
    depth_sigma_log: float = 0.2  # how far one frame's depth-based step length may be off (log)
    track_sigma_log: float = 0.05  # how far the relative scale of tracked corners may be off (log)
    # how much the step length changes from one frame to the next (log; inertia; chosen on development clips)
    speed_sigma_log: float = 0.005
    min_parallax_px: float = 1.0  # below: the camera stands
    max_corners: int = 2000
    camera_height: float | None = None  # metres above the road; None: no road-plane scale
    ground_sigma_log: float = 0.08  # how far one frame's road-based step length may be off (log), at 20 road corners
    bias_rate: float = 0.2  # how fast the generator's depth bias estimate follows the road's
    max_road_corners: int = 600

    def __post_init__(self) -> None:
        self.prev_gray: np.ndarray | None = None
        self.prev_depth: np.ndarray | None = None
        self.prev_w: np.ndarray | None = None
        self.carried_uv = np.zeros((0, 2))  # corners of the previous frame with metric depth
        self.carried_z = np.zeros(0)
        self.log_len: float | None = None  # Kalman state: log step length (m) and its variance
        self.var = 0.0
        self.last = MonoStep(np.eye(4), 0, 0.0, "constant_speed")
        self.heading: np.ndarray | None = None  # unit direction of the last step made while moving
        self.depth_log_bias: float | None = None  # log of (generator depth / metric depth), measured on the road
        self.ground_rejected: list[float] = []  # road readings (log step length) refused in a row

    @property
    def depth_scale(self) -> float:
        """Factor that brings the generator's depth to the road's metric scale (1 until measured)."""
        return 1.0 if self.depth_log_bias is None else float(np.exp(-self.depth_log_bias))

    def _depth_at(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.prev_depth.shape
        ui = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        vi = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        return self.prev_depth[vi, ui], self.prev_w[vi, ui]

    def _fuse(self, absolute: tuple[float, float] | None, log_ratio: float | None) -> None:
        """Kalman update of the log step length: predict the change from the tracks' relative scale
        fused with the vehicle's inertia (no change), then correct by an absolute measurement
        (log length, its sigma). Without a state yet, the measurement starts it."""
        if self.log_len is None:
            if absolute is not None:
                self.log_len, self.var = absolute[0], max(absolute[1], 0.25 if self.camera_height else 0.0) ** 2
            return
        q, r = self.speed_sigma_log**2, self.track_sigma_log**2
        if log_ratio is not None:
            self.log_len += log_ratio * q / (q + r)
            self.var += q * r / (q + r)
        else:
            self.var += q
        if absolute is not None:
            gain = self.var / (self.var + absolute[1] ** 2)
            self.log_len += gain * (absolute[0] - self.log_len)
            self.var *= 1.0 - gain

    def _implausible(self, log_meas: float, sigma: float, gate_sigmas: float = 3.0) -> bool:
        """Whether an absolute step length is further from the predicted one than the filter's and
        the measurement's uncertainty allow."""
        spread = self.var + self.speed_sigma_log**2 + sigma**2
        return (log_meas - self.log_len) ** 2 > gate_sigmas**2 * spread

    def _keep_heading(
        self, motion: np.ndarray, p0: np.ndarray, p1: np.ndarray, inl: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The essential matrix's motion points against the direction of travel (the last moving step's,
        else the camera's axis). A vehicle cannot reverse between two frames without standing still in
        between; OpenCV's cheirality vote leaves far points out, so near movers can carry it (traffic
        driving off ahead moves along the same epipolar lines as if the camera went backwards; KITTI raw
        clip, frames 31-47: 14-83 matches for backwards, 850-5100 in front for forwards). Flips the
        direction, keeping the rotation and the epipole, where at least as many matches fit the flipped
        motion and lie in front of both cameras as fit the original; those matches are its inliers."""
        flipped = motion.copy()
        flipped[:3, 3] *= -1.0
        support = [(sampson_px(T, p0, p1, self.K) < 1.0) & in_front(T, p0, p1, self.K) for T in (motion, flipped)]
        return (flipped, support[1]) if support[1].sum() >= max(8, support[0].sum()) else (motion, inl)

    def _road_reading(self, p0: np.ndarray, p1: np.ndarray, motion: np.ndarray) -> tuple[float, float] | None:
        """From the road plane of the tracked road corners: the log step length and its sigma; None where
        there is no road reading."""
        if self.camera_height is None or len(p0) < 8:
            return None
        X = triangulate(motion, p0, p1, self.K)
        par = rotation_parallax(p0, p1, motion[:3, :3].T, self.K)
        fit = fit_ground(X[par > self.min_parallax_px])
        if fit is None:
            return None
        return float(np.log(self.camera_height / fit.height)), self.ground_sigma_log * np.sqrt(
            max(1.0, 20.0 / fit.inliers)
        )

    def step(self, image: np.ndarray, depth: np.ndarray, log_sigma: np.ndarray) -> MonoStep | None:
        """The motion from the previous frame to this one (None for the first frame); then this frame's depth
        kept for the next step."""
        result = self.motion(image)
        self.remember(depth, log_sigma)
        return result

    def motion(self, image: np.ndarray) -> MonoStep | None:
        """The motion from the previous frame to this one; None for the first frame. It needs the previous
        frame's depth (`remember`) but not this frame's: it can run while the generator computes that."""
        cur = gray(image)
        prev = self.prev_gray
        result = None
        if prev is not None:
            n_old = len(self.carried_uv)
            p0 = np.r_[self.carried_uv, corners(prev, self.max_corners)]
            road = (
                road_corners(prev, self.K, self.camera_height, self.max_road_corners)
                if self.camera_height
                else np.zeros((0, 2))
            )
            result = self._motion(prev, cur, p0, n_old, road)
        self.prev_gray = cur
        if result is not None:
            self.last = result
        return result

    def remember(self, depth: np.ndarray, log_sigma: np.ndarray) -> None:
        """This frame's generator depth and log-sigma, which the next step's length is read from."""
        self.prev_depth = depth
        self.prev_w = 1.0 / np.maximum(np.exp(log_sigma) / np.maximum(depth, 1e-3), 1e-3) ** 2

    def _checked_ground(self, ground: tuple[float, float] | None) -> tuple[float, float] | None:
        """The road's step-length reading (log length, sigma), None where the filter finds it implausible; three
        refused readings in a row that agree with each other mean the filter, whose state is only inertia
        since, is what is wrong: it restarts from the road."""
        if ground is None:
            return None
        if self.log_len is None or not self._implausible(*ground):
            self.ground_rejected = []
            return ground
        self.ground_rejected = (self.ground_rejected + [ground[0]])[-3:]
        recent = np.array(self.ground_rejected)
        if len(recent) == 3 and np.ptp(recent) < 3 * self.ground_sigma_log:
            self.log_len, self.ground_rejected = None, []
            return float(np.median(recent)), ground[1]
        return None

    def _carry(self, T: np.ndarray, X: np.ndarray, front: np.ndarray, uv1: np.ndarray) -> None:
        """Carry this step's corners on (`X`: metric, first camera; `uv1`: where they are in the new image)
        with their metric depth in the new frame, for the next step's relative length."""
        T_1_0 = invert_T(T)
        X1 = X @ T_1_0[:3, :3].T + T_1_0[:3, 3]
        carry = front & (X1[:, 2] > 0.5)
        self.carried_uv, self.carried_z = uv1[carry], X1[carry, 2]

    def _motion(self, prev: np.ndarray, cur: np.ndarray, p0: np.ndarray, n_old: int, road: np.ndarray) -> MonoStep:
        keep_last = MonoStep(self.last.T_rel, 0, 0.0, "constant_speed")
        if len(p0) < 8:
            self.carried_uv, self.carried_z = np.zeros((0, 2)), np.zeros(0)
            return keep_last
        n_main = len(p0)
        p0 = np.r_[p0, road]  # the road corners are tracked too, but only read for the road plane
        p1, ok = follow(prev, cur, p0)
        road_idx = n_main + np.nonzero(ok[n_main:])[0]
        idx = np.nonzero(ok[:n_main])[0]
        # USAC_ACCURATE (local optimisation) gets the rotation several times closer than plain RANSAC,
        # and a tenth of a degree of rotation is a pixel of the parallax the step length is read from
        motion, inl = relative_motion(p0[idx], p1[idx], self.K, method=cv2.USAC_ACCURATE)
        if motion is None:
            self.carried_uv, self.carried_z = np.zeros((0, 2)), np.zeros(0)
            return keep_last
        heading = self.heading if self.heading is not None else np.array([0.0, 0.0, 1.0])  # else the camera's axis
        if motion[:3, 3] @ heading < 0:
            motion, inl = self._keep_heading(motion, p0[idx], p1[idx], inl)
        good = idx[inl]
        R_1_0 = motion[:3, :3].T
        flow = rotation_parallax(p0[good], p1[good], R_1_0, self.K)
        parallax = float(np.median(flow))
        if parallax < self.min_parallax_px:  # standing: rotation only, tracks carried on unchanged
            T = np.eye(4)
            T[:3, :3] = motion[:3, :3]
            self.carried_uv, self.carried_z = np.zeros((0, 2)), np.zeros(0)
            self.heading = None  # from standing still the vehicle may set off either way
            return MonoStep(T, len(good), parallax, "standing")
        X = triangulate(motion, p0[good], p1[good], self.K)  # unit step, camera 0
        z = X[:, 2]
        front = (z > 1e-3) & np.isfinite(z)
        # a corner's triangulated depth is known to about (1 px / its parallax), relatively
        tri_var = (1.0 / np.maximum(flow, 0.1)) ** 2
        # absolute: generator depth over unit-step depth
        gd, gw = self._depth_at(p0[good])
        use = front & (gd > 0)
        log_meas = None
        if use.sum() >= 20:
            log_meas = float(np.log(weighted_median(gd[use] / z[use], 1.0 / (1.0 / gw[use] + tri_var[use]))))
        # relative: corners carried from the last step with metric depth
        old = front & (good < n_old)
        log_ratio = None
        if old.sum() >= 20 and self.log_len is not None:
            log_ratio = float(np.log(weighted_median(self.carried_z[good[old]] / z[old], 1.0 / tri_var[old])))
            log_ratio -= float(self.log_len)
        ground = self._road_reading(p0[road_idx], p1[road_idx], motion)
        ground = self._checked_ground(ground)
        bias = self.depth_log_bias or 0.0
        depth = None if log_meas is None else (log_meas - bias, self.depth_sigma_log)
        if ground is None and self.log_len is not None and depth is not None and self._implausible(*depth):
            # both scale readings come from this essential matrix: a wrong one (a rare bad RANSAC draw
            # in forward motion) shows as a jump in speed no vehicle makes; keep the last motion instead
            self.carried_uv, self.carried_z = np.zeros((0, 2)), np.zeros(0)
            self.var += self.speed_sigma_log**2
            return MonoStep(self.last.T_rel, 0, parallax, "constant_speed")
        absolute = ground if ground is not None else depth
        self._fuse(absolute, log_ratio)
        source = "constant_speed" if absolute is None else ("ground" if ground is not None else "depth")
        source += "+tracks" if log_ratio is not None and absolute is not None else ""
        if ground is not None and log_meas is not None:  # the road measures the generator's depth bias
            resid = log_meas - float(self.log_len)
            old_bias = resid if self.depth_log_bias is None else self.depth_log_bias
            self.depth_log_bias = old_bias + self.bias_rate * (resid - old_bias)
        length = float(np.exp(self.log_len)) if self.log_len is not None else 0.0
        self.heading = motion[:3, 3].copy()
        T = motion.copy()
        T[:3, 3] *= length
        self._carry(T, X * length, front, p1[good])
        return MonoStep(T, len(good), parallax, source)


def parallax_agrees(
    T_rel: np.ndarray,
    X0: np.ndarray,
    uv0: np.ndarray,
    uv1: np.ndarray,
    K: np.ndarray,
    max_ratio: float = 3.0,
    min_px: float = 3.0,
) -> np.ndarray:
    """Per match: whether its parallax (the displacement left once the rotation is taken out) is
    within `max_ratio` of the parallax its depth-seeded point `X0` (first camera) predicts under the
    motion T_rel; matches whose predicted parallax is under `min_px` are not judged (the depth is
    too uncertain to tell)."""
    if not len(uv0):
        return np.zeros(0, bool)
    T_1_0 = invert_T(T_rel)
    X1 = X0 @ T_1_0[:3, :3].T + T_1_0[:3, 3]
    ahead = X1[:, 2] > 1e-3
    proj = (X1 @ K.T)[:, :2] / np.where(ahead, X1[:, 2], 1.0)[:, None]
    predicted = rotation_parallax(uv0, proj, T_1_0[:3, :3], K)
    seen = rotation_parallax(uv0, uv1, T_1_0[:3, :3], K)
    judged = ahead & (predicted >= min_px)
    ratio = seen / np.maximum(predicted, 1e-9)
    return ~judged | ((ratio >= 1.0 / max_ratio) & (ratio <= max_ratio))


def epipolar_agrees(
    T_rel: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, K: np.ndarray, px: float = 2.0, min_fraction: float = 0.5
) -> bool:
    """Whether most matches satisfy the epipolar geometry of a candidate motion (a PnP pose built on
    wrong depth does not); a motion too small to define an epipolar geometry is not refused."""
    if len(uv0) < 8:
        return False
    if np.linalg.norm(T_rel[:3, 3]) < 1e-3:
        return True
    return float(np.mean(sampson_px(T_rel, uv0, uv1, K) < px)) >= min_fraction
