"""Configuration models (pydantic) and YAML loading. Every CLI option can come from a config file;
options given on the command line override it."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from leovr.errors import ConfigError
from leovr.eval.depth_metrics import LEOVR_BINS
from leovr.lidar.cheap_sensor import parse_input

Scenario = Literal["city_loop", "straight", "dynamic", "traffic"]  # leovr.sim.world.SCENARIOS
GeneratorRuntime = Literal["torch", "onnxruntime", "onnxruntime_int8"]  # leovr.depth.runtime.for_inference


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class FrameSelection(_Model):
    """What depth jobs share: the generator, the cheap LiDAR input, the frames and how they are scored."""

    checkpoint: str | None = None  # generator weights (.pt); None = the shipped checkpoint
    generator_focal_px: float | None = 260.0  # generator run at this focal length (px, its training camera); None = native
    # onnxruntime_int8: the network in 8-bit integers from the checkpoint's calibration table (leovr.depth.quantize;
    # a checkpoint without one runs in floating point, with a warning); onnxruntime: floating point, torch's outputs
    generator_runtime: GeneratorRuntime = "onnxruntime_int8"
    # the classical prior at depth edges (generator and `interp`): the side the image puts a pixel on, or the nearest return
    prior_edges: Literal["image", "nearest"] = "image"
    input: str = "mid40"  # cheap LiDAR input simulated from the sequence's scan (full, vlp16, mid40, ratio:R)
    seed: int = 0  # seeds the simulated input (ratio:R draws)
    start: int = 0  # first frame (index into the sequence)
    end: int | None = None  # frame index to stop before; None = the last frame
    step: int = 1  # every n-th frame
    bins: list[float] = list(LEOVR_BINS)  # ground-truth distance bins (m) the depth error is also reported in
    parallax_window: int = 7  # held-out point dropped when a return in this window (px, side) is nearer ...
    parallax_rel: float = 0.15  # ... by more than this fraction (LiDAR-camera parallax filter)

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))

    @field_validator("step")
    @classmethod
    def _check_step(cls, v: int) -> int:
        if v < 1:
            raise ValueError("step must be at least 1")
        return v


class CompleteConfig(FrameSelection):
    """`leovr complete`: classical completion of a cheap LiDAR input, scored on held-out points."""

    method: Literal["nearest", "ipbasic", "interp", "generator"] = "ipbasic"  # completion method


class BenchBaselineConfig(_Model):
    """`leovr bench baseline`."""

    data: str | None = None  # KITTI raw clip; None = ../shared/data/kitti_raw
    inputs: list[str] = ["vlp16", "mid40"]  # cheap LiDAR inputs simulated from the clip's scans
    methods: list[Literal["nearest", "ipbasic", "interp"]] = ["nearest", "ipbasic", "interp"]  # methods scored
    quick_step: int = 6  # --quick scores every 6th frame
    seed: int = 0  # seeds the simulated inputs


class SimulateConfig(_Model):
    """`leovr simulate`: one rendered sequence of the procedural world."""

    scenario: Scenario = "city_loop"  # the procedural world's route and traffic
    lidar: Literal["vlp16", "hdl64", "mid40"] = "mid40"  # simulated LiDAR
    frames: int = Field(20, ge=1)  # frames rendered
    seed: int = 0  # seeds the world and the drive
    light: Literal["day", "dusk", "night"] = "day"  # lighting of the rendered images
    speed_kmh: float = Field(30.0, ge=0.0)  # driving speed (km/h)
    rate_hz: float = Field(10.0, gt=0.0)  # frame rate (Hz)
    width: int = Field(448, ge=16)  # image width (px)
    height: int = Field(256, ge=16)  # image height (px)
    focal: float = Field(260.0, gt=0.0)  # camera focal length (px)


class DemoConfig(_Model):
    """`leovr demo`: by default a generated Mid-40 sequence (the embedded default)."""

    data: str | None = None  # a recorded sequence instead of the generated one
    frames: int = Field(12, ge=1)  # frames generated and refined
    scenario: Scenario = "city_loop"  # generated sequence's scenario
    lidar: Literal["vlp16", "hdl64", "mid40"] = "mid40"  # generated sequence's LiDAR
    seed: int = 0  # seeds the generated sequence
    input: str | None = None  # None: all of the generated scan, or mid40 on a recorded dense scan


class BenchSimulateConfig(_Model):
    """`leovr bench simulate`."""

    frames: int = Field(10, ge=1)  # frames rendered per LiDAR
    lidars: list[Literal["vlp16", "hdl64", "mid40"]] = ["mid40", "vlp16", "hdl64"]  # LiDARs rendered


class BenchDepthConfig(_Model):
    """`leovr bench depth`: classical methods and the generator on simulator test sequences and the KITTI clip."""

    dataset: str | None = None  # simulator dataset with a test split; None = the cached `default` recipe
    kitti: str | None = None  # KITTI raw clip; None = ../shared/data/kitti_raw
    checkpoint: str | None = None  # None = the shipped generator
    generator_focal_px: float | None = 260.0  # run the generator at this focal length (px); None = native
    # depth methods scored
    methods: list[Literal["nearest", "ipbasic", "interp", "generator"]] = ["nearest", "ipbasic", "interp", "generator"]
    synthetic_lidars: list[Literal["mid40", "vlp16"]] = ["mid40", "vlp16"]  # rendered test sequences' LiDARs
    synthetic_step: int = Field(1, ge=1)  # every n-th test frame
    kitti_inputs: list[str] = ["vlp16", "mid40"]  # cheap inputs simulated from the KITTI scans
    quick_step: int = Field(6, ge=1)  # --quick: every 6th KITTI frame and a 4-frame rendered test set
    seed: int = 0  # seeds the simulated inputs


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
    lm_iterations: int = Field(3, ge=1)  # Levenberg-Marquardt iterations per update (3 measured as good as 6, half the time)
    # LM retries a step that raises the error at 10x damping only below this cap; 1e-10: no retry, the update ends
    # (docs/decisions/0002-no-lm-retries.md)
    lm_lambda_upper_bound: float = Field(1e-10, gt=0)
    pixel_sigma: float = 1.0  # reprojection factor (eq. 8) sigma (px), Huber
    bearing_sigma_rad: float = 0.003  # LiDAR point factor (eq. 10): bearing sigma (rad)
    range_sigma_m: float = 0.1  # LiDAR point factor: range sigma (m)
    landmark_prior_rel: float = 0.3  # landmark prior from the depth it was initialised with, sigma / depth
    odometry_sigma_rad: float = 0.05  # front-end motion between consecutive frames (weak): rotation sigma (rad)
    odometry_sigma_m: float = 0.3  # ... translation sigma (m)
    # KISS-ICP's point-to-point registration covariance x this (docs/decisions/0001-icp-covariance-inflation.md)
    icp_cov_inflation: float = Field(6.0, gt=0)
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
    offsets: list[int] = [2, 4, 8, 12, 16]  # frames before and after frame i that its corners are tracked into
    # a causal run's frames before frame i: the previous frame too (without it a causal Mid-40-like run on
    # kitti_raw_0013 lost its way, ATE 1.23 against 0.14 m; depth better on both real drives and a rendered one)
    causal_offsets: list[int] = [1, 2, 4, 8, 12, 16]
    max_corners: int = 4000  # Shi-Tomasi corners per frame, at most ...
    corner_quality: float = 0.003  # ... their quality level (share of the strongest corner's) ...
    corner_distance_px: int = 4  # ... and distance apart (px), at least
    # pyramidal Lucas-Kanade: window (px), pyramid levels, iterations (21 / 4 / 30: 2.5x the time, worse)
    lk_window_px: int = 11
    lk_levels: int = 3  # ... pyramid levels
    lk_iterations: int = 20  # ... iterations
    track_check_px: float = 0.5  # forward-backward optical-flow agreement (px)
    min_views: int = 4  # views a corner needs, frame i included
    max_rms_px: float = 0.7  # multi-view reprojection error (px), at most
    min_parallax_px: float = 8.0  # the largest displacement against a point at infinity, over the views (px), at least
    lidar_gap_px: float = 8.0  # a corner joins the input only this far from any LiDAR return (px)
    scale_radius_px: float = 2.0  # a tracked corner takes the LiDAR depth of a return this near, for a pair's length (px)
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
    rows: int = 16  # the correction's grid (nodes), corner to corner (finer than the graph's 8 x 14: 1.81 -> 1.77 m)
    cols: int = 28  # ... its columns
    # candidates: log offsets in [-span, span], 0.2 apart (odd count: 0 is one); a parabola through the best and
    # its neighbours refines it. 0.2 apart beat 0.1 on the development drives (span 0.5 / 11: 1.846 m, 0.8 / 9:
    # 1.813, 1.0 / 11: 1.813, 0.6 / 7: 1.829, 0.8 / 11: 1.824, 1.0 / 21: 1.837)
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
    # depth is known, the check rests on little and the sweep's choices elsewhere are no better (development data:
    # simulator drives 0.64-1.0 of them, 5-95 %, and the sweep helped on 91 % of the frames; KITTI frames 0-37
    # 0.01-0.35, and the sweep made 35 of 38 frames worse with the graph's poses, whatever the check's bias)
    min_backed_share: float = 0.5
    # their median choice may be this far from 0 (a step length read wrong, a turn misread). Simulator validation
    # drives: 5-95 % -0.07 to 0.04; the sweep helped in every bias bin, so with the share test above in front of
    # it: 0.05: 1.813 m, 0.1: 1.785, 0.15: 1.772, off: 1.770 (0.1 kept as the safer). KITTI frames 0-37 (graph's
    # poses): -0.51 to -0.05, refused by the share test already (without it, 0.05 alone lets 1-2 frames through,
    # each made worse)
    max_bias_log: float = 0.1
    # the sweep runs on images made smaller by the integer factor that brings them nearest this many pixels
    # (448 x 256: 2, KITTI's 1242 x 375: 4; the patch size is at that scale); 0: this fixed factor
    sweep_pixels: int = 30000
    downsample: int = 0  # a fixed integer factor instead (0: from sweep_pixels)
    # a far candidate (depth x e^far_log, ~20x: as good as infinity) that a moved node's best must beat by
    # `far_gain`: a vehicle driving along with the camera matches best at infinity, and without this test its
    # nodes were pushed to the span's far end (KITTI frames 0-37 with KISS-ICP's poses on the full scan, no
    # check: 1.70 -> 1.85 m without, 1.65 m with; simulator validation 1.823 -> 1.807 m); 0: off
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
    """`refine.graph` settings that a camera-only run uses in their place (camera_only_graph_config): the
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
    # road scale: every step's length solved again over the whole recording after the window pass
    # (odometry/step_length.py)
    length_smoothing: bool = True
    # ... the step length changing by this much a frame (m; 0.005 at 10 Hz is 0.5 m/s^2; chosen on development clips)
    length_change_sigma_m: float = Field(0.005, gt=0)
    odometry_sigma_rad: float = 0.005  # the epipolar motion's rotation sigma in the graph (rad)
    odometry_sigma_rel: float = 0.05  # its translation sigma per metre of step
    # the camera's height above the road (m), which sets the metric scale; None: the recording's own
    # (KITTI: 1.65 m); 0: off (scale from the generator)
    camera_height_m: float | None = Field(None, ge=0)
    ground_sigma_log: float = Field(0.08, gt=0)  # one frame's road-based step length, log sigma at 20 road corners
    # the epipolar motion's translation sigma per metre of step where the road gave its length
    ground_odometry_sigma_rel: float = Field(0.01, gt=0)
    # road scale: landmarks triangulated from the metric motion where the rays part by this angle (deg),
    # else seeded from the generator's depth (docs/decisions/0008-camera-only-loose-priors.md)
    ground_triangulation_min_deg: float = Field(0.3, gt=0)
    triangulated_prior_rel: float = Field(1.0, gt=0)  # ... and their depth prior, sigma / depth
    # road scale: the road's normal as a prior on each frame's pitch and roll (rad; 0: off); assumes a
    # flat road (the world normal is the mean of the first 10 seen)
    road_attitude_sigma_rad: float = Field(0.003, ge=0)
    # `refine.graph` settings used in their place without LiDAR (camera_only_graph_config)
    graph: CameraOnlyGraphConfig = CameraOnlyGraphConfig()


class RefineConfig(FrameSelection):
    """`leovr refine`: generator depth, visual-LiDAR front end and the sliding-window graph (LeoVR Sec. III).
    The settings of each stage are a table of their own below."""

    input: str = "full"  # the recording's own scan; vlp16 / mid40 / ratio:R simulate a cheaper sensor (evaluation); none: camera only
    window: int = Field(4, ge=2)  # frames in the sliding window (LeoVR Fig. 15)
    # live use: each frame's depth and pose from it and earlier frames only; false: final when it leaves the window
    causal: bool = False
    depth_source: Literal["generator", "ipbasic"] = "generator"  # ipbasic: no network (self-supervised cold start)
    # motion-compensate scans with per-point times by the sweep's motion (odometry.sweep_motion: from the images
    # where they agree, else the last step; causal: the last step)
    deskew: bool = True
    compare: bool = False  # also run the textbook monocular VO (`mono_vo`) and KISS-ICP alone (`kiss_icp`, with LiDAR; always with ground-truth poses)
    frontend: FrontEndConfig = FrontEndConfig()  # ORB features, their LiDAR depth, the initial pose
    graph: GraphConfig = GraphConfig()  # the sliding-window graph: its factors, the depth correction field, the solver
    accumulation: AccumulationConfig = AccumulationConfig()  # a cone LiDAR's earlier scans in the generator's input
    motion_stereo: MotionStereoConfig = MotionStereoConfig()  # image corners triangulated over nearby frames correct the depth
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


class BenchRefineConfig(_Model):
    """`leovr bench refine`: depth, trajectory and timing of the refinement on simulator and KITTI clips."""

    dataset: str | None = None  # simulator dataset with a test split; None = the cached default recipe
    kitti_raw_clips: list[str] | None = None  # KITTI raw drives; None = every one under ../shared/data ([]: none)
    kitti_odometry: str | None = None  # None = the shared KITTI odometry clip (skipped when absent)
    checkpoint: str | None = None  # generator weights; None = the shipped generator
    window: int = Field(4, ge=2)  # sliding-window length (frames)
    windows: list[int] = [2, 3, 4, 6]  # window-length ablation on the first Mid-40 test sequence
    synthetic_lidars: list[Literal["mid40", "vlp16"]] = ["mid40", "vlp16"]  # rendered test sequences' LiDARs
    kitti_inputs: list[str] = ["vlp16", "mid40"]  # cheap inputs simulated from the KITTI scans
    frames: int | None = None  # frames per sequence (None = all)
    quick_frames: int = Field(8, ge=3)  # --quick: 8-frame rendered test sequences, first 8 KITTI frames


class BenchLoopConfig(_Model):
    """`leovr bench loop`: loop closure on simulated city loops and the shared real clips."""

    lidars: list[Literal["mid40", "vlp16"]] = ["mid40", "vlp16"]  # simulated LiDARs
    # reported drives: never used for training or tuning (docs/decisions/0010-loop-validation-limits.md)
    seeds: list[int] = [3300, 3301]
    tuning_seeds: list[int] = [3000, 3001]  # the validation thresholds were tuned on these: reported apart
    frames: int = Field(130, ge=10)  # frames per drive; at 80 km/h a lap of the city loop is about 110 frames
    quick_frames: int = Field(120, ge=10)  # --quick: one LiDAR, one seed
    speed_kmh: float = 80.0  # driving speed (km/h)
    loop_min_gap: int = 30  # loop candidates at least this many frames older
    kitti_raw: str | None = None  # KITTI raw clip; None = the shared one (skipped when absent)
    kitti_odometry: str | None = None  # KITTI odometry clip; None = the shared one (skipped when absent)


class BenchSpeedConfig(_Model):
    """`leovr bench speed`: time per frame of `leovr refine`, per stage, on a long rendered drive and the
    KITTI raw clip, with the same run's accuracy and IP-Basic's time as the machine's yard stick."""

    frames: int = Field(200, ge=10)  # rendered 448 x 256 drive
    scenario: Scenario = "city_loop"  # the rendered drive's scenario
    lidar: Literal["mid40", "vlp16"] = "mid40"  # the rendered drive's LiDAR
    seed: int = 3200  # a drive used for nothing else
    kitti_raw: str | None = None  # None = ../shared/data/kitti_raw (skipped when absent)
    kitti_input: str = "vlp16"  # cheap input simulated from the KITTI scans
    generator_runtime: GeneratorRuntime = "onnxruntime_int8"  # refine's, as a user runs it
    quick_frames: int = Field(12, ge=4)  # --quick: this many rendered and KITTI frames
    target_ms_448: float = 100.0  # target: end to end, median per 448 x 256 frame (ms)
    target_ms_kitti: float = 250.0  # target: end to end, median per KITTI frame (ms)
    target_graph_p95_over_median: float = 1.5  # target: the graph's p95 time over its median


class TrainConfig(_Model):
    """`leovr train --mode supervised`: the depth generator on simulator splits (LeoVR Sec. V-A defaults)."""

    dataset: str | None = None  # folder with manifest.json; None: the cached recipe below
    recipe: str = "default"  # dataset recipe (tools/make_dataset.py --recipe)
    epochs: int = Field(24, ge=1)  # training epochs
    batch_size: int = Field(8, ge=1)  # frames per batch
    lr: float = Field(1e-4, gt=0)  # learning rate
    lr_step_epochs: int = Field(6, ge=1)  # learning rate multiplied by lr_gamma every this many epochs
    lr_gamma: float = Field(0.5, gt=0, le=1)  # ... by this factor
    sigma_epochs: int = Field(2, ge=0)  # second phase: uncertainty head only, depth path frozen
    loss: Literal["l1", "l2"] = "l1"  # depth loss, masked on valid ground truth
    smoothness: float = Field(0.0, ge=0)  # weight of edge-aware smoothness (optional)
    ratio_min: float = 0.005  # density-agnostic input (SLIM): share of ground-truth pixels drawn, at least ...
    ratio_max: float = 0.30  # ... and at most
    native_prob: float = Field(0.5, ge=0, le=1)  # share of samples using the sequence's own LiDAR pattern
    lidar_encoder: Literal["partial", "interp"] = "partial"  # LiDAR branch: SLIM partial convolutions | pre-interpolated input
    cross_attention: bool = True  # image-LiDAR cross attention at the encoders' deepest stage
    output: Literal["absolute", "residual", "fusion"] = "fusion"  # what the decoder predicts (leovr.depth.network)
    channels: list[int] = [16, 32, 64, 128, 128]  # encoder channels: stem, then each stage (stride 2 each)
    blocks: list[int] = [3, 4, 6, 3]  # ResNet blocks per encoder stage
    max_frames: int | None = None  # cap on training frames (quick runs)
    init_checkpoint: str | None = None  # start from these weights (fine-tuning); the network must match
    # the residual networks' classical prior at depth edges: the image's side (as at inference) or the nearest return
    prior_edges: Literal["image", "nearest"] = "image"
    seed: int = 0  # seeds sampling and initialisation


class SelfSupConfig(_Model):
    """`leovr train --mode selfsup`: cold-start self-supervised training (LeoVR Sec. IV, V-A). No ground
    truth is read: poses, landmarks and refined depth come from the graph on the raw sequences."""

    epochs: int = Field(24, ge=1)  # training epochs
    init_fraction: float = Field(0.75, ge=0, le=1)  # initialisation stage: the first 3/4 of the epochs (18 of 24)
    refresh_every: int = Field(2, ge=1)  # refinement stage: poses, masks and supervision renewed every 2 epochs
    batch_size: int = Field(8, ge=1)  # frames per batch
    lr: float = Field(1e-4, gt=0)  # learning rate
    lr_step_epochs: int = Field(6, ge=1)  # learning rate multiplied by lr_gamma every this many epochs
    lr_gamma: float = Field(0.5, gt=0, le=1)  # ... by this factor
    alpha: float = Field(0.8, ge=0, le=1)  # eq. 17: alpha/2 (1 - SSIM) + (1 - alpha) L1
    weight_feature: float = Field(0.4, ge=0)  # lambda_f, eq. 22
    weight_refined: float = Field(0.1, ge=0)  # lambda_r
    weight_smooth: float = Field(0.2, ge=0)  # lambda_s
    # sparse depth reconstruction |log D - log z| at the LiDAR input's returns (0: off; on the traffic validation
    # seed it helped the unmasked run 8 % and the masked one not at all)
    weight_sparse: float = Field(0.0, ge=0)
    target_loss: Literal["log_l1", "l2"] = "log_l1"  # L_f and L_r: |log D - log D*| (default) or the paper's squared metres
    flow_mask: bool = True  # eq. 19 motion-optical-flow mask on the photometric loss
    flow_lambda_px: float = Field(1.0, gt=0)  # lambda: largest distance (px) of the flow end point to its epipolar line
    flow_method: Literal["dis", "farneback"] = "dis"  # OpenCV optical flow
    rigid_mask: bool = True  # also drop pixels whose flow disagrees with the rigid flow of the graph's pose and depth
    rigid_abs_px: float = Field(0.5, gt=0)  # rigid test tolerance: px ...
    rigid_rel: float = Field(0.3, ge=0)  # ... plus this share of the rigid flow's depth-dependent part
    rigid_support_px: float = Field(4.0, ge=0)  # initialisation stage: rigid and depth tests only this close to a LiDAR return (0: everywhere)
    depth_mask: bool = False  # drop pixels whose depth, moved into the neighbour, disagrees with the neighbour's depth
    depth_mask_rel: float = Field(0.05, gt=0, lt=1)  # depth test tolerance, relative
    auto_mask: bool = True  # monodepth2: per-pixel minimum over the neighbours, pixels that match better unwarped dropped
    weight_nll: float = Field(0.1, ge=0)  # Gaussian NLL of the uncertainty head at the LiDAR-backed landmarks (0: head untrained)
    input: str = "full"  # LiDAR input of the generator and the graph (full, vlp16, mid40, ratio:R)
    train_focal_px: float | None = 260.0  # frames resampled to this focal length (px; the generator's camera); None = native
    max_frames: int | None = None  # first frames of each sequence only (None = all)
    loop_closure: bool = True  # pose quality assurance (Sec. IV-B) in every graph pass
    loop_min_gap: int = Field(30, ge=2)  # loop candidates at least this many frames older
    landmark_frames: int = Field(4, ge=0)  # a landmark counts as visible in frame i when last observed within this many frames
    landmarks_lidar_only: bool = True  # L_f on LiDAR-backed landmarks only (triangulated-only ones carry metres of error)
    refined_agree_rel: float = Field(0.05, gt=0)  # L_r uses a frame when its refined depth is within this of the landmarks (median)
    lidar_encoder: Literal["partial", "interp"] = "partial"  # LiDAR branch: SLIM partial convolutions | pre-interpolated input
    cross_attention: bool = True  # image-LiDAR cross attention at the encoders' deepest stage
    output: Literal["absolute", "residual", "fusion"] = "absolute"  # the paper's cold start predicts depth itself
    channels: list[int] = [16, 32, 64, 128, 128]  # encoder channels: stem, then each stage (stride 2 each)
    blocks: list[int] = [3, 4, 6, 3]  # ResNet blocks per encoder stage
    init_checkpoint: str | None = None  # start from these weights instead of random ones
    rerun_frames: int = Field(2, ge=1)  # frames logged to --rerun each epoch
    seed: int = 0  # seeds sampling and initialisation

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))


class AdaptConfig(_Model):
    """`leovr adapt`: fine-tune the generator on the user's recordings by hiding part of their own LiDAR
    input (selfsup.masked_lidar); no ground truth, no held-out evaluation points."""

    input: str = "full"  # the recording's own scan; vlp16 / mid40 / ratio:R when evaluating a cheaper sensor
    init_checkpoint: str | None = None  # None = the shipped generator (must be a residual / fusion network)
    generator_focal_px: float | None = 260.0  # frames resampled to the generator's training focal length (px)
    seed: int = 0  # seeds the masked splits and training
    start: int = 0  # frames [start:end] of every sequence
    end: int | None = None  # ... None = to the last frame
    splits_per_frame: int = Field(4, ge=1)  # masked splits drawn per frame (one per visit, at random)
    val_every: int = Field(8, ge=0)  # every n-th frame validates, never trained on (0 = no validation)
    epochs: int = Field(40, ge=1)  # at most; early stopping usually ends sooner
    patience: int = Field(6, ge=1)  # stop after this many epochs without a better validation MAE
    max_minutes: float | None = Field(18.0, gt=0)  # stop before the next epoch once training took this long (min)
    batch_size: int = Field(4, ge=1)  # frames per batch
    lr: float = Field(1e-4, gt=0)  # learning rate
    weight_smooth: float = Field(0.01, ge=0)  # edge-aware smoothness of the inverse depth
    weight_nll: float = Field(1.0, ge=0)  # Gaussian NLL of the uncertainty head at the hidden returns
    # loss at the hidden returns: metres, or log depth (relative); this and the next two chosen on the KITTI raw
    # clip's development frames 0-37 (VLP-16-like), never its test frames 38-47
    depth_loss: Literal["l1", "log_l1"] = "log_l1"
    span_rings: bool = True  # hidden-return parallax filter reaches the next rings (selfsup.masked_lidar)
    weight_anchor: float = Field(5.0, ge=0)  # |log depth - starting network's| on the whole input (selfsup.adapt)

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))


class BenchRealConfig(_Model):
    """`leovr bench real`: every depth method on each real KITTI raw drive, same held-out pixels, leovr's
    trajectory beside KISS-ICP's where the drive has ground-truth poses, and (optionally) adaptation under
    the inductive and transductive protocols."""

    clips: list[str] | None = None  # KITTI raw drives; None = every one under ../shared/data (development data)
    inputs: list[str] = ["vlp16", "mid40"]  # cheap inputs simulated from the drives' scans
    checkpoint: str | None = None  # generator to start from (None = the shipped one)
    window: int = Field(4, ge=2)  # sliding-window length (frames)
    # inputs the generator is also adapted to each clip for (minutes per input and protocol); none by default
    # (docs/decisions/0009-no-adaptation-by-default.md)
    adapt_inputs: list[str] = []
    causal: bool = True  # also run each input in refine's causal mode (live use) and report it beside
    inductive_train_fraction: float = Field(0.8, gt=0, lt=1)  # adapt on the first 80 % of a clip's frames, score the rest
    adapt_epochs: int = Field(40, ge=1)  # at most; early stopping on the validation frames usually ends sooner
    quick_frames: int = Field(12, ge=4)  # --quick: the first 12 frames ...
    quick_train_frames: int = Field(8, ge=1)  # ... adapted on the first 8
    quick_epochs: int = Field(1, ge=1)  # --quick: adaptation epochs
    seed: int = 0  # seeds the simulated inputs and adaptation


class BenchSelfSupConfig(_Model):
    """`leovr bench selfsup`: cold-start self-supervised training against untrained and supervised
    models on the same frames and schedule, plus a cold start on the shared KITTI raw clip."""

    dataset: str | None = None  # simulator dataset (tools/make_dataset.py); None = the cached default recipe
    scenarios: list[Scenario] = ["dynamic", "city_loop"]  # simulator scenarios trained and scored
    traffic_sequences: int = Field(3, ge=1)  # traffic scenario (its own dataset recipe): training sequences; 2 test sequences
    parts: list[Literal["synthetic", "traffic", "kitti"]] = ["synthetic", "traffic", "kitti"]  # which parts of the bench run
    lidar: Literal["mid40", "vlp16"] = "mid40"  # LeoVR's self-supervised experiments use the Mid-40
    train_sequences: int = Field(3, ge=1)  # per scenario (day sequences first)
    test_sequences: int = Field(2, ge=1)  # per scenario, from the test split
    epochs: int = Field(24, ge=1)  # the paper's schedule: 18 initialisation + 6 refinement epochs
    quick_epochs: int = Field(2, ge=1)  # --quick: epochs
    quick_frames: int = Field(12, ge=4)  # --quick: frames per sequence, one sequence per scenario
    train_focal_px: float = 130.0  # px, half the simulator's: 224 x 128 frames keep the run under an hour
    channels: list[int] = [16, 32, 64, 128, 128]  # encoder channels: stem, then each stage (stride 2 each)
    batch_size: int = Field(8, ge=1)  # frames per batch
    lr: float = Field(1e-3, gt=0)  # learning rate
    kitti_raw: str | None = None  # None = ../shared/data/kitti_raw (skipped when absent)
    kitti_input: str = "vlp16"  # cheap input simulated from the clip's scans
    kitti_train_frames: int = Field(38, ge=4)  # cold start on the first frames ...
    kitti_test_frames: int = Field(10, ge=1)  # ... scored on held-out beams of the last frames
    kitti_epochs: int = Field(96, ge=1)  # 5 batches an epoch on the 48-frame clip: 480 steps
    kitti_refresh_every: int = Field(8, ge=1)  # refinement-stage graph re-runs on the clip every N epochs


class BatchConfig(_Model):
    """`leovr batch`: one Ray task per sequence, on a local Ray instance or an existing cluster."""

    job: Literal["refine", "complete", "adapt+refine"] = "refine"  # run on each sequence, with its own section's settings
    address: str | None = None  # None: start a local Ray instance; "auto" or HOST:PORT: join a running cluster
    workers: int | None = Field(None, ge=1)  # tasks in flight; None = the cluster's CPUs / cpus_per_task
    cpus_per_task: int = Field(1, ge=1)  # Ray's num_cpus per task; also the task's torch / OpenCV threads
    max_retries: int = Field(3, ge=0)  # a task whose worker dies is re-run (resuming) up to this often
    adapt_processes: int | None = Field(None, ge=1)  # adapt+refine: data-parallel processes of cpus_per_task CPUs (None = one per node, all its CPUs)
    dashboard: bool = False  # start Ray's dashboard with a local instance (needs `pip install "ray[default]"`)


class BenchBatchConfig(_Model):
    """`leovr bench batch`: wall time of `leovr batch` with 1 and 2 workers on the same generated sequences."""

    sequences: int = Field(4, ge=1)  # rendered sequences
    frames: int = Field(16, ge=3)  # frames per sequence
    lidar: Literal["mid40", "vlp16"] = "mid40"  # the sequences' LiDAR
    seed: int = 3300  # drives used for nothing else
    target_speedup: float = 1.7  # target: wall time with 1 worker over 2 workers


class LeovrConfig(_Model):
    complete: CompleteConfig = CompleteConfig()
    simulate: SimulateConfig = SimulateConfig()
    bench_simulate: BenchSimulateConfig = BenchSimulateConfig()
    bench_baseline: BenchBaselineConfig = BenchBaselineConfig()
    bench_depth: BenchDepthConfig = BenchDepthConfig()
    demo: DemoConfig = DemoConfig()
    train: TrainConfig = TrainConfig()
    refine: RefineConfig = RefineConfig()
    bench_refine: BenchRefineConfig = BenchRefineConfig()
    bench_loop: BenchLoopConfig = BenchLoopConfig()
    bench_speed: BenchSpeedConfig = BenchSpeedConfig()
    selfsup: SelfSupConfig = SelfSupConfig()
    adapt: AdaptConfig = AdaptConfig()
    bench_real: BenchRealConfig = BenchRealConfig()
    bench_selfsup: BenchSelfSupConfig = BenchSelfSupConfig()
    batch: BatchConfig = BatchConfig()
    bench_batch: BenchBatchConfig = BenchBatchConfig()


def _describe(exc: ValidationError) -> str:
    """One line per invalid field: 'section.key: what is wrong'."""
    return "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())


def load_config(path: str | Path | None = None) -> LeovrConfig:
    """Defaults, overlaid with a YAML file when given; unknown keys and bad values are errors."""
    if path is None:
        return LeovrConfig()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    try:
        return LeovrConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {_describe(exc)}") from exc


def _given(options: dict[str, Any]) -> dict[str, Any]:
    """The options that were given: None left out, in nested mappings too (an emptied mapping with them)."""
    given = {}
    for key, value in options.items():
        if isinstance(value, dict):
            value = _given(value) or None
        if value is not None:
            given[key] = value
    return given


def _merged(base: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """`base` with `given` on top; a nested mapping is merged key by key, not replaced."""
    out = dict(base)
    for key, value in given.items():
        nested = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merged(out[key], value) if nested else value
    return out


def override(model: _Model, **options: Any) -> Any:
    """A copy of `model` with the options that were given (not None) applied and validated. A nested
    model's options come as a mapping and change only the keys they name:
    `override(cfg, window=6, loop={"enabled": True})`."""
    try:
        return model.model_validate(_merged(model.model_dump(), _given(options)))
    except ValidationError as exc:
        raise ConfigError(f"invalid option: {_describe(exc)}") from exc
