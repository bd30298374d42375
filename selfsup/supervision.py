"""What the graph gives the trainer (LeoVR Sec. IV-B, IV-D): poses with loop closure, landmarks and
refined depth from one pass of `leovr poses` over a raw sequence, turned into per-frame training
targets at the training resolution: neighbour poses, motion-optical-flow masks, the landmarks'
sparse depth D^f and the refined depth D^r with its agreement flag.

Initialisation stage: no network is trusted yet, so the graph runs on IP-Basic depth with point
factors only. Refinement stage: the current generator and the full graph."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from leovr.config import AccumulationConfig, GraphConfig, LoopConfig, RefineConfig, SelfSupConfig
from leovr.data.io import read_json_object, require_file, write_text
from leovr.data.kitti_common import read_kitti_poses
from leovr.data.run_info import read_run_depth
from leovr.data.sequence import Sequence
from leovr.depth.inference import rescale_sparse
from leovr.errors import DataError
from leovr.geometry import invert_T
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor
from leovr.lidar.projection import sparse_depth
from selfsup.masked_lidar import masked_split
from selfsup.motion_mask import PairKeep, movers, pair_keep

# The masks and targets' fixed settings (LeoVR Sec. IV; chosen on development data):
FLOW_LAMBDA_PX = 1.0  # eq. 19's lambda: largest distance (px) of the flow end point to its epipolar line
FLOW_METHOD = "dis"  # OpenCV optical flow (dis | farneback)
# the rigid test: a pixel's flow within this many px, plus RIGID_REL of the rigid flow's depth-dependent part, of the
# rigid flow of the graph's pose and depth
RIGID_ABS_PX = 0.5
RIGID_REL = 0.3
RIGID_SUPPORT_PX = 4.0  # initialisation stage: rigid and depth tests only this close to a LiDAR return (0: everywhere)
DEPTH_MASK_REL = 0.05  # depth test tolerance, relative
LANDMARK_FRAMES = 4  # a landmark counts as visible in frame i when last observed within this many frames
REFINED_AGREE_REL = 0.05  # L_r uses a frame when its refined depth is within this of the landmarks (median)
MASKED_SPLITS = 4  # masked-LiDAR splits drawn per frame (one per visit, at random)


class PosePass(Protocol):
    """The window graph over a sequence (the application's `leovr.pipeline.refine.run_refine`): writes
    `poses_kitti.txt`, `landmarks*.npy` and `depth/` into `out`, resuming from its `progress.json`."""

    def __call__(
        self, seq: Sequence, cfg: RefineConfig, out: Path, *, resume: bool, progress: bool, score: bool
    ) -> object: ...


@dataclass
class TrainFrame:
    """One frame as the network sees it: resampled to the training focal length."""

    index: int
    image: np.ndarray  # H x W x 3 uint8
    sparse: np.ndarray  # H x W float32 metres, the cheap LiDAR input
    K: np.ndarray  # 3 x 3 at the training resolution
    # masked-LiDAR splits (selfsup.masked_lidar) at the training resolution: (thinner input, hidden returns)
    masked: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    # the starting network's depth on this input (H x W metres; fine-tuning's anchor), None without one
    anchor: np.ndarray | None = None


@dataclass
class GraphResult:
    poses: np.ndarray  # F x 4 x 4 camera-to-world, frame order of `indices`
    indices: list[int]
    landmarks: np.ndarray  # N x 3 world
    landmark_frame: np.ndarray  # N: frame that last observed each landmark
    landmark_lidar: np.ndarray  # N: a LiDAR return fixed its range
    depth_dir: Path  # refined depth PNGs


@dataclass
class Supervision:
    """Targets of every frame of one sequence from one graph pass."""

    poses: np.ndarray  # F x 4 x 4
    feature_depth: list[np.ndarray]  # D^f per frame, H x W (0 = none)
    refined: list[np.ndarray | None]  # D^r per frame (refinement stage only)
    use_refined: np.ndarray  # F bools: D^r agrees with the landmarks
    mask_prev: list[np.ndarray | None]  # mu for the pair (i, i-1), H x W bool
    mask_next: list[np.ndarray | None]


def at_training_size(mask: np.ndarray, frame: TrainFrame) -> np.ndarray:
    """A full-resolution boolean mask of `frame` (e.g. the simulator's moving mask) resampled, nearest, to the
    frame's training resolution."""
    h, w = frame.sparse.shape
    return cv2.resize(mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0


def train_frames(seq: Sequence, cfg: SelfSupConfig) -> list[TrainFrame]:
    """Images and cheap LiDAR input of the selected frames at the training focal length."""
    n = len(seq) if cfg.max_frames is None else min(len(seq), cfg.max_frames)
    if n < 3:
        raise DataError(seq.path, f"self-supervised training needs at least 3 frames, got {n}")
    out = []
    for i in range(n):
        f = seq[i]
        if f.points is None:
            raise DataError(seq.path, f"frame {i} has no LiDAR scan; the trainer needs the LiDAR input")
        kept = simulate_cheap_sensor(
            f.points, parse_input(cfg.input), f.index, cfg.seed, f.K, f.T_cam_lidar, f.shape
        ).kept
        sparse = sparse_depth(kept, f.K, f.T_cam_lidar, f.shape)
        image = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, axis=2)
        K = f.K.astype(np.float64).copy()
        s = 1.0 if cfg.train_focal_px is None else cfg.train_focal_px / float(f.K[0, 0])
        resample = abs(s - 1.0) > 1e-6
        shape = (int(round(f.height * s)), int(round(f.width * s))) if resample else f.shape
        masked = []
        if cfg.weight_masked > 0 and len(kept):
            rng = np.random.default_rng([cfg.seed, i])
            for _ in range(MASKED_SPLITS):
                split = masked_split(kept, f.K, f.T_cam_lidar, f.shape, rng, span_rings=True, every=sparse)
                thin, hidden = (rescale_sparse(m, s, shape) if resample else m for m in (split.sparse, split.target))
                # a hidden return on a pixel the thinner input still measures teaches nothing
                masked.append((thin.astype(np.float32), np.where(thin > 0, 0.0, hidden).astype(np.float32)))
        if resample:
            image = cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
            sparse = rescale_sparse(sparse, s, shape)
            K[:2] *= s
        out.append(TrainFrame(i, image, sparse.astype(np.float32), K, masked))
    return out


def graph_pass(
    seq: Sequence,
    cfg: SelfSupConfig,
    out: Path,
    checkpoint: Path | None,
    n_frames: int,
    pose_pass: PosePass,
    progress: bool = True,
) -> GraphResult:
    """`leovr poses` (`pose_pass`) on the (blind) sequence into `out`; reused when `out/done.json` exists and
    was made with the same checkpoint file (path, size and time), resumed when a previous pass was interrupted.
    `checkpoint=None`: IP-Basic depth, point factors only."""
    out = Path(out)
    stamp = None if checkpoint is None else _file_stamp(Path(checkpoint))
    done = out / "done.json"
    if done.is_file():
        left = read_json_object(done)
        same = left.get("checkpoint") == (None if checkpoint is None else str(checkpoint))
        if not same or left.get("checkpoint_stamp", stamp) != stamp:  # a pass over other weights: run it again
            shutil.rmtree(out)
    if not done.is_file():
        rcfg = RefineConfig(
            input=cfg.input,
            end=n_frames,
            seed=cfg.seed,
            loop=LoopConfig(enabled=cfg.loop_closure),
            generator_focal_px=cfg.train_focal_px,
            depth_source="ipbasic" if checkpoint is None else "generator",
            # forced on with a generator (not `auto`): L_r needs a correction field that can move
            graph=GraphConfig(depth_factors=checkpoint is not None),
            checkpoint=None if checkpoint is None else str(checkpoint),
            # the trainer's own checkpoints carry no int8 calibration table: floating point
            generator_runtime="onnxruntime",
            # the trainer's graph passes as measured by `bench selfsup`: each frame's own scan only
            # (the earlier scans of a cone LiDAR in the depth input are not measured in training yet)
            accumulation=AccumulationConfig(frames=0),
        )
        pose_pass(seq, rcfg, out, resume=(out / "progress.json").is_file(), progress=progress, score=False)
        write_text(
            done,
            json.dumps({"checkpoint": None if checkpoint is None else str(checkpoint), "checkpoint_stamp": stamp})
            + "\n",
        )
    indices = list(range(n_frames))
    poses = read_kitti_poses(require_file(out / "poses_kitti.txt", "graph-pass poses"))
    if len(poses) != n_frames:
        raise DataError(out / "poses_kitti.txt", f"graph pass has {len(poses)} poses for {n_frames} frames")
    arrays = [
        np.load(require_file(out / name, "graph-pass landmarks"))
        for name in ("landmarks.npy", "landmarks_frame.npy", "landmarks_lidar.npy")
    ]
    return GraphResult(poses, indices, *arrays, out / "depth")


def _file_stamp(path: Path) -> list[int]:
    """[size, modification time in ns]: a checkpoint overwritten with new weights gets a new stamp."""
    st = require_file(path, "generator checkpoint").stat()
    return [st.st_size, st.st_mtime_ns]


def landmark_depth(
    frame: TrainFrame, T_world_cam: np.ndarray, landmarks: np.ndarray, landmark_frame: np.ndarray, near_frames: int
) -> np.ndarray:
    """D^f: landmarks last observed within `near_frames` of this frame, projected (nearest wins)."""
    h, w = frame.sparse.shape
    out = np.full((h, w), np.inf, np.float32)
    near = np.abs(landmark_frame - frame.index) <= near_frames
    if near.any():
        P = (landmarks[near] - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]  # world -> camera
        z = P[:, 2]
        uv = P @ frame.K.T
        ok = z > 0.5
        u = np.floor(uv[ok, 0] / z[ok] + 0.5).astype(np.int64)
        v = np.floor(uv[ok, 1] / z[ok] + 0.5).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        np.minimum.at(out, (v[inside], u[inside]), z[ok][inside].astype(np.float32))
    out[np.isinf(out)] = 0.0
    return out


def refined_agrees(refined: np.ndarray, feature_depth: np.ndarray, max_rel: float, min_points: int = 10) -> bool:
    """The refined map is geometrically consistent with the landmarks: median relative gap under max_rel."""
    ok = (feature_depth > 0) & (refined > 0)
    if ok.sum() < min_points:
        return False
    return bool(np.median(np.abs(refined[ok] - feature_depth[ok]) / feature_depth[ok]) < max_rel)


def graph_depth_at(graph: GraphResult, frame: TrainFrame) -> np.ndarray:
    """The depth the graph pass wrote for a frame, at the training resolution."""
    d = read_run_depth(graph.depth_dir.parent, graph.depth_dir.name, frame.index)
    return cv2.resize(d, (frame.sparse.shape[1], frame.sparse.shape[0]), interpolation=cv2.INTER_NEAREST)


def rigid_support(depth: np.ndarray | None, sparse: np.ndarray, radius_px: float) -> np.ndarray | None:
    """`depth` where a LiDAR input return lies within `radius_px` (a classical fill is unreliable
    further out: beyond a Mid-40's cone it extrapolates), 0 elsewhere; all of it when radius_px <= 0."""
    if depth is None or radius_px <= 0:
        return depth
    far = cv2.distanceTransform((sparse <= 0).astype(np.uint8), cv2.DIST_L2, 3) > radius_px
    return np.where(far, 0.0, depth)


def pair_tests(
    frames: list[TrainFrame], poses: np.ndarray, depth: list[np.ndarray | None], cfg: SelfSupConfig, k: int, j: int
) -> PairKeep:
    """The flow tests of frame k against its neighbour j, with the graph's poses and depth."""
    T_j_i = invert_T(poses[j]) @ poses[k]
    with_depth = cfg.rigid_mask or cfg.depth_mask
    return pair_keep(
        frames[k].image,
        frames[j].image,
        T_j_i,
        frames[k].K,
        (depth[k], depth[j]) if with_depth else None,
        FLOW_LAMBDA_PX,
        RIGID_ABS_PX,
        RIGID_REL,
        FLOW_METHOD,
        depth_rel=DEPTH_MASK_REL,
        rigid=cfg.rigid_mask,
        depth_test=cfg.depth_mask,
    )


def mover_keep(t: PairKeep, rigid: bool, depth: bool) -> np.ndarray:
    """The mover tests the config switches on: both = their hysteresis (`movers`), one = that one."""
    if rigid and depth:
        return ~movers(~t.rigid, ~t.depth)
    if rigid:
        return t.rigid
    if depth:
        return t.depth
    return np.ones_like(t.inside)


def keep_mask(t: PairKeep, cfg: SelfSupConfig) -> np.ndarray:
    """The mask the trainer uses: inside the neighbour, and every test the config switches on."""
    keep = t.inside & mover_keep(t, cfg.rigid_mask, cfg.depth_mask)
    if cfg.flow_mask:
        keep &= t.epipolar
    return keep


def build_supervision(
    frames: list[TrainFrame],
    graph: GraphResult,
    cfg: SelfSupConfig,
    with_refined: bool,
    mask_dir: Path | None = None,
    moving: list[np.ndarray] | None = None,
) -> Supervision:
    """Per-frame targets from a graph pass; masks are written as PNGs to `mask_dir` for inspection.

    `moving` (a bound for benchmarks, never a method): each frame's true moving mask at the training
    resolution; the photometric mask is then exactly its complement, in place of every configured test."""
    n = len(frames)
    keep = graph.landmark_lidar  # L_f on LiDAR-backed landmarks only: triangulated-only ones carry metres of error
    fdepth = [
        landmark_depth(f, graph.poses[k], graph.landmarks[keep], graph.landmark_frame[keep], LANDMARK_FRAMES)
        for k, f in enumerate(frames)
    ]
    graph_depth = (
        [graph_depth_at(graph, f) for f in frames] if with_refined or cfg.rigid_mask or cfg.depth_mask else [None] * n
    )
    # initialisation stage: the graph's depth is a classical fill, trusted by the rigid and depth tests only near
    # returns
    rigid_depth = (
        graph_depth
        if with_refined
        else [rigid_support(d, f.sparse, RIGID_SUPPORT_PX) for d, f in zip(graph_depth, frames)]
    )
    refined: list[np.ndarray | None] = [None] * n
    use = np.zeros(n, bool)
    if with_refined:
        for k in range(n):
            refined[k] = graph_depth[k]
            use[k] = refined_agrees(refined[k], fdepth[k], REFINED_AGREE_REL)
    prev: list[np.ndarray | None] = [None] * n
    nxt: list[np.ndarray | None] = [None] * n
    if moving is not None or cfg.flow_mask or cfg.rigid_mask or cfg.depth_mask:
        if mask_dir is not None:
            mask_dir.mkdir(parents=True, exist_ok=True)
        for k in range(n):
            for j, store, tag in ((k - 1, prev, "prev"), (k + 1, nxt, "next")):
                if 0 <= j < n:
                    store[k] = (
                        ~moving[k]
                        if moving is not None
                        else keep_mask(pair_tests(frames, graph.poses, rigid_depth, cfg, k, j), cfg)
                    )
                    if mask_dir is not None:
                        cv2.imwrite(str(mask_dir / f"{frames[k].index:06d}_{tag}.png"), store[k].astype(np.uint8) * 255)
    return Supervision(graph.poses, fdepth, refined, use, prev, nxt)
