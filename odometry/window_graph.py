"""The sliding-window factor graph (LeoVR Sec. III-C, Fig. 6): per frame a Pose3 and a depth
correction field, ORB landmarks as Point3, tied by reprojection, LiDAR point, depth-consistency and
depth-prior factors; a gtsam fixed-lag smoother marginalises frames that leave the window.

Frames enter one at a time (`add_frame`); each call returns the frames that just left the window with
their final pose and field. A spinning LiDAR's window is smoothed incrementally (IncrementalFixedLagSmoother:
iSAM2, every variable that moved relinearised at each update): the poses and depth of batch smoothing in less
time (docs/decisions/0011-tuned-settings.md). Every other
window is batch (BatchFixedLagSmoother, Levenberg-Marquardt): a cone LiDAR's consistency factors draw a fresh
pixel sample before every update, which a cached linearisation would not see, and its pair factors start far
from their solution (one Gauss-Newton step per frame does not get there); iSAM2 cannot marginalise a
camera-only window (its leaving pose is no leaf of the Bayes tree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from leovr.config import RefineConfig
from leovr.geometry import invert_T
from odometry.depth_field import CorrectionGrid
from odometry.factors import (
    DepthConsistency,
    FrameDepth,
    LidarDepth,
    consistency_factor,
    lidar_point_factor,
    projection_factor,
)
from odometry.leaving_observations import conditioned_observations
from odometry.motion_gates import icp_agrees, pair_agrees
from odometry.step_covariance import window_step_covariances
from odometry.window_recovery import anchor_landmarks

# The solver and the correction field, fixed (docs/decisions/0011-tuned-settings.md, 0002-no-lm-retries.md):
LM_ITERATIONS = 3  # Levenberg-Marquardt iterations per update
# LM retries a step that raises the error at 10x damping only below this cap; 1e-10: no retry, the update ends
LM_LAMBDA_UPPER_BOUND = 1e-10
GRID_ROWS, GRID_COLS = 8, 14  # depth correction field: log-depth offsets per frame
CONSISTENCY_SAMPLES = 300  # pixels per depth-consistency factor, resampled each update
LIDAR_DEPTH_SAMPLES = 400  # own LiDAR returns on the correction field
PRIOR_SIGMA_MIN, PRIOR_SIGMA_MAX = 0.02, 0.5  # the generator prior on the field: sigma / depth per cell, clipped
PAIR_OFFSETS = (1, 2, 3)  # pair factors to the frames this many before (frames)


def X(i: int) -> int:
    return gtsam.symbol("x", i)


def C(i: int) -> int:
    return gtsam.symbol("c", i)


def L(k: int) -> int:
    return gtsam.symbol("l", k)


@dataclass
class Observation:
    """A landmark seen in a frame: pixel, the associated LiDAR point in the camera frame if any, and how
    coarsely the pixel is known (its reprojection sigma over `graph.pixel_sigma`)."""

    landmark: int
    frame: int
    uv: np.ndarray
    lidar_cam: np.ndarray | None = None
    pixel_scale: float = 1.0


@dataclass
class FrameInput:
    """What the front end hands the graph for one new frame."""

    index: int
    T_init: np.ndarray  # camera to world
    log_depth: np.ndarray  # generator depth, log metres
    rel_sigma: np.ndarray  # generator sigma / depth per pixel
    observations: list[Observation]
    new_landmarks: dict[int, np.ndarray]  # landmark id -> initial world position
    trusted: np.ndarray | None  # H x W bool: where depth consistency may be sampled
    lidar_uvz: np.ndarray | None  # M x 3: the frame's own LiDAR returns (u, v, depth)
    T_prev_rel: np.ndarray | None = None  # front-end motion from the previous frame
    # its 6 x 6 covariance (rotation rad, translation m); None: the config's weak sigmas
    odometry_cov: np.ndarray | None = None
    icp_pose: tuple[np.ndarray, np.ndarray] | None = None  # KISS-ICP's pose (camera to world) and its 6 x 6 covariance
    # landmark id -> its prior's sigma per metre of depth where it differs from `landmark_prior_rel`
    landmark_prior_rel: dict[int, float] = field(default_factory=dict)
    # earlier frame j -> T_j_i (4 x 4): this frame's motion to j read from the images (essential matrix, LiDAR
    # length; odometry.frame_tracks.pair_motions), a between factor where j is still in the window
    pair_motions: dict[int, np.ndarray] = field(default_factory=dict)
    # the front end's feature matches with the previous frame: (its index, its pixels, this frame's pixels); a
    # second opinion on the rotation where a pair motion and the initial pose disagree (`_pair_factors`)
    matches_prev: tuple[int, np.ndarray, np.ndarray] | None = None


@dataclass
class FrameResult:
    index: int
    T_world_cam: np.ndarray
    log_offset: np.ndarray  # H x W log-depth correction
    # 6 x 6 covariance of the step from the frame before (odometry.step_covariance), as the window last had it
    step_cov: np.ndarray | None = None


@dataclass
class _Pair:
    i: int
    j: int
    dc: DepthConsistency
    trusted_uv: tuple[np.ndarray, np.ndarray]


def lm_params(lambda_upper_bound: float = LM_LAMBDA_UPPER_BOUND) -> gtsam.LevenbergMarquardtParams:
    """The smoother's Levenberg-Marquardt settings: LM_ITERATIONS iterations, and a step that does not lower the
    error is retried with more damping only while lambda stays under `lambda_upper_bound`. gtsam's batch smoother
    never lets lambda fall below 1e-10, so the cap of 1e-10 ends the update at the first step that fails (the
    window is converged) instead of solving it again at damping that barely changes the step."""
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(LM_ITERATIONS)
    lm.setlambdaUpperBound(lambda_upper_bound)
    return lm


@dataclass
class WindowGraph:
    cfg: RefineConfig
    K: np.ndarray
    shape: tuple[int, int]
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    # a leaving frame's observations of landmarks that stay: conditioned on its pose (with LiDAR), else marginalised
    # (camera only: conditioning carried the leaving pose's pitch error on to the landmarks that stay)
    condition_leaving: bool = True
    # each leaving frame's step covariance (odometry.step_covariance), for loop closure's pose graph
    step_covariances: bool = False

    def __post_init__(self) -> None:
        self.grid = CorrectionGrid(GRID_ROWS, GRID_COLS, *self.shape)
        self.cal = gtsam.Cal3_S2(self.K[0, 0], self.K[1, 1], 0.0, self.K[0, 2], self.K[1, 2])
        self.depths: dict[int, FrameDepth] = {}
        self.poses: dict[int, np.ndarray] = {}
        self.fields: dict[int, np.ndarray] = {}
        self.landmarks: dict[int, np.ndarray] = {}
        self.retired_landmarks: dict[int, np.ndarray] = {}  # last estimate of landmarks marginalised out
        self.landmark_frame: dict[int, int] = {}  # the latest frame that observed each landmark
        self.landmark_lidar: set[int] = set()  # landmarks with at least one LiDAR point factor
        self.frame_landmarks: dict[int, set[int]] = {}  # frame -> landmarks it observed
        self.pairs: list[_Pair] = []
        self.icp_poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # frame -> covariance of the step into it (odometry.step_covariance), kept for loop closure
        self.step_cov: dict[int, np.ndarray] = {}
        self.icp_rejected = 0  # KISS-ICP motions left out by the images' (`_icp_factors`)
        self.last: int | None = None
        # the correction field's depth factors; `auto` is on until the caller knows the sensor (refine: a
        # spinning LiDAR turns them off)
        self.depth_factors: bool = self.cfg.graph.depth_factors is not False
        self.incremental = False  # iSAM2 instead of batch (`set_sensor`)
        self.smoother = self._new_smoother()

    def _new_smoother(self) -> gtsam.FixedLagSmoother:
        """iSAM2 for a spinning LiDAR's window (`set_sensor`), else batch Levenberg-Marquardt (module docstring)."""
        lag = self.cfg.window - 0.5
        if not self.incremental:
            return gtsam.BatchFixedLagSmoother(lag, lm_params())
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.0)
        params.relinearizeSkip = 1
        return gtsam.IncrementalFixedLagSmoother(lag, params)

    def set_sensor(self, spinning: bool) -> None:
        """What the caller learnt of the LiDAR from its first scan: a spinning one turns `auto` depth factors
        off, and before the first frame its window (no resampled factor, no pair factor, first guesses from
        KISS-ICP and PnP) is smoothed incrementally."""
        g = self.cfg.graph
        if g.depth_factors == "auto":
            self.depth_factors = not spinning
        if self.last is None:
            self.incremental = (
                spinning and not self.depth_factors and g.pair_factors is not True and self.condition_leaving
            )
            self.smoother = self._new_smoother()

    # ----------------------------------------------------------------- factors of one new frame
    def _frame_factors(self, f: FrameInput, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        g = self.cfg.graph
        values.insert(X(f.index), gtsam.Pose3(f.T_init))
        if self.last is None:
            graph.add(
                gtsam.PriorFactorPose3(X(f.index), gtsam.Pose3(f.T_init), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4))
            )
        else:
            rel = f.T_prev_rel if f.T_prev_rel is not None else invert_T(self.poses[self.last]) @ f.T_init
            if f.odometry_cov is not None:
                noise = gtsam.noiseModel.Gaussian.Covariance(f.odometry_cov)
            else:
                noise = gtsam.noiseModel.Diagonal.Sigmas(
                    np.r_[np.full(3, g.odometry_sigma_rad), np.full(3, g.odometry_sigma_m)]
                )
            graph.add(gtsam.BetweenFactorPose3(X(self.last), X(f.index), gtsam.Pose3(rel), noise))
        if f.icp_pose is not None:
            self._icp_factors(f, *f.icp_pose, graph)
        self._pair_factors(f, graph)
        fd = FrameDepth(f.log_depth, self.grid)
        self.depths[f.index] = fd
        values.insert(C(f.index), np.zeros(self.grid.size))
        sig = self.grid.cell_means(f.rel_sigma)
        sig = np.clip(np.nan_to_num(sig, nan=PRIOR_SIGMA_MAX), PRIOR_SIGMA_MIN, PRIOR_SIGMA_MAX)
        graph.add(gtsam.PriorFactorVector(C(f.index), np.zeros(self.grid.size), gtsam.noiseModel.Diagonal.Sigmas(sig)))
        if self.depth_factors and f.lidar_uvz is not None and len(f.lidar_uvz):
            uvz = f.lidar_uvz
            if len(uvz) > LIDAR_DEPTH_SAMPLES:
                uvz = uvz[self.rng.choice(len(uvz), LIDAR_DEPTH_SAMPLES, replace=False)]
            graph.add(LidarDepth(fd, uvz[:, 0], uvz[:, 1], uvz[:, 2], g.lidar_depth_sigma_log).factor(C(f.index)))
        for k, P in f.new_landmarks.items():
            values.insert(L(k), np.asarray(P, float))
            self.landmarks[k] = np.asarray(P, float)
            # the depth it was initialised from (generator or LiDAR) keeps a landmark determined when the baseline is
            # short
            depth = max(1.0, float(np.linalg.norm(P - self.poses.get(self.last, f.T_init)[:3, 3])))
            rel = f.landmark_prior_rel.get(k, g.landmark_prior_rel)
            graph.add(
                gtsam.PriorFactorPoint3(L(k), np.asarray(P, float), gtsam.noiseModel.Isotropic.Sigma(3, rel * depth))
            )
        for o in f.observations:
            graph.add(projection_factor(o.uv, X(o.frame), L(o.landmark), self.cal, g.pixel_sigma * o.pixel_scale))
            if o.lidar_cam is not None:
                graph.add(
                    lidar_point_factor(o.lidar_cam, X(o.frame), L(o.landmark), g.bearing_sigma_rad, g.range_sigma_m)
                )
        if self.depth_factors and f.trusted is not None and self.last is not None and f.trusted.any():
            v, u = np.nonzero(f.trusted)
            dc = DepthConsistency(fd, self.depths[self.last], self.K, g.consistency_sigma_log)
            pair = _Pair(f.index, self.last, dc, (u.astype(float), v.astype(float)))
            self._resample(pair)
            self.pairs.append(pair)
            graph.add(consistency_factor(dc, [X(f.index), X(self.last), C(f.index), C(self.last)]))

    def _pair_factors(self, f: FrameInput, graph: gtsam.NonlinearFactorGraph) -> None:
        """The images' motions from this frame to earlier frames of the window: rotation to
        `pair_sigma_rad`, translation to `pair_sigma_rel` of its length, Huber-robust (a pair's essential
        matrix is sometimes far off). A pair whose rotation disagrees with the front end's initial pose is kept
        only if the essential matrix of the front end's own matches with the previous frame agrees with it
        instead (`pair_agrees`): in a fast turn either the pair's tracks or the initial pose can be the one that
        failed (Huber still lets a 100-sigma outlier pull the pose)."""
        g = self.cfg.graph
        second: list[np.ndarray | None] = []  # the matches' rotation, computed once and only when needed
        for j, T in f.pair_motions.items():
            if j not in self.poses:
                continue
            if not pair_agrees(T, j, f.T_init, f.matches_prev, self.poses, self.K, second):
                continue
            length = float(np.linalg.norm(T[:3, 3]))
            base = gtsam.noiseModel.Diagonal.Sigmas(
                np.r_[np.full(3, g.pair_sigma_rad), np.full(3, g.pair_sigma_rel * length + 0.01)]
            )
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), base)
            graph.add(gtsam.BetweenFactorPose3(X(j), X(f.index), gtsam.Pose3(T), noise))

    def _icp_factors(self, f: FrameInput, T: np.ndarray, cov: np.ndarray, graph: gtsam.NonlinearFactorGraph) -> None:
        """KISS-ICP as the pose prior: its motion from every frame still in the window to this one
        (KISS-ICP registers against a local map, so its motion over several frames is as precise as over
        one: chaining only consecutive motions would lose that and drift); covariances from the
        registration (`LidarOdometry.covariance`). A motion that disagrees with the images' (the pair motion to
        that frame, else the front end's motion chained through the window; `icp_agrees`) is left out: a
        registration that slipped or slid (a cone LiDAR in a fast turn) is still sure of itself."""
        i = f.index
        self.icp_poses = {j: v for j, v in self.icp_poses.items() if j in self.poses}
        for j, (Tj, cov_j) in self.icp_poses.items():
            motion = invert_T(Tj) @ T
            if not icp_agrees(motion, j, f.pair_motions.get(j), f.T_init, f.T_prev_rel, self.poses, self.last):
                self.icp_rejected += 1
                continue
            graph.add(
                gtsam.BetweenFactorPose3(
                    X(j), X(i), gtsam.Pose3(motion), gtsam.noiseModel.Gaussian.Covariance(cov + cov_j)
                )
            )
        self.icp_poses[i] = (T, cov)

    def _resample(self, pair: _Pair) -> None:
        u, v = pair.trusted_uv
        n = CONSISTENCY_SAMPLES
        pick = self.rng.choice(len(u), n, replace=len(u) < n)
        pair.dc.set_samples(u[pick], v[pick])

    # ----------------------------------------------------------------------------- public API
    def add_frame(self, f: FrameInput) -> list[FrameResult]:
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for p in self.pairs:  # a fresh pixel sample for every consistency factor still in the window
            self._resample(p)
        self._frame_factors(f, graph, values)
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        stamps.insert((X(f.index), float(f.index)))
        stamps.insert((C(f.index), float(f.index)))
        for k in {o.landmark for o in f.observations}:
            stamps.insert((L(k), float(f.index)))
            self.landmark_frame[k] = f.index
        self.landmark_lidar.update(o.landmark for o in f.observations if o.lidar_cam is not None)
        for o in f.observations:
            self.frame_landmarks.setdefault(o.frame, set()).add(o.landmark)
        drop = self._condition_leaving(f.index, graph)
        try:
            self.smoother.update(graph, values, stamps, drop)
        except (RuntimeError, IndexError) as exc:
            if not self.incremental and "ndetermin" not in str(exc):
                raise
            centre = self.poses.get(self.last, np.eye(4))[:3, 3] if self.last is not None else np.zeros(3)
            self.smoother = anchor_landmarks(self.smoother, self._new_smoother, self.incremental, centre, f.index, exc)
        self.last = f.index
        est = self.smoother.calculateEstimate()
        done = self._collect(est)
        if self.step_covariances:
            keys = {i: X(i) for i in self.poses}
            self.step_cov |= window_step_covariances(self.smoother.getFactors(), est, keys, self.poses)
        return done

    def _condition_leaving(self, newest: int, graph: gtsam.NonlinearFactorGraph) -> list[int]:
        """Observations, by the frames about to leave the window, of landmarks that stay in it: returns their
        indices in the smoother's graph (to remove) and adds to `graph` each one conditioned on the leaving
        pose (`conditioned_observations`). `condition_leaving=False` marginalises."""
        if not self.condition_leaving:
            return []
        cutoff = newest - (self.cfg.window - 0.5)  # the smoother marginalises keys stamped before this
        leaving = [i for i in self.poses if i < cutoff]
        staying = {
            L(k)
            for i in leaving
            for k in self.frame_landmarks.get(i, ())
            if self.landmark_frame.get(k, -1) >= cutoff and k in self.landmarks
        }
        if not staying:
            return []
        poses = {X(i): self.poses[i] for i in leaving}
        return conditioned_observations(self.smoother.getFactors(), poses, staying, self.landmarks, graph)

    def _collect(self, est: gtsam.Values) -> list[FrameResult]:
        live = {i for i in self.poses} | {self.last}
        done = []
        for i in sorted(live):
            if est.exists(X(i)):
                self.poses[i] = est.atPose3(X(i)).matrix()
                self.fields[i] = est.atVector(C(i))
            else:
                done.append(self._finish(i))
        for k in list(self.landmarks):
            if est.exists(L(k)):
                self.landmarks[k] = est.atPoint3(L(k))
            else:
                self.retired_landmarks[k] = self.landmarks.pop(k)
        self.pairs = [p for p in self.pairs if est.exists(X(p.i)) and est.exists(X(p.j))]
        return done

    def _finish(self, i: int) -> FrameResult:
        T, c = self.poses.pop(i), self.fields.pop(i)
        self.depths.pop(i, None)
        self.frame_landmarks.pop(i, None)
        return FrameResult(i, T, self.grid.upsample(c), self.step_cov.pop(i, None))

    def current(self, i: int) -> FrameResult:
        """Frame i's estimate now, the frame staying in the window (a causal run's output for its newest frame)."""
        return FrameResult(i, self.poses[i].copy(), self.grid.upsample(self.fields[i]))

    def flush(self) -> list[FrameResult]:
        """Every frame still in the window, with its current estimate (end of sequence)."""
        return [self._finish(i) for i in sorted(self.poses)]

    def all_landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (N x 3) of every landmark so far (final estimates, then live ones) and the
        latest frame that observed each (N), so a later pose correction can move them with that frame."""
        items = list(self.retired_landmarks.items()) + list(self.landmarks.items())
        pts = np.array([p for _, p in items], float).reshape(-1, 3)
        return pts, np.array([self.landmark_frame.get(k, -1) for k, _ in items], np.int64)

    def lidar_backed(self) -> np.ndarray:
        """Per landmark, in the order of `all_landmarks`: whether a LiDAR return fixed its range."""
        keys = list(self.retired_landmarks) + list(self.landmarks)
        return np.array([k in self.landmark_lidar for k in keys], bool)

    def pose(self, i: int) -> np.ndarray:
        return self.poses[i]

    def has_landmark(self, k: int) -> bool:
        return k in self.landmarks
