"""`leovr refine`'s settings: one model per stage (front end, window graph, accumulation, motion stereo,
photometric step, loop closure) and the camera-only profile, nested in RefineConfig."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from leovr.config_base import FrameSelection, _Model
from leovr.lidar.cheap_sensor import parse_input


class FrontEndConfig(_Model):
    """The visual-LiDAR front end: ORB features per frame, their LiDAR depth and the initial pose."""

    n_features: int = Field(1000, ge=50)  # ORB features per frame
    assoc_radius_px: float = 5.0  # feature <-> projected LiDAR point association radius (px, eq. 10)
    assoc_max_rel_spread: float = 0.1  # reject when depths within the radius spread more than this (relative)
    pnp_reproj_px: float = 2.0  # PnP / epipolar inlier threshold of the front end (px)


class GraphConfig(_Model):
    """The sliding-window factor graph (LeoVR Sec. III-C): its factors, the depth correction field and the
    solver."""

    # the correction field's depth-consistency and LiDAR-depth factors (false: point factors only); auto: off with a
    # spinning LiDAR, judged on the first scan of 100+ returns (docs/decisions/0003-depth-factors-auto.md)
    depth_factors: bool | Literal["auto"] = "auto"
    grid_rows: int = Field(8, ge=2)  # depth correction field: rows of log-depth offsets per frame
    grid_cols: int = Field(14, ge=2)  # depth correction field: columns
    # Levenberg-Marquardt iterations per update (docs/decisions/0011-tuned-settings.md)
    lm_iterations: int = Field(3, ge=1)
    # LM retries a step that raises the error at 10x damping only below this cap; 1e-10: no retry, the update ends
    # (docs/decisions/0002-no-lm-retries.md)
    lm_lambda_upper_bound: float = Field(1e-10, gt=0)
    # reprojection factor (eq. 8) sigma (px), Huber; x 1.2^n for a keypoint of ORB pyramid level n
    pixel_sigma: float = 1.0
    bearing_sigma_rad: float = 0.003  # LiDAR point factor (eq. 10): bearing sigma (rad)
    range_sigma_m: float = 0.1  # LiDAR point factor: range sigma (m)
    landmark_prior_rel: float = 0.3  # landmark prior from the depth it was initialised with, sigma / depth
    odometry_sigma_rad: float = 0.05  # front-end motion between consecutive frames (weak): rotation sigma (rad)
    odometry_sigma_m: float = 0.3  # ... translation sigma (m)
    # KISS-ICP's point-to-point registration covariance x this (docs/decisions/0001-icp-covariance-inflation.md)
    icp_cov_inflation: float = Field(2.0, gt=0)
    consistency_samples: int = Field(300, ge=10)  # pixels per depth-consistency factor, resampled each update
    consistency_sigma_log: float = 0.05  # depth-consistency sigma (log depth)
    lidar_depth_samples: int = Field(400, ge=0)  # own LiDAR returns on the correction field (0 = off)
    lidar_depth_sigma_log: float = 0.03  # LiDAR-depth factor sigma (log depth)
    prior_sigma_min: float = 0.02  # generator prior on the field: sigma / depth per cell, clipped below ...
    prior_sigma_max: float = 0.5  # ... and above
    # the images' motion to the window's frames `pair_offsets` before as robust between factors; auto: cone LiDAR
    # only; needs a LiDAR (docs/decisions/0006-pair-factors-cone-only.md)
    pair_factors: bool | Literal["auto"] = "auto"
    pair_offsets: list[int] = [1, 2, 3]  # pair factors to the frames this many before (frames)
    pair_sigma_rad: float = Field(0.0007, gt=0)  # pair factor rotation sigma (rad)
    pair_sigma_rel: float = Field(0.02, gt=0)  # pair factor translation sigma per metre of the pair's travel (+ 1 cm)
    # a pair whose rotation is this far (deg) from both the initial pose's and the front end's essential matrix is
    # left out; 0: no test (docs/decisions/0006-pair-factors-cone-only.md)
    pair_gate_deg: float = Field(3.0, ge=0)


class AccumulationConfig(_Model):
    """A cone LiDAR's earlier scans, placed with the graph's poses, in the generator's input."""

    # cone LiDAR: earlier frames' inputs placed with the graph's poses fill the generator's input (frames; 0: off;
    # spinning LiDAR: off) (docs/decisions/0004-earlier-scans-cone-only.md)
    frames: int = Field(16, ge=0)
    # drop an earlier return once a later scan sees free space or a surface in front of it (RangeImage)
    check: bool = True


class MotionStereoConfig(_Model):
    """Motion stereo (odometry.motion_stereo): image corners triangulated over the frames before and after
    correct the generator's depth where a cone LiDAR does not reach; settings chosen on development data only."""

    # image corners outside the LiDAR's reach, triangulated over +-16 frames, correct the generator's depth;
    # auto: cone LiDAR only; needs a LiDAR (docs/decisions/0005-motion-stereo-cone-only.md)
    enabled: bool | Literal["auto"] = "auto"
    # frames before and after frame i that its corners are tracked into; a farther one only the corners that the
    # nearer one on the same side kept
    offsets: list[int] = [2, 4, 8, 12, 16]
    # a causal run's frames before frame i: the previous frame too (without it a causal Mid-40-like run lost its
    # way; docs/decisions/0011-tuned-settings.md)
    causal_offsets: list[int] = [1, 2, 4, 8, 12, 16]
    max_corners: int = 4000  # Shi-Tomasi corners per frame, at most ...
    corner_quality: float = 0.003  # ... their quality level (share of the strongest corner's) ...
    corner_distance_px: int = 4  # ... and distance apart (px), at least
    # pyramidal Lucas-Kanade: window (px), pyramid levels, iterations (docs/decisions/0011-tuned-settings.md)
    lk_window_px: int = 11
    lk_levels: int = 3  # ... pyramid levels
    lk_iterations: int = 20  # ... iterations
    track_check_px: float = 0.5  # forward-backward optical-flow agreement (px)
    min_views: int = 4  # views a corner needs, frame i included
    max_rms_px: float = 0.7  # multi-view reprojection error (px), at most
    min_parallax_px: float = 8.0  # the largest displacement against a point at infinity, over the views (px), at least
    lidar_gap_px: float = 8.0  # a corner joins the input only this far from any LiDAR return (px)
    # a tracked corner takes the LiDAR depth of a return this near, for a pair's length (px)
    scale_radius_px: float = 2.0
    scale_min_points: int = 10  # a pair with fewer LiDAR-backed corners (parallax > 2 px) is dropped
    min_depth_m: float = 1.5  # corners kept between this depth (m) ...
    max_depth_m: float = 150.0  # ... and this
    # a corner is kept when at least this many other kept corners lie within neighbour_radius x focal length
    # (pixels) and their median depth is within max_log_diff of its own (log): lone corners and outliers go
    min_neighbours: int = 2
    neighbour_radius: float = 0.05  # ... the neighbours' radius (x focal length)
    max_log_diff: float = 0.15  # ... their median depth's largest difference (log)
    # corrected_depth: the corners' log ratio to the generator spread with sigma = spread x focal length (px),
    # over pixels whose generator depth is within about range_log (log) of the corner's, fading where their
    # summed weight is small against `support` corners' worth
    spread: float = 0.06
    support: float = 1.0  # ... corners' worth of weight below which the correction fades
    range_log: float = 0.2  # ... generator depth this near the corner's (log)
    # a corner's ratio is taken against the generator depth within this many pixels (px) that matches it best
    edge_px: int = 2


class PhotometricConfig(_Model):
    """The photometric field (odometry.photo_field): a plane sweep against the neighbours' images corrects a
    leaving frame's depth where no return lies; settings chosen on development data only."""

    # a leaving frame's depth where no return lies, by a plane sweep against its neighbours' images
    # (odometry.photo_field); auto: cone LiDAR only (docs/decisions/0007-photometric-field-cone-only.md)
    enabled: bool | Literal["auto"] = "auto"
    offsets: list[int] = [1, 2, 3]  # plane sweep against the frames this many before and after (frames)
    # the correction's grid (nodes), corner to corner, finer than the graph's 8 x 14
    # (docs/decisions/0011-tuned-settings.md)
    rows: int = 16
    cols: int = 28  # ... its columns
    # candidates: log offsets in [-span, span], 0.2 apart (odd count: 0 is one); a parabola through the best and
    # its neighbours refines it (docs/decisions/0011-tuned-settings.md)
    span_log: float = 0.8
    candidates: int = 9  # ... candidates in the span
    patch_px: int = 2  # ZNCC window half size, at the downsampled scale
    min_texture: float = 4.0  # gray-level variance in the window: flatter patches do not vote
    min_pixels: int = 30  # a node needs this much (bilinear) weight of voting pixels for every candidate
    # a node moves only when its best candidate's mean ZNCC cost is this much below no change
    min_gain: float = Field(0.05, ge=0)
    min_depth_m: float = 0.5  # pixels nearer than this (m) do not vote
    min_backed: int = 5  # nodes with returns and a clear choice needed to check the poses
    # ... and this share of the seen nodes with returns: where the images pin the depth at few of the nodes whose
    # depth is known, the check rests on little and the sweep's choices elsewhere are no better
    # (docs/decisions/0011-tuned-settings.md)
    min_backed_share: float = 0.5
    # their median choice may be this far from 0 (a step length read wrong, a turn misread;
    # docs/decisions/0011-tuned-settings.md)
    max_bias_log: float = 0.1
    # the sweep runs on images made smaller by the integer factor that brings them nearest this many pixels
    # (448 x 256: 2, KITTI's 1242 x 375: 4; the patch size is at that scale); 0: this fixed factor
    sweep_pixels: int = 30000
    downsample: int = 0  # a fixed integer factor instead (0: from sweep_pixels)
    # a far candidate (depth x e^far_log, ~20x: as good as infinity) that a moved node's best must beat by
    # `far_gain`: a vehicle driving along with the camera matches best at infinity, and without this test its
    # nodes were pushed to the span's far end (docs/decisions/0011-tuned-settings.md); 0: off
    far_log: float = 3.0
    far_gain: float = 0.05  # ... by this much (ZNCC cost)


class LoopConfig(_Model):
    """Loop closure after the window pass (LeoVR Sec. IV-B): bag-of-words candidates, geometric validation,
    a global pose graph."""

    enabled: bool = False  # after the window pass: bag-of-words loops, validation, global pose graph
    min_gap: int = Field(30, ge=2)  # loop candidates at least this many frames older
    odometry_cauchy: float = Field(1.0, gt=0)  # loop pose graph: odometry factors under a Cauchy kernel (sigmas)
    vocabulary: str | None = None  # ORB vocabulary (.npz); None = the shipped one


class CameraOnlyGraphConfig(_Model):
    """`refine.graph` settings that a camera-only run uses in their place (camera_only_config): the
    generator's depth is far less sure without LiDAR (docs/decisions/0008-camera-only-loose-priors.md)."""

    # landmark prior from the generator's depth, far less sure without LiDAR, sigma / depth
    landmark_prior_rel: float = Field(10.0, gt=0)
    consistency_sigma_log: float = Field(0.3, gt=0)  # depth-consistency sigma (log depth)


class CameraOnlyConfig(_Model):
    """The camera-only profile, used without LiDAR (`--input none`, or a recording without one): the metric
    step length from the road or the generator, and looser graph priors."""

    depth_sigma_log: float = 0.2  # how far one frame's depth-based step length may be off (log)
    track_sigma_log: float = 0.05  # how far the tracks' relative scale may be off (log)
    speed_sigma_log: float = 0.005  # step-length change per frame (log; inertia; chosen on development clips)
    # the epipolar motion's rotation sigma in the graph (rad): its precision (thousands of sub-pixel tracks), not
    # the reprojection factors' on ORB matches, which pulled the heading off where it was looser
    odometry_sigma_rad: float = Field(0.0003, gt=0)
    odometry_sigma_rel: float = 0.05  # its translation sigma per metre of step
    # the camera's height above the road (m), which sets the metric scale; None: the recording's own
    # (KITTI: 1.65 m); 0: off (scale from the generator)
    camera_height_m: float | None = Field(None, ge=0)
    ground_sigma_log: float = Field(0.08, gt=0)  # one frame's road-based step length, log sigma at 20 road corners
    # the epipolar motion's translation sigma per metre of step where the road gave its length
    ground_odometry_sigma_rel: float = Field(0.001, gt=0)
    # road scale: landmarks triangulated from the metric motion where the rays part by this angle (deg),
    # else seeded from the generator's depth (docs/decisions/0008-camera-only-loose-priors.md)
    ground_triangulation_min_deg: float = Field(0.3, gt=0)
    triangulated_prior_rel: float = Field(1.0, gt=0)  # ... and their depth prior, sigma / depth
    # ORB features per frame in place of `frontend.n_features`: the graph marginalises a leaving frame's landmarks
    # into one dense factor, whose cost grows with them; half as many keep the ATE at less time
    # (docs/decisions/0011-tuned-settings.md)
    n_features: int = Field(500, ge=50)
    # `refine.graph` settings used in their place without LiDAR (camera_only_config)
    graph: CameraOnlyGraphConfig = CameraOnlyGraphConfig()


class RefineConfig(FrameSelection):
    """`leovr refine`: generator depth, visual-LiDAR front end and the sliding-window graph (LeoVR Sec. III).
    The settings of each stage are a table of their own below."""

    # the recording's own scan; vlp16 / mid40 / ratio:R simulate a cheaper sensor (evaluation); none: camera only
    input: str = "full"
    window: int = Field(4, ge=2)  # frames in the sliding window (LeoVR Fig. 15)
    # live use: each frame's depth and pose from it and earlier frames only; false: final when it leaves the window
    causal: bool = False
    depth_source: Literal["generator", "ipbasic"] = "generator"  # ipbasic: no network (self-supervised cold start)
    # motion-compensate scans with per-point times by the sweep's motion (odometry.sweep_motion: from the images
    # where they agree, else the last step; causal: the last step)
    deskew: bool = True
    # also run the textbook monocular VO (`mono_vo`) and KISS-ICP alone (`kiss_icp`, with LiDAR; always with
    # ground-truth poses)
    compare: bool = False
    frontend: FrontEndConfig = FrontEndConfig()  # ORB features, their LiDAR depth, the initial pose
    graph: GraphConfig = GraphConfig()  # the sliding-window graph: its factors, the depth correction field, the solver
    accumulation: AccumulationConfig = AccumulationConfig()  # a cone LiDAR's earlier scans in the generator's input
    # image corners triangulated over nearby frames correct the depth
    motion_stereo: MotionStereoConfig = MotionStereoConfig()
    photometric: PhotometricConfig = PhotometricConfig()  # plane sweep of a leaving frame's depth where no return lies
    loop: LoopConfig = LoopConfig()  # loop closure after the window pass
    camera_only: CameraOnlyConfig = CameraOnlyConfig()  # the camera-only profile (no LiDAR)

    @model_validator(mode="after")
    def _check_causal(self) -> "RefineConfig":
        if self.causal and self.loop.enabled:
            raise ValueError("loop.enabled corrects the whole recording afterwards; a causal run cannot have it")
        return self

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        if v.strip().lower() == "none":
            return "none"
        try:
            return str(parse_input(v))
        except ValueError:
            raise ValueError(f"unknown input '{v}' (choose full, vlp16, mid40, ratio:R or none)") from None
