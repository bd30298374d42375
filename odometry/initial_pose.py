"""Initial pose of each new frame: KISS-ICP on the LiDAR scan, or PnP + RANSAC on features whose 3D
position is known, whichever explains more of the frame's feature matches (a Mid-40 cone is often too
narrow for ICP; a textureless or dark image too poor for PnP)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import gtsam
import numpy as np

from leovr.data.io import MIN_SCAN_POINTS
from leovr.geometry import invert_T, orthonormalized, skew


@dataclass
class PoseGuess:
    T_world_cam: np.ndarray
    source: str  # "icp", "pnp", "constant_velocity" or "first"
    inliers: int


class LidarOdometry:
    """KISS-ICP on scans, reported as camera poses in the world frame of the first camera, each with the
    covariance of its registration (`covariance`). `deskew=False` (the graph's front end): the scans
    come deskewed by leovr, or carry no times. `deskew=True` (the `kiss_icp` baseline): KISS-ICP
    deskews each scan itself from its point times with its own last motion, as its pipeline does; its
    pose then refers to the end of the sweep."""

    def __init__(
        self, T_cam_lidar: np.ndarray, max_range: float = 100.0, cov_inflation: float = 1.0, deskew: bool = False
    ) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        cfg = KISSConfig()
        cfg.data.deskew = deskew
        cfg.data.max_range = max_range
        cfg.data.min_range = 1.0
        cfg.mapping.voxel_size = max_range / 100.0
        cfg.registration.max_num_threads = 1  # as fast as its pool on 2 cores (48 KITTI scans: 1.92 vs 1.95 s)
        self.icp = KissICP(cfg)
        self.T_cl = T_cam_lidar
        self.cov_inflation = cov_inflation
        self.frames = 0
        self.skipped_last = False  # the last scan had too few points: KISS-ICP's last pose is an older frame's
        self.spinning: bool | None = None  # a 360-degree scanner (VLP-16, HDL-64), from the first scan
        self._fit: tuple | None = None  # the last registration's inputs, for `covariance` (computed on demand)
        self._covariance: np.ndarray | None = None

    def register(
        self, points: np.ndarray | None, times: np.ndarray | None = None, guess: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Camera pose (camera to world) after registering this scan, or None when it has too few points or
        is None (the frame has no scan). `times` (one per point, any unit: KISS-ICP normalises them over the
        sweep) are used only with `deskew=True`. `guess`: the camera's motion since the previous scan (pose of
        this camera in that one), KISS-ICP's prediction in place of its constant velocity (which misses the start
        of a turn by the turn's whole rate, further than its correspondence distance reaches), at the length of
        KISS-ICP's own last step (along a straight road a scan constrains its step length least, and a
        registration started from another length keeps part of it); ignored after a skipped scan."""
        self._fit, self._covariance = None, None
        if points is None or len(points) < MIN_SCAN_POINTS:
            self.skipped_last = True
            return None
        xyz = np.ascontiguousarray(points[:, :3], np.float64)
        if self.spinning is None:
            self.spinning = is_spinning(xyz)
        timed = self.icp.config.data.deskew and times is not None and len(times) == len(xyz) and np.ptp(times) > 0
        local_map = self.icp.local_map.point_cloud() if self.frames else None  # before this scan joins it
        stamps = np.asarray(times, np.float64) if timed else np.array([])
        if guess is not None and self.frames and not self.skipped_last:  # a guess from the frame KISS-ICP last saw
            delta = orthonormalized(invert_T(self.T_cl) @ guess @ self.T_cl)
            own, length = float(np.linalg.norm(self.icp.last_delta[:3, 3])), float(np.linalg.norm(delta[:3, 3]))
            moves = np.linalg.norm(guess[:3, 3]) > 1e-6  # a rotation only (standing) has no direction to stretch
            if own > 0 and length > 1e-9 and moves:  # the guess's rotation and direction, KISS-ICP's own step length
                delta[:3, 3] *= own / length
            source = self._register_predicted(xyz, stamps, delta)
        else:
            _, source = self.icp.register_frame(xyz, stamps)
        self.frames += 1
        self.skipped_last = False
        T_l0_l = self.icp.last_pose
        self._fit = (source, local_map, T_l0_l, 3.0 * self.icp.adaptive_threshold.get_threshold())
        return self.T_cl @ T_l0_l @ invert_T(self.T_cl)

    def restart(self, points: np.ndarray) -> np.ndarray | None:
        """KISS-ICP started again from this scan as the first one (its map and motion cleared): a causal run's
        first scan, deskewed once the first step is known. The first camera's pose, as `register` gives it."""
        from kiss_icp.kiss_icp import KissICP

        self.icp = KissICP(self.icp.config)
        self.frames, self.skipped_last = 0, False
        return self.register(points)

    def _register_predicted(self, xyz: np.ndarray, stamps: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """KISS-ICP's `register_frame` started from the LiDAR motion `delta` instead of its last one. Its
        adaptive threshold is still fed the deviation from its own constant-velocity prediction: the
        threshold sets the match distance that the registration covariance is computed with (and that
        `icp_cov_inflation` was calibrated on), and a threshold shrunk by good predictions made the graph
        trust KISS-ICP up to 5x more in turns than its errors there deserve (tuning lap 3000)."""
        icp = self.icp
        frame = icp.preprocessor.preprocess(xyz, stamps, delta)
        source, frame_downsample = icp.voxelize(frame)
        sigma = icp.adaptive_threshold.get_threshold()
        new_pose = icp.registration.align_points_to_map(
            points=source,
            voxel_map=icp.local_map,
            initial_guess=icp.last_pose @ delta,
            max_correspondance_distance=3 * sigma,
            kernel=sigma,
        )
        icp.adaptive_threshold.update_model_deviation(invert_T(icp.last_pose @ icp.last_delta) @ new_pose)
        icp.local_map.update(frame_downsample, new_pose)
        icp.last_delta = invert_T(icp.last_pose) @ new_pose
        icp.last_pose = new_pose
        return source

    @property
    def covariance(self) -> np.ndarray | None:
        """6 x 6 covariance of the last registered pose (camera frame, gtsam Pose3 order: rotation,
        translation), x `cov_inflation`; zero for the first scan (it defines the map's frame); None
        without a registration or with too few matches. Computed on first use (a KD-tree query)."""
        if self._covariance is None and self._fit is not None:
            source, local_map, T_l0_l, max_dist = self._fit
            if local_map is None:
                self._covariance = np.zeros((6, 6))
            elif (cov_l := registration_covariance(source, local_map, T_l0_l, max_dist)) is not None:
                Ad = gtsam.Pose3(self.T_cl).AdjointMap()
                self._covariance = self.cov_inflation * (Ad @ cov_l @ Ad.T)
            self._fit = None
        return self._covariance


def first_step(scan0: np.ndarray | None, scan1: np.ndarray | None, T_cam_lidar: np.ndarray) -> np.ndarray | None:
    """The camera's motion from the first frame to the second (pose of camera 1 in camera 0) by KISS-ICP on
    the two raw scans: the deskew motion of the first sweeps, before the front end has estimated any step
    (without it they are deskewed as if standing, which at 80 km/h misplaces the first map by metres).
    None when either scan has too few points."""
    if scan0 is None or scan1 is None:
        return None
    odo = LidarOdometry(T_cam_lidar)
    if odo.register(scan0) is None:
        return None
    return odo.register(scan1)


MIN_JUDGED_RETURNS = 100  # a scan is judged spinning or not on at least this many returns


def is_spinning(xyz: np.ndarray, sectors: int = 12) -> bool:
    """Whether a scan comes from a spinning LiDAR: returns in most of the azimuth sectors around the
    sensor (a Mid-40's 38-degree cone fills one or two of twelve; a VLP-16 or HDL-64 sweep nearly all,
    less what the car body hides)."""
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    counts = np.bincount(((az + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors, minlength=sectors)
    return bool(np.mean(counts >= max(5, 0.002 * len(xyz))) >= 0.5)


def registration_covariance(
    source: np.ndarray, target: np.ndarray, T: np.ndarray, max_dist: float
) -> np.ndarray | None:
    """Covariance (6 x 6, body frame, rotation then translation) of the point-to-point alignment T of
    `source` onto `target`: the inverse Gauss-Newton Hessian of the matched residuals, scaled by their
    variance. A poor fit (large residuals), few matches or a narrow spread of points (a Mid-40 cone:
    little lever arm for the rotation about its axis) give a large covariance. Point-to-point: it
    does not see surfaces that leave a direction free (a plane, a corridor). It assumes independent
    residuals, so it is over-confident by a roughly constant factor that the caller calibrates
    (`icp_cov_inflation`). None with fewer than 30 matches."""
    from scipy.spatial import cKDTree

    if len(source) < 30 or len(target) < 30:
        return None
    q = source @ T[:3, :3].T + T[:3, 3]
    d, j = cKDTree(target).query(q, distance_upper_bound=max_dist)
    ok = np.isfinite(d)
    if ok.sum() < 30:
        return None
    p, r = source[ok], q[ok] - target[j[ok]]
    var = max(float(np.mean(np.sum(r**2, axis=1))) / 3.0, 1e-8)
    # d(T exp(xi) p) / d xi = R [-[p]x | I]; R drops out of J^T J
    S = np.sum(p, axis=0)
    PP = p.T @ p
    H = np.zeros((6, 6))
    H[:3, :3] = np.trace(PP) * np.eye(3) - PP  # sum [p]x^T [p]x
    H[:3, 3:] = skew(S)  # sum -[p]x^T = sum [p]x
    H[3:, :3] = H[:3, 3:].T
    H[3:, 3:] = len(p) * np.eye(3)
    try:
        return np.linalg.inv(H / var)
    except np.linalg.LinAlgError:
        return None


def pnp_pose(
    obj: np.ndarray, img: np.ndarray, K: np.ndarray, reproj_px: float = 2.0
) -> tuple[np.ndarray | None, np.ndarray]:
    """Camera pose (camera to world) from world points and their pixels; also the inlier mask."""
    mask = np.zeros(len(obj), bool)
    if len(obj) < 8:
        return None, mask
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        obj.astype(np.float64),
        img.astype(np.float64),
        K,
        None,
        iterationsCount=200,
        reprojectionError=reproj_px,
        confidence=0.999,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )
    if not ok or inl is None or len(inl) < 6:
        return None, mask
    mask[inl.ravel()] = True
    R, _ = cv2.Rodrigues(rvec)
    T_cw = np.eye(4)
    T_cw[:3, :3], T_cw[:3, 3] = R, tvec.ravel()
    return invert_T(T_cw), mask


def reprojection_inliers(
    T_world_cam: np.ndarray, obj: np.ndarray, img: np.ndarray, K: np.ndarray, reproj_px: float = 2.0
) -> np.ndarray:
    """Which world points project within `reproj_px` of their pixel from this pose."""
    if len(obj) == 0:
        return np.zeros(0, bool)
    T_cw = invert_T(T_world_cam)
    P = obj @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = P[:, 2]
    uv = (P @ K.T)[:, :2] / np.where(z > 1e-6, z, 1e-6)[:, None]
    return (z > 0.1) & (np.linalg.norm(uv - img, axis=1) < reproj_px)


def choose_pose(
    candidates: dict[str, np.ndarray | None], obj: np.ndarray, img: np.ndarray, K: np.ndarray, reproj_px: float = 2.0
) -> PoseGuess | None:
    """The candidate with the most reprojection inliers (ties: the order given)."""
    best = None
    for name, T in candidates.items():
        if T is None:
            continue
        n = int(reprojection_inliers(T, obj, img, K, reproj_px).sum())
        if best is None or n > best.inliers:
            best = PoseGuess(T, name, n)
    return best
