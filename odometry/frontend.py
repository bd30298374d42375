"""The visual-LiDAR front end: per new frame, ORB features matched to the previous frame, LiDAR depth
associated to features, an initial pose (KISS-ICP or PnP, by a reprojection quality test, or constant
velocity), landmarks from consistent matches, and the trusted region for the depth factor: the convex
hull of the matches that agree with the camera motion (features on moving objects do not).

Without LiDAR the initial pose is the epipolar one (`odometry.mono_motion`: essential matrix, step
length from tracks and generator depth); a PnP pose is taken only where that fails and only if the
tracks' epipolar geometry agrees with it; new landmarks are triangulated from the two poses where the
parallax allows, seeded from the generator's depth elsewhere."""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from leovr.config import RefineConfig
from leovr.geometry import back_project, invert_T
from leovr.threads import Worker
from odometry.features import Features, detect, match
from odometry.initial_pose import (
    LidarOdometry,
    choose_pose,
    pnp_pose,
    reprojection_inliers,
)
from odometry.lidar_assoc import associate
from odometry.motion_gates import turning_as_the_images
from odometry.mono_motion import MonoMotion, MonoStep, epipolar_agrees, parallax_agrees, sampson_px, triangulate
from odometry.window_graph import FrameInput, Observation, WindowGraph


# With a LiDAR, a landmark seeded from the generator's depth (no return at its pixel) gets this depth prior (sigma /
# depth) instead of `graph.landmark_prior_rel`: the generator's learned scale may not set the poses' scale (tighter
# priors carried it into a cone LiDAR's steps; docs/decisions/0001-icp-covariance-inflation.md)
GENERATOR_LANDMARK_PRIOR_REL = 1.0
# a feature takes the depth of the LiDAR returns within this radius (px) when their depths spread by at most this
# share of their median (odometry.lidar_assoc.associate)
ASSOC_RADIUS_PX = 5.0
ASSOC_MAX_REL_SPREAD = 0.1
# Camera only (docs/decisions/0008-camera-only-loose-priors.md): the epipolar motion enters the graph with the
# rotation sigma of its precision (thousands of sub-pixel tracks), not the reprojection factors' on ORB matches,
# which pulled the heading off where it was looser (rad)
MONO_ODOMETRY_SIGMA_RAD = 0.0003
MONO_ODOMETRY_SIGMA_REL = 0.05  # its translation sigma per metre of step
MONO_GROUND_ODOMETRY_SIGMA_REL = 0.001  # ... where the road plane gave the step's length
# where the road gave the step, landmarks are triangulated from the metric motion once their rays part by this
# angle (deg; else seeded from the generator's depth) and get this depth prior (sigma / depth)
MONO_GROUND_TRIANGULATION_MIN_DEG = 0.3
MONO_TRIANGULATED_PRIOR_REL = 1.0
# a spinning LiDAR's sweep is deskewed over the mean length of KISS-ICP's last steps (this many): a sweep deskewed
# over a wrong length registers with the opposite error and the two feed each other; averaging damps that loop
# (docs/decisions/0014-deskew-with-kiss-icp-step.md)
SWEEP_STEP_FRAMES = 4
# With LiDAR, an initial-pose candidate (KISS-ICP's step, PnP) whose step length is off the median of the last
# STEP_LENGTH_FRAMES initial steps by more than STEP_LENGTH_CHANGE_REL of it and STEP_LENGTH_CHANGE_M is left out
# while another candidate holds: a vehicle's step changes little in a frame, and a PnP on matches of one depth, or a
# registration that slipped in a turn, can still reproject the most matches
STEP_LENGTH_FRAMES = 3
STEP_LENGTH_CHANGE_REL = 0.5
STEP_LENGTH_CHANGE_M = 0.3


@dataclass
class _Prev:
    index: int
    feats: Features
    cam_pts: np.ndarray  # N x 3 feature points in the camera frame (LiDAR depth, else generator depth)
    lidar_cam: list  # per feature: camera-frame LiDAR point or None
    landmark: np.ndarray  # per feature: landmark id or -1
    T_icp: np.ndarray | None


@dataclass
class FrontEnd:
    cfg: RefineConfig
    K: np.ndarray
    shape: tuple[int, int]
    T_cam_lidar: np.ndarray
    use_lidar: bool = True
    prev: _Prev | None = None
    next_landmark: int = 0
    velocity: np.ndarray = field(default_factory=lambda: np.eye(4))
    # the motion the next sweep is deskewed with: with a spinning LiDAR the last step as KISS-ICP measured it
    # (registered against its map) over the mean length of its last SWEEP_STEP_FRAMES steps, else `velocity`. The
    # initial pose is PnP's wherever it reprojects more matches, and its step length wobbles with the depth along the
    # view (docs/decisions/0014-deskew-with-kiss-icp-step.md)
    sweep_velocity: np.ndarray = field(default_factory=lambda: np.eye(4))
    _icp_lengths: list[float] = field(default_factory=list)  # KISS-ICP's last step lengths (m)
    _step_lengths: list[float] = field(default_factory=list)  # the last initial steps' lengths (m)
    sources: list[str] = field(default_factory=list)
    camera_height: float | None = None  # camera only: metres above the road (the road plane gives the scale)
    # camera only: the road's scale of the last processed frame's generator depth (read once the next frame's motion
    # may already be running ahead and moving MonoMotion's own)
    _scale: float = 1.0
    _worker: Worker | None = None  # camera only: the next frame's motion, computed ahead (`prefetch_motion`)
    _prefetched: tuple[int, Future] | None = None

    def __post_init__(self) -> None:
        cfg = self.cfg
        self.icp = (
            LidarOdometry(self.T_cam_lidar, cov_inflation=cfg.graph.icp_cov_inflation) if self.use_lidar else None
        )
        self.mono = None if self.use_lidar else MonoMotion(self.K, camera_height=self.camera_height)

    @property
    def depth_scale(self) -> float:
        """The factor applied to the generator's depth of the last frame: the road's scale (camera only,
        with a camera height), else 1."""
        return self._scale if self.mono is not None and self.camera_height else 1.0

    def prefetch_motion(self, index: int, image: Callable[[], np.ndarray]) -> None:
        """Camera only: start frame `index`'s motion from the last processed frame (`image()`: its image) in a
        worker thread, beside the graph of the last frame and the generator of this one (Lucas-Kanade and the
        essential matrix leave the interpreter lock); `process(index, ...)` takes it. It needs nothing of frame
        `index` but its image, so the motion is the one `process` would compute."""
        if self.mono is None:
            return
        if self._worker is None:
            self._worker = Worker("motion", threaded=True)
        self._prefetched = (index, self._worker.submit(lambda: self.mono.motion(image())))

    def close(self) -> None:
        """Wait for a motion computed ahead and stop its worker."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def _mono_step(self, index: int, image: np.ndarray, depth: np.ndarray, log_sigma: np.ndarray) -> MonoStep | None:
        """Camera only: frame `index`'s motion (computed ahead, else now), then its depth kept for the next."""
        ahead, self._prefetched = self._prefetched, None
        if ahead is not None and ahead[0] != index:
            ahead[1].result()
            raise RuntimeError(f"the motion of frame {ahead[0]} was computed ahead, frame {index} came instead")
        step = ahead[1].result() if ahead is not None else self.mono.motion(image)
        self.mono.remember(depth, log_sigma)
        self._scale = self.mono.depth_scale  # nothing runs ahead yet: the next motion starts after this frame's
        return step

    def _feature_points(self, feats: Features, depth: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, list]:
        uv = feats.uv
        ui = np.clip(np.rint(uv[:, 0]).astype(int), 0, self.shape[1] - 1)
        vi = np.clip(np.rint(uv[:, 1]).astype(int), 0, self.shape[0] - 1)
        z = depth[vi, ui].astype(np.float64)
        lidar_z = np.full(len(uv), np.nan)
        if self.use_lidar and sparse is not None:
            lv, lu = np.nonzero(sparse > 0)
            lidar_z = associate(
                uv, np.stack([lu, lv], 1).astype(float), sparse[lv, lu], ASSOC_RADIUS_PX, ASSOC_MAX_REL_SPREAD
            )
        z = np.where(np.isfinite(lidar_z), lidar_z, z)
        pts = back_project(uv, z, self.K)
        lidar_cam = [pts[k] if np.isfinite(lidar_z[k]) else None for k in range(len(uv))]
        return pts, lidar_cam

    def process(
        self,
        index: int,
        image: np.ndarray,
        depth: np.ndarray,
        log_sigma: np.ndarray,
        sparse: np.ndarray | None,
        scan: np.ndarray | None,
        graph: WindowGraph,
        icp_guess: np.ndarray | None = None,
        images_step: np.ndarray | None = None,
    ) -> FrameInput:
        """Build the graph input of a new frame (`depth`: generator depth; `sparse`: the LiDAR input
        as a depth map; `scan`: its points in the LiDAR frame, for KISS-ICP; `icp_guess`: the camera's motion
        from the previous frame read from the images, KISS-ICP's prediction; `images_step`: the pair motion from the
        previous frame, which the initial pose must turn as, where there is one)."""
        cfg = self.cfg
        step = self._mono_step(index, image, depth, log_sigma) if self.mono is not None else None
        if self.depth_scale != 1.0:  # the generator's depth at the road's metric scale
            depth, log_sigma = depth * self.depth_scale, log_sigma + np.log(self.depth_scale)
        feats = detect(image, cfg.frontend.n_features)
        cam_pts, lidar_cam = self._feature_points(feats, depth, sparse)
        T_icp = self.icp.register(scan, guess=icp_guess) if self.icp is not None else None
        landmark = np.full(len(feats), -1, np.int64)
        observations: list[Observation] = []
        new_landmarks: dict[int, np.ndarray] = {}
        prior_rel: dict[int, float] = {}
        trusted = None
        odo_cov = None
        matches_prev = None
        if self.prev is None:
            T_init, source, T_rel = np.eye(4), "first", None
        else:
            p = self.prev
            T_prev = graph.pose(p.index)
            ia, ib = match(p.feats, feats)
            matches_prev = (p.index, p.feats.uv[ia].astype(np.float64), feats.uv[ib].astype(np.float64))
            obj = (p.cam_pts[ia] @ T_prev[:3, :3].T + T_prev[:3, 3]) if len(ia) else np.zeros((0, 3))
            img = feats.uv[ib].astype(np.float64)
            if step is not None:  # camera only: the epipolar motion, else PnP if the epipolar test agrees
                T_init, source, odo_cov = self._camera_only_pose(step, T_prev, obj, img, p.feats.uv[ia], feats.uv[ib])
            else:
                T_init, source = self._lidar_pose(T_prev, T_icp, obj, img, images_step)
            T_rel = invert_T(T_prev) @ T_init
            triangulated = np.zeros(len(ia), bool)
            if not len(ia):
                inl = np.zeros(0, bool)
            elif step is not None:  # camera only: the epipolar test picks the matches
                inl = sampson_px(T_rel, p.feats.uv[ia], feats.uv[ib], self.K) < cfg.frontend.pnp_reproj_px
                # a vehicle driving along with the camera passes the epipolar test (it moves along its
                # epipolar lines) but shows far less parallax than its depth predicts
                inl &= parallax_agrees(T_rel, p.cam_pts[ia], p.feats.uv[ia], feats.uv[ib], self.K)
                # where the road gave the step, its metric motion places landmarks from a smaller ray angle
                road = step.scale_source.startswith("ground")
                obj, triangulated = self._triangulated(
                    obj,
                    T_prev,
                    T_rel,
                    p.feats.uv[ia],
                    feats.uv[ib],
                    MONO_GROUND_TRIANGULATION_MIN_DEG if road else 1.0,
                )
            else:
                inl = reprojection_inliers(T_init, obj, img, self.K, cfg.frontend.pnp_reproj_px)
            if inl.sum() >= 6:
                trusted = convex_hull_mask(img[inl], self.shape) & (depth > 0)
            road_placed = triangulated & (step is not None and step.scale_source.startswith("ground"))
            self._observe(
                index,
                feats,
                lidar_cam,
                landmark,
                ia[inl],
                ib[inl],
                obj[inl],
                road_placed[inl],
                graph,
                observations,
                new_landmarks,
                prior_rel,
            )
            self.velocity = T_rel
            self._step_lengths = (self._step_lengths + [float(np.linalg.norm(T_rel[:3, 3]))])[-STEP_LENGTH_FRAMES:]
            self.sweep_velocity = self._sweep_step(T_icp, T_rel)
        self.sources.append(source)
        lidar_uvz = None
        if sparse is not None and self.use_lidar:
            lv, lu = np.nonzero(sparse > 0)
            lidar_uvz = np.stack([lu, lv, sparse[lv, lu]], 1).astype(float)
        rel_sigma = np.exp(log_sigma) / np.maximum(depth, 1e-3)
        self.prev = _Prev(index, feats, cam_pts, lidar_cam, landmark, T_icp)
        # KISS-ICP's motion, the graph's metric scale that holds over a drive, with its registration covariance (a
        # cone's is loose sideways and in yaw, where the images' motion holds it)
        icp_pose = None
        if T_icp is not None and self.icp.covariance is not None:
            icp_pose = (T_icp, self.icp.covariance)
        return FrameInput(
            index,
            T_init,
            np.log(np.maximum(depth, 1e-3)),
            rel_sigma,
            observations,
            new_landmarks,
            trusted,
            lidar_uvz,
            T_rel,
            odo_cov,
            icp_pose,
            prior_rel,
            matches_prev=matches_prev,
        )

    def _sweep_step(self, T_icp: np.ndarray | None, T_rel: np.ndarray) -> np.ndarray:
        """The camera motion the next sweep is deskewed with (`sweep_velocity`)."""
        if T_icp is None or self.prev.T_icp is None or not self.icp.spinning:
            return T_rel
        step = invert_T(self.prev.T_icp) @ T_icp
        length = float(np.linalg.norm(step[:3, 3]))
        self._icp_lengths = (self._icp_lengths + [length])[-SWEEP_STEP_FRAMES:]
        if length > 1e-9:
            step[:3, 3] *= float(np.mean(self._icp_lengths)) / length
        return step

    def _lidar_pose(
        self,
        T_prev: np.ndarray,
        T_icp: np.ndarray | None,
        obj: np.ndarray,
        img: np.ndarray,
        images_step: np.ndarray | None = None,
    ) -> tuple[np.ndarray, str]:
        """Initial pose with LiDAR and its source: KISS-ICP's step or PnP on the previous frame's points, whichever
        reprojects more matches among those that turn as the images do (`images_step`, the pair motion from the
        previous frame); the last step again when neither holds (PnP on under 6 inliers, no ICP)."""
        p, px = self.prev, self.cfg.frontend.pnp_reproj_px
        cands: dict[str, np.ndarray | None] = {}
        if T_icp is not None and p.T_icp is not None:
            cands["icp"] = T_prev @ invert_T(p.T_icp) @ T_icp
        cands["pnp"] = pnp_pose(obj, img, self.K, px)[0]
        cands = self._plausible(cands, T_prev)
        turning = turning_as_the_images(cands, T_prev, images_step)
        guess = choose_pose(turning, obj, img, self.K, px)
        if turning is not cands and (guess is None or guess.inliers < 6 and "icp" not in turning):
            turning, guess = cands, choose_pose(cands, obj, img, self.K, px)  # what turns as the images does not hold
        if guess is None or guess.inliers < 6 and "icp" not in turning:
            return T_prev @ self.velocity, "constant_velocity"
        return guess.T_world_cam, guess.source

    def _plausible(self, cands: dict[str, np.ndarray | None], T_prev: np.ndarray) -> dict[str, np.ndarray | None]:
        """The candidates whose step length is near the last steps' (all of them when none is, or before
        STEP_LENGTH_FRAMES steps)."""
        if len(self._step_lengths) < STEP_LENGTH_FRAMES:
            return cands
        ref = float(np.median(self._step_lengths))
        tol = max(STEP_LENGTH_CHANGE_REL * ref, STEP_LENGTH_CHANGE_M)
        kept = {
            name: T
            for name, T in cands.items()
            if T is not None and abs(float(np.linalg.norm((invert_T(T_prev) @ T)[:3, 3])) - ref) <= tol
        }
        return kept or cands

    def _observe(
        self,
        index: int,
        feats: Features,
        lidar_cam: np.ndarray,
        landmark: np.ndarray,
        ia: np.ndarray,
        ib: np.ndarray,
        obj: np.ndarray,
        road_placed: np.ndarray,
        graph: WindowGraph,
        observations: list[Observation],
        new_landmarks: dict[int, np.ndarray],
        prior_rel: dict[int, float],
    ) -> None:
        """The inlier matches (previous frame's feature ia[m], this frame's ib[m]) as observations: of the
        previous frame's landmark where the graph still holds it, else of a new one at `obj[m]` (world), observed
        from both frames; `road_placed`: placed by the road's metric motion, not the generator's depth, so given
        its own depth prior."""
        p = self.prev
        scale_prev, scale_cur = p.feats.pixel_scale(ia), feats.pixel_scale(ib)
        for m in range(len(ia)):
            a, b = ia[m], ib[m]
            k = int(p.landmark[a])
            if k < 0 or not graph.has_landmark(k):
                k = self.next_landmark
                self.next_landmark += 1
                new_landmarks[k] = obj[m]
                if road_placed[m]:
                    prior_rel[k] = MONO_TRIANGULATED_PRIOR_REL
                elif self.use_lidar and p.lidar_cam[a] is None:
                    prior_rel[k] = GENERATOR_LANDMARK_PRIOR_REL
                observations.append(
                    Observation(k, p.index, p.feats.uv[a].astype(float), p.lidar_cam[a], float(scale_prev[m]))
                )
            landmark[b] = k
            observations.append(Observation(k, index, feats.uv[b].astype(float), lidar_cam[b], float(scale_cur[m])))

    def _camera_only_pose(
        self, step: MonoStep, T_prev: np.ndarray, obj: np.ndarray, img: np.ndarray, uv0: np.ndarray, uv1: np.ndarray
    ) -> tuple[np.ndarray, str, np.ndarray | None]:
        """Initial pose without LiDAR, its source and its between-factor covariance: the epipolar motion with
        its filtered step length; where that failed, PnP on the landmarks if its motion passes the
        epipolar test of the matches; else constant velocity."""
        cfg = self.cfg
        if step.scale_source != "constant_speed":
            length = float(np.linalg.norm(step.T_rel[:3, 3]))
            ground = step.scale_source.startswith("ground")
            rel = MONO_GROUND_ODOMETRY_SIGMA_REL if ground else MONO_ODOMETRY_SIGMA_REL
            sigmas = np.r_[np.full(3, MONO_ODOMETRY_SIGMA_RAD), np.full(3, max(rel * length, 0.01))]
            return T_prev @ step.T_rel, f"epipolar ({step.scale_source})", np.diag(sigmas**2)
        T_pnp = pnp_pose(obj, img, self.K, cfg.frontend.pnp_reproj_px)[0]
        if T_pnp is not None and epipolar_agrees(invert_T(T_prev) @ T_pnp, uv0, uv1, self.K):
            return T_pnp, "pnp", None
        return T_prev @ self.velocity, "constant_velocity", None

    def _triangulated(
        self,
        obj: np.ndarray,
        T_prev: np.ndarray,
        T_rel: np.ndarray,
        uv0: np.ndarray,
        uv1: np.ndarray,
        min_angle_deg: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """World points of matches triangulated from the two poses where the rays part by at least
        `min_angle_deg`, the depth-seeded point `obj` elsewhere; and which were triangulated."""
        if np.linalg.norm(T_rel[:3, 3]) < 1e-6:
            return obj, np.zeros(len(obj), bool)
        X0 = triangulate(T_rel, uv0.astype(float), uv1.astype(float), self.K)  # previous camera
        ray0 = X0 / np.maximum(np.linalg.norm(X0, axis=1, keepdims=True), 1e-9)
        d1 = X0 - T_rel[:3, 3]
        ray1 = d1 / np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-9)
        angle = np.degrees(np.arccos(np.clip(np.sum(ray0 * ray1, axis=1), -1, 1)))
        ok = (X0[:, 2] > 0.5) & ((X0 - T_rel[:3, 3]) @ T_rel[:3, 2] > 0.5) & (angle >= min_angle_deg)
        world = X0 @ T_prev[:3, :3].T + T_prev[:3, 3]
        return np.where(ok[:, None], world, obj), ok


def convex_hull_mask(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixels inside the convex hull of the points (the trusted region); empty with fewer than 3."""
    mask = np.zeros(shape, np.uint8)
    if len(uv) >= 3:
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
    return mask.astype(bool)
