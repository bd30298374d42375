"""What `leovr refine` keeps and writes: the resumable progress, each frame's score, timing.json, the pose
files and metrics.json."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig, RefineConfig
from leovr.data.io import depth_png_bytes, depth_to_uint16, format_max_depth, write_png_bytes, write_text
from leovr.data.kitti_common import write_kitti_poses
from leovr.data.native import write_tum_poses
from leovr.data.run_info import read_run_depth
from leovr.data.sequence import Sequence
from leovr.depth.fills import complete_depth
from leovr.errors import DataError
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.accumulated_baseline import ACCUMULATED
from leovr.pipeline.completion import EvalSample, ground_truth_note
from leovr.pipeline.refine_input import TRUTH_DESKEW_NOTE, frame_sample

# per frame, in timing.json as means: the generator (prior included, and the sweep's motion read from the
# images when it is), the front end, the graph update, and the
# writing of the frames that left the window (depth PNGs, progress.json); the baselines beside them are not timed.
# `total_ms` is their sum (the cost of a sequential run); `wall_ms` the frame's time on the run's clock, shorter
# because the generator of the next frame runs while the graph updates
TIMED = ("generator_ms", "frontend_ms", "graph_ms", "output_ms")
WALL = "wall_ms"  # a frame's time on the run's clock (the next frame's generator overlapping this one's graph)
CPU = "cpu_ms"  # the CPU time of every thread of the process over that span (user + system)
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
# alone;
# nearest / ipbasic_accumulated: the fills of the same frames' returns placed with KISS-ICP's poses (cone LiDAR only)
PNG_FOLDER = {"ipbasic": "depth_ipbasic", "generator": "depth_generator", "refined": "depth"}


@dataclass
class FrameScore:
    """A frame's ground-truth pixels and each method's depth there, taken from the arrays the run
    produced (the PNGs hold the same maps to 1/256 m)."""

    kind: str
    pick: tuple[np.ndarray, np.ndarray]
    gt: np.ndarray
    pred: dict[str, np.ndarray] = field(default_factory=dict)
    # the frame's own cheap input (rows, cols, depth) when earlier scans joined the generator's: the
    # single-frame generator (`generator_frame`) is scored from it after the run, not timed
    own_input: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

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
class Progress:
    """What has been finished: poses (camera to world) and the front end's choices, per frame index."""

    poses: dict[int, list[float]] = field(default_factory=dict)
    icp_poses: dict[int, list[float]] = field(default_factory=dict)
    sources: dict[int, str] = field(default_factory=dict)
    poses_no_loop: dict[int, list[float]] = field(default_factory=dict)  # before loop closure, when it ran
    times: dict[int, list[float]] = field(default_factory=dict)  # frame -> ms per stage of TIMED
    # frame -> the window's 6 x 6 covariance of the step into it, row by row (odometry.step_covariance)
    step_covariances: dict[int, list[float]] = field(default_factory=dict)

    @classmethod
    def load(cls, path: Path) -> "Progress":
        try:
            d = json.loads(path.read_text())
            if not isinstance(d, dict):
                raise ValueError("not a JSON object")
            d.setdefault("poses_no_loop", {})  # only runs with loop closure have it
            d.setdefault("step_covariances", {})
            keyed = {
                name: {int(k): v for k, v in d[name].items()}
                for name in ("poses", "icp_poses", "sources", "poses_no_loop", "times", "step_covariances")
            }
            # 16 finite numbers each (a 4 x 4 pose), 36 for a covariance
            for name, size in (("poses", 16), ("icp_poses", 16), ("poses_no_loop", 16), ("step_covariances", 36)):
                bad = [
                    i
                    for i, T in keyed[name].items()
                    if not isinstance(T, list) or len(T) != size or not np.isfinite(np.asarray(T, float)).all()
                ]
                if bad:
                    raise ValueError(f"{name} of frame {bad[0]} is not {size} finite numbers")
            return cls(**keyed)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataError(path, f"cannot resume from this progress file: {exc}") from exc

    def text(self) -> str:
        return json.dumps(self.__dict__) + "\n"

    def save(self, path: Path) -> None:
        write_text(path, self.text())

    def covariances(self, indices: list[int]) -> list[np.ndarray | None]:
        """The window's 6 x 6 covariance of the step into each of `indices` (None where it has none)."""
        kept = self.step_covariances
        return [np.array(kept[i]).reshape(6, 6) if i in kept else None for i in indices]

    def stacked(self, name: str, indices: list[int]) -> np.ndarray | None:
        """The poses kept under `name` ("poses", "poses_no_loop") as F x 4 x 4 in the order
        of `indices`; None unless every one of them is there."""
        kept = getattr(self, name)
        if not indices or any(i not in kept for i in indices):
            return None
        return np.stack([np.array(kept[i]).reshape(4, 4) for i in indices])


def write_frame_files(out: Path, name: str, maps: dict[str, np.ndarray], state_path: Path, state: str) -> None:
    """A leaving frame's depth maps (folder -> metres) as PNGs, then the run's progress record that names it.
    A map equal to an earlier one in its PNG units is not encoded again (a spinning LiDAR's refined depth is
    its generator's: a PNG is 10 ms)."""
    encoded: list[tuple[np.ndarray, bytes]] = []
    for folder, depth in maps.items():
        units = depth_to_uint16(depth)
        data = next((png for seen, png in encoded if np.array_equal(seen, units)), None)
        if data is None:
            data = depth_png_bytes(units, out / folder / name)
            encoded.append((units, data))
        write_png_bytes(out / folder / name, data)
    write_text(state_path, state)


def check_replay(out: Path, state: Progress, replayed: dict[int, np.ndarray], tol_m: float = 0.05) -> None:
    """Warn when replaying the finished frames of a resumed run did not give back the poses written
    before the interruption (another leovr version, or the recording changed in between)."""
    written = state.poses_no_loop or state.poses  # as the window pass left them
    gap = {
        i: float(np.linalg.norm(T[:3, 3] - np.array(written[i]).reshape(4, 4)[:3, 3]))
        for i, T in replayed.items()
        if i in written
    }
    if not gap:
        return
    worst = max(gap, key=gap.get)
    if gap[worst] > tol_m:
        warnings.warn(
            f"{out}: resuming replayed the finished frames but frame {worst}'s pose moved {gap[worst]:.2f} m "
            "from the one written before the interruption; the outputs mix two runs: rerun without --resume",
            stacklevel=2,
        )


def input_label(name: str, has_lidar: bool) -> str:
    """What the progress bar and metrics say the graph runs on."""
    if name == "none":
        return "camera only (the recording's LiDAR held out)"
    if not has_lidar:
        return "camera only (no LiDAR)"
    return "own scan" if name == "full" else f"{name} simulated from the scan"


def single_frame_generator(seq: Sequence, scored: dict[int, "FrameScore"], generator, progress: bool) -> None:
    """`generator_frame` for the scored frames whose generator input held earlier scans: the generator on
    the frame's own scan alone, the same-run yardstick for what the earlier scans and the graph add."""
    todo = [i for i, fs in scored.items() if fs.own_input is not None]
    for i in tqdm(todo, desc="score single-frame generator", unit="frame", disable=not progress or not todo):
        fs = scored[i]
        f = seq[i]
        sparse = np.zeros(f.shape, np.float32)
        rows, cols, z = fs.own_input
        sparse[rows, cols] = z
        fs.add("generator_frame", generator(EvalSample(f, sparse, sparse, "none"))[0])
        fs.own_input = None


def frame_score(seq: Sequence, ccfg: CompleteConfig, out: Path, i: int, has_lidar: bool) -> FrameScore | None:
    """Score of a frame finished before a resume: its maps read back from the PNGs at the run's scale."""
    sample = frame_sample(seq, i, ccfg, camera_only=not has_lidar)
    fs = FrameScore.of(sample)
    if fs is None:
        return None
    if has_lidar:
        fs.add("nearest", complete_depth(sample.sparse, "nearest"))
    for method, folder in PNG_FOLDER.items():
        if method != "ipbasic" or has_lidar:
            fs.add(method, read_run_depth(out, folder, i, sample.frame.shape))
    return fs


def timing_record(times: dict[int, list[float]], indices: list[int]) -> dict:
    """timing.json: per stage the mean (`generator_ms`, ...), median, p95 and max over the frames, and
    the per-frame series (to see whether a stage grows along the sequence), with each frame's wall and CPU
    time. Runs from before a figure was recorded have none for it: null in the series, left out of the stats."""
    timed = [i for i in indices if i in times]
    width = len(TIMED) + 2
    ms = np.array([list(times[i])[:width] + [np.nan] * (width - len(times[i])) for i in timed], float).reshape(
        -1, width
    )
    stages = {k: np.nan_to_num(ms[:, n]) for n, k in enumerate(TIMED)} | {
        "total_ms": np.nansum(ms[:, : len(TIMED)], axis=1),
        WALL: ms[:, len(TIMED)],
        CPU: ms[:, len(TIMED) + 1],
    }
    record: dict = {k: float(np.mean(v)) if len(v) and np.isfinite(v).all() else None for k, v in stages.items()}
    record["frames_timed"] = len(timed)
    record["stats"] = {
        k: {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
        for k, v in stages.items()
        if len(v) and np.isfinite(v).all()
    }
    record["series"] = {"frame": timed} | {
        k: [None if not np.isfinite(x) else round(float(x), 2) for x in v] for k, v in stages.items()
    }
    return record


def frame_scores(
    seq: Sequence,
    ccfg: CompleteConfig,
    indices: list[int],
    out: Path,
    has_lidar: bool,
    progress: bool,
    score: bool,
    scored: dict[int, FrameScore],
    collect: dict[int, FrameScore] | None,
) -> tuple[list[FrameScore], list[np.ndarray | None]]:
    """Every selected frame's score (none with `score=False`) and ground-truth pose; the frames this process
    did not score (finished before a resume) read back from their PNGs."""
    gt_poses, scores = [], []
    for i in tqdm(indices if score else [], desc="score", unit="frame", disable=not progress):
        gt_poses.append(seq[i].T_world_cam)
        fs = scored[i] if i in scored else frame_score(seq, ccfg, out, i, has_lidar)
        if fs is not None:
            scores.append(fs)
            if collect is not None:
                collect[i] = fs
    return scores, gt_poses


def pooled_depth(
    scores: list[FrameScore], accs: dict[str, DepthMetricAccumulator], pool: dict[str, DepthMetricAccumulator] | None
) -> set[str]:
    """Adds every frame's scored pixels to `accs` and `pool`; returns the kinds of ground truth met."""
    kinds = set()
    partial = {m for m in SCORED if 0 < sum(m in fs.pred for fs in scores) < len(scores)}
    for fs in scores:  # a method some frames lack (a resumed run's single-frame generator) is left out
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


def write_outputs(
    seq: Sequence,
    cfg: RefineConfig,
    ccfg: CompleteConfig,
    indices: list[int],
    state: Progress,
    out: Path,
    has_lidar: bool,
    progress: bool,
    pool: dict | None = None,
    score: bool = True,
    scored: dict[int, FrameScore] | None = None,
    collect: dict[int, FrameScore] | None = None,
    baselines: dict[str, tuple[np.ndarray, str]] | None = None,
    no_returns: bool = False,
) -> dict:
    """Poses in KITTI and TUM form, timing, and depth / trajectory metrics (`no_returns`: a LiDAR run in
    which no frame had a return inside its image, said in its `mode`). Depth is scored from the
    arrays the run produced (`scored`); frames finished before a resume are read back from their PNGs.
    `baselines` (name -> poses of the same frames and their alignment, "sim3" for a monocular one) are
    scored beside leovr's trajectory."""
    poses = np.stack([np.array(state.poses[i]).reshape(4, 4) for i in indices])
    stamps = seq.timestamps()[indices]
    write_kitti_poses(out / "poses_kitti.txt", poses)
    write_tum_poses(out / "poses_tum.txt", stamps, poses)
    counts = {s: list(state.sources.values()).count(s) for s in sorted(set(state.sources.values()))}
    timing = timing_record(state.times, indices)
    timing["initial_pose_sources"] = counts
    write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    accs = {m: DepthMetricAccumulator(cfg.bins) for m in SCORED}
    scores, gt_poses = frame_scores(seq, ccfg, indices, out, has_lidar, progress, score, scored or {}, collect)
    kinds = pooled_depth(scores, accs, pool)
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
        "timing": {k: v for k, v in timing.items() if k != "series"},  # the series is in timing.json
    }
    if score and all(T is not None for T in gt_poses) and len(indices) >= 3:
        metrics["trajectory"] = trajectory_record(poses, gt_poses, has_lidar, state, indices, baselines)
        plot_steps(poses, gt_poses, metrics["trajectory"], baselines, out / "step_ratio.png")
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return metrics
