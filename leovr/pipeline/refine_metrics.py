"""A refine run's metrics.json: each frame's scored pixels (`FrameScore`) pooled per method, leovr's trajectory and
the pose baselines' against the ground truth, and `step_ratio.png`."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leovr.config import CompleteConfig, RefineConfig
from leovr.data.io import format_max_depth, write_text
from leovr.data.sequence import Sequence
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.accumulated_baseline import ACCUMULATED
from leovr.pipeline.completion import EvalSample, ground_truth_note
from leovr.pipeline.refine_input import TRUTH_DESKEW_NOTE
from leovr.pipeline.refine_outputs import Progress, input_label

# depth methods in metrics.json, same pixels
SCORED = (
    "nearest",
    "ipbasic",
    *ACCUMULATED,
    "generator",
    "generator_frame",
    "refined",
)
# generator: as it ran in the graph (with earlier scans for a cone LiDAR); generator_frame: on the frame's own scan
# alone; nearest / ipbasic_accumulated: the fills of the same frames' returns placed with KISS-ICP's poses (cone
# LiDAR only)


@dataclass
class FrameScore:
    """A frame's ground-truth pixels and each method's depth there: the run's as its PNGs hold them, the
    baselines' as they would."""

    kind: str
    pick: tuple[np.ndarray, np.ndarray]
    gt: np.ndarray
    pred: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, sample: EvalSample) -> "FrameScore | None":
        if sample.gt_kind == "none":
            return None
        pick = np.nonzero(np.isfinite(sample.gt) & (sample.gt > 0))
        return cls(sample.gt_kind, pick, sample.gt[pick])

    def add(self, method: str, depth: np.ndarray) -> None:
        """Scored as its depth PNG holds it, saturated at the format's largest depth (a far cell's correction
        can carry pixels past 256 m; scored unsaturated, they counted kilometres that no file held)."""
        self.pred[method] = np.minimum(depth[self.pick], format_max_depth())


@dataclass
class RunScores:
    """What the scoring pass found: each scored frame's pixels, the ground-truth poses of the selected frames
    (empty when not scored) and the pose baselines (name -> poses of the same frames, alignment)."""

    frames: dict[int, FrameScore] = field(default_factory=dict)
    gt_poses: list[np.ndarray | None] = field(default_factory=list)
    baselines: dict[str, tuple[np.ndarray, str]] = field(default_factory=dict)


def pooled_depth(
    scores: list[FrameScore], accs: dict[str, DepthMetricAccumulator], pool: dict[str, DepthMetricAccumulator] | None
) -> set[str]:
    """Adds every frame's scored pixels to `accs` and `pool`; returns the kinds of ground truth met."""
    kinds = set()
    partial = {m for m in SCORED if 0 < sum(m in fs.pred for fs in scores) < len(scores)}
    for fs in scores:  # a method some frames lack is left out
        kinds.add(fs.kind)
        for method, pred in fs.pred.items():
            if method in partial:
                continue
            for target in (accs, pool or {}):
                if method in target:
                    target[method].add(pred, fs.gt)
    return kinds


def trajectory_record(
    poses: np.ndarray,
    gt_poses: list[np.ndarray],
    has_lidar: bool,
    state: Progress,
    indices: list[int],
    baselines: dict[str, tuple[np.ndarray, str]] | None,
) -> dict:
    """leovr's trajectory against the ground truth, before loop closure moved it when it ran, and the
    baselines' beside it."""
    ref = np.stack([invert_T(gt_poses[0]) @ T for T in gt_poses])
    align = "se3" if has_lidar else "sim3"
    record = {"leovr": trajectory_metrics(poses, ref, align)}
    earlier = state.stacked("poses_no_loop", indices)  # before loop closure moved them, when it ran
    if earlier is not None:
        record["leovr_no_loop"] = trajectory_metrics(earlier, ref, align)
    for name, (est, how) in (baselines or {}).items():
        record[name] = trajectory_metrics(est, ref, how)
    return record


def plot_steps(
    poses: np.ndarray,
    gt_poses: list[np.ndarray],
    record: dict,
    baselines: dict[str, tuple[np.ndarray, str]] | None,
    path: Path,
) -> None:
    """`step_ratio.png`: each trajectory's step lengths over the ground truth's along the run (at the scale it is
    scored at: a Sim(3)-aligned one times its alignment's scale)."""
    from leovr.viz.step_plot import plot_step_ratios

    tracks = {"leovr": poses} | {name: est for name, (est, _) in (baselines or {}).items()}
    scaled = {}
    for name, est in tracks.items():
        est = np.array(est, float)
        est[:, :3, 3] *= record[name]["scale"]
        scaled[name] = est
    plot_step_ratios(scaled, np.stack(gt_poses), path)


def write_metrics(
    seq: Sequence,
    cfg: RefineConfig,
    ccfg: CompleteConfig,
    indices: list[int],
    state: Progress,
    out: Path,
    has_lidar: bool,
    timing: dict,
    scores: RunScores,
    pool: dict[str, DepthMetricAccumulator] | None = None,
    no_returns: bool = False,
) -> dict:
    """metrics.json: the run's settings and timing, depth per method pooled over the scored frames (also into
    `pool`), and with ground-truth poses the trajectories against them (`step_ratio.png` beside it).
    `no_returns`: a LiDAR run in which no frame had a return inside its image, said in its `mode`."""
    accs = {m: DepthMetricAccumulator(cfg.bins) for m in SCORED}
    kinds = pooled_depth([scores.frames[i] for i in indices if i in scores.frames], accs, pool)
    metrics: dict = {
        "sequence": str(Path(seq.path).resolve()),
        "reader": seq.name,
        "input": cfg.input if seq.has_lidar else "none (no LiDAR)",
        "input_note": input_label(cfg.input, has_lidar),
        "frames": len(indices),
        "window": cfg.window,
        "causal": cfg.causal,
        "mode": (
            input_label(cfg.input, has_lidar)
            if not has_lidar
            else "visual-LiDAR"
            if not no_returns
            else "visual-LiDAR input without a LiDAR return inside any image: depth and poses from the images alone"
        ),
        "ground_truth": "; ".join(ground_truth_note(k, ccfg) for k in sorted(kinds))
        + ("; " + TRUTH_DESKEW_NOTE if "heldout" in kinds else ""),
        "depth": {m: a.result() for m, a in accs.items() if not a.empty},
        "timing": timing,
    }
    gt_poses = scores.gt_poses
    if gt_poses and all(T is not None for T in gt_poses) and len(indices) >= 3:
        poses = state.stacked("poses", indices)
        metrics["trajectory"] = trajectory_record(poses, gt_poses, has_lidar, state, indices, scores.baselines)
        plot_steps(poses, gt_poses, metrics["trajectory"], scores.baselines, out / "step_ratio.png")
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return metrics
