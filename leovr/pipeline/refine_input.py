"""A refine run's settings derived from its input, and one frame's input: its image, its cheap LiDAR
input (deskewed) and the depth the graph starts from when no trained network may be used."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from leovr.config import CompleteConfig, FrameSelection, RefineConfig
from leovr.data.records import Frame
from leovr.data.sequence import Sequence
from leovr.depth.fills import complete_depth
from leovr.errors import DataError
from leovr.eval.heldout import parallax_filter
from leovr.lidar.deskew import deskew_frame
from leovr.lidar.projection import sparse_depth
from leovr.pipeline.completion import EvalSample, prepare_sample


def completion_config(cfg: RefineConfig) -> CompleteConfig:
    """The generator with the run's input and scoring settings, as `complete` would run it."""
    shared = set(FrameSelection.model_fields)
    settings = cfg.model_dump(include=shared)
    if settings["input"] == "none":  # camera only: the generator gets no LiDAR (frame_sample), the scan is truth
        settings["input"] = "full"
    return CompleteConfig(method="generator", **settings)


def camera_only_config(cfg: RefineConfig) -> RefineConfig:
    """The front end's and graph's settings without LiDAR: `refine.graph` with the camera-only profile's graph
    settings (`refine.camera_only.graph`: the generator's depth, far less sure without LiDAR, gets a looser landmark
    prior and depth-consistency sigma) in their place, and its ORB feature count (`refine.camera_only.n_features`)."""
    graph = cfg.graph.model_copy(update=cfg.camera_only.graph.model_dump())
    frontend = cfg.frontend.model_copy(update={"n_features": cfg.camera_only.n_features})
    return cfg.model_copy(update={"graph": graph, "frontend": frontend})


def road_height(seq: Sequence, cfg: RefineConfig) -> float | None:
    """The camera's height above the road for camera-only runs: the config's, else the recording's;
    None (or 0 in the config): unknown, the generator's depth sets the scale."""
    h = cfg.camera_only.camera_height_m
    h = seq.camera_height_m if h is None else h
    return h if h else None


def classical_source(sample: EvalSample) -> tuple[np.ndarray, np.ndarray]:
    """IP-Basic depth with its holes (above the scan) filled from the nearest completed pixel, and a
    flat 20 % relative sigma: the graph's depth input when no trained network may be used (the
    self-supervised cold start)."""
    from scipy.ndimage import distance_transform_edt

    depth = complete_depth(sample.sparse, "ipbasic")
    hole = depth <= 0
    if hole.all():
        raise DataError(f"frame {sample.frame.index}", "no LiDAR return in the image: nothing to complete")
    if hole.any():
        _, (iv, iu) = distance_transform_edt(hole, return_indices=True)
        depth = depth[iv, iu]
    return depth, np.log(0.2 * depth)


def stereo_image(seq: Sequence, j: int) -> np.ndarray | None:
    """Frame j's image for motion stereo, None when it cannot be read (the frame's own turn reports it)."""
    from leovr.data.io import read_image

    try:
        path = seq.image_path(j)
        return read_image(path, gray=True) if path is not None else seq[j].image
    except DataError:
        return None


def ground_truth_motion(seq: Sequence, i: int) -> tuple[np.ndarray, float] | None:
    """The camera's ground-truth motion over one frame interval at frame i (to the next frame, at the last one
    from the previous) and that interval's seconds; None without poses."""
    if not seq.has_poses or len(seq) < 2:
        return None
    a, b = (i, i + 1) if i + 1 < len(seq) else (i - 1, i)
    Ta, Tb = seq.pose(a), seq.pose(b)
    times = seq.timestamps()
    dt = float(times[b] - times[a])
    if Ta is None or Tb is None or not dt > 0:
        return None
    return np.linalg.inv(Ta) @ Tb, dt


TRUTH_DESKEW_NOTE = (
    "scans with point times deskewed with the ground-truth motion where the recording has poses, "
    "else with the run's own"
)


def truth_scan(seq: Sequence, i: int, frame: Frame) -> Callable[[], np.ndarray] | None:
    """Where the recording has poses and point times: a function giving frame i's scan deskewed with the
    ground-truth motion, so that the held-out truth does not depend on the run's own motion estimate (without
    poses it is deskewed like the input: None)."""
    if frame.depth is not None or frame.point_times is None or frame.points is None:
        return None
    motion = ground_truth_motion(seq, i)
    return None if motion is None else (lambda: deskew_frame(frame, *motion).points)


def frame_sample(
    seq: Sequence,
    i: int,
    ccfg: CompleteConfig,
    motion_cam: np.ndarray | None = None,
    frame_dt: float = 0.1,
    camera_only: bool = False,
    truth: bool = True,
    frame: Frame | None = None,
) -> EvalSample:
    """The frame with its cheap LiDAR input (deskewed when a motion is given) and ground truth; without
    LiDAR (or `camera_only`, `--input none`) an empty input, and the whole scan, if any, held out.
    `truth=False`: a held-out truth is left for `with_truth` (prepare_sample). `frame`: seq[i], read already."""
    raw = seq[i] if frame is None else frame
    f = deskew_frame(raw, motion_cam, frame_dt)
    has_points = f.points is not None and len(f.points) > 0
    if has_points and not camera_only:
        return prepare_sample(f, ccfg, truth, truth_scan(seq, i, raw), None if f is raw else raw.points)
    empty = np.zeros(f.shape, np.float32)
    if f.depth is not None:
        return EvalSample(f, empty, f.depth, "dense", None)
    if has_points:
        scan = truth_scan(seq, i, raw)
        every = sparse_depth(f.points if scan is None else scan(), f.K, f.T_cam_lidar, f.shape)
        return EvalSample(f, empty, parallax_filter(every, every), "heldout", None)
    return EvalSample(f, empty, empty, "none", None)
