"""`leovr refine`'s settings: one model per stage (front end, window graph, accumulation, motion stereo,
photometric step, loop closure) and the camera-only profile, nested in RefineConfig."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from leovr.config_base import FrameSelection, _Model
from leovr.lidar.cheap_sensor import parse_input


class FrontEndConfig(_Model):
    """The visual-LiDAR front end: ORB features per frame and the initial pose."""

    n_features: int = Field(1000, ge=50)  # ORB features per frame
    pnp_reproj_px: float = 2.0  # PnP / epipolar inlier threshold of the front end (px)


class GraphConfig(_Model):
    """The sliding-window factor graph (LeoVR Sec. III-C): its factors' weights (the solver's settings and the
    correction field's size are constants of odometry.window_graph)."""

    # the correction field's depth-consistency and LiDAR-depth factors (false: point factors only); auto: off with a
    # spinning LiDAR, judged on the first scan of 100+ returns (docs/decisions/0003-depth-factors-auto.md)
    depth_factors: bool | Literal["auto"] = "auto"
    # reprojection factor (eq. 8) sigma (px), Huber; x 1.2^n for a keypoint of ORB pyramid level n
    pixel_sigma: float = 1.0
    bearing_sigma_rad: float = 0.003  # LiDAR point factor (eq. 10): bearing sigma (rad)
    range_sigma_m: float = 0.1  # LiDAR point factor: range sigma (m)
    landmark_prior_rel: float = 0.3  # landmark prior from the depth it was initialised with, sigma / depth
    odometry_sigma_rad: float = 0.05  # front-end motion between consecutive frames (weak): rotation sigma (rad)
    odometry_sigma_m: float = 0.3  # ... translation sigma (m)
    # KISS-ICP's point-to-point registration covariance x this (docs/decisions/0001-icp-covariance-inflation.md)
    icp_cov_inflation: float = Field(2.0, gt=0)
    consistency_sigma_log: float = 0.05  # depth-consistency sigma (log depth)
    lidar_depth_sigma_log: float = 0.03  # LiDAR-depth factor sigma (log depth)
    # the images' motion to the window's frames 1-3 before as robust between factors; auto: cone LiDAR only; needs a
    # LiDAR (docs/decisions/0006-pair-factors-cone-only.md)
    pair_factors: bool | Literal["auto"] = "auto"
    pair_sigma_rad: float = Field(0.0007, gt=0)  # pair factor rotation sigma (rad)
    pair_sigma_rel: float = Field(0.02, gt=0)  # pair factor translation sigma per metre of the pair's travel (+ 1 cm)


class AccumulationConfig(_Model):
    """A cone LiDAR's earlier scans, placed with the graph's poses, in the generator's input."""

    # cone LiDAR: earlier frames' inputs placed with the graph's poses fill the generator's input (frames; 0: off;
    # spinning LiDAR: off) (docs/decisions/0004-earlier-scans-cone-only.md)
    frames: int = Field(16, ge=0)
    # drop an earlier return once a later scan sees free space or a surface in front of it (RangeImage)
    check: bool = True


class MotionStereoConfig(_Model):
    """Motion stereo (odometry.motion_stereo): image corners triangulated over the frames before and after
    correct the generator's depth where a cone LiDAR does not reach; its other settings are constants of
    odometry.motion_stereo, odometry.frame_tracks and odometry.corner_correction, chosen on development data
    only."""

    # image corners outside the LiDAR's reach, triangulated over +-16 frames, correct the generator's depth;
    # auto: cone LiDAR only; needs a LiDAR (docs/decisions/0005-motion-stereo-cone-only.md)
    enabled: bool | Literal["auto"] = "auto"
    # frames before and after frame i that its corners are tracked into; a farther one only the corners that the
    # nearer one on the same side kept
    offsets: list[int] = [2, 4, 8, 12, 16]
    # a causal run's frames before frame i: the previous frame too (without it a causal Mid-40-like run lost its
    # way; docs/decisions/0011-tuned-settings.md)
    causal_offsets: list[int] = [1, 2, 4, 8, 12, 16]


class PhotometricConfig(_Model):
    """The photometric field (odometry.photo_field): a plane sweep against the neighbours' images corrects a
    leaving frame's depth where no return lies; its other settings are constants of odometry.photo_field, chosen on
    development data only."""

    # a leaving frame's depth where no return lies, by a plane sweep against its neighbours' images
    # (odometry.photo_field); auto: cone LiDAR only (docs/decisions/0007-photometric-field-cone-only.md)
    enabled: bool | Literal["auto"] = "auto"
    offsets: list[int] = [1, 2, 3]  # plane sweep against the frames this many before and after (frames)


class LoopConfig(_Model):
    """Loop closure after the window pass (LeoVR Sec. IV-B): bag-of-words candidates, geometric validation,
    a global pose graph."""

    enabled: bool = False  # after the window pass: bag-of-words loops, validation, global pose graph
    min_gap: int = Field(30, ge=2)  # loop candidates at least this many frames older
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

    # the camera's height above the road (m), which sets the metric scale; None: the recording's own
    # (KITTI: 1.65 m); 0: off (scale from the generator)
    camera_height_m: float | None = Field(None, ge=0)
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
    # motion-compensate scans with per-point times by the sweep's motion (odometry.sweep_motion: the images'
    # rotation along the last step's arc with a spinning LiDAR, the last step with a cone unless the images clearly
    # disagree; causal: the last step)
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
