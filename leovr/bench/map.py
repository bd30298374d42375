"""`leovr bench map`: maps of each real drive fused from leovr's refined depth, from the nearest fill of the same
cheap input, and the cheap input's own returns accumulated, scored on the held-out returns no method saw.

Per clip and cheap input (simulated from the drive's HDL-64 scan): `leovr refine` runs over the clip; its
refined depth and uncertainty, and the nearest fill of the very same cheap input, are each fused into a TSDF
map with the run's poses (`leovr.pipeline.tsdf_map`); the cheap returns themselves, placed with the same poses,
are the third map. The held-out returns of every frame (the pixels `refine` scores), placed in the world with
the ground-truth poses where the drive has them (rigidly aligned to the run's trajectory, as for the ATE; else the
run's poses), within the maps' reach are the truth: accuracy is their mean
distance to a map where it covers them (within 1 m), completeness the share within 0.2 m. The refined map is
also fused at several uncertainty thresholds, which chose the default (`map.sigma_max`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from leovr.bench.common import write_bench
from leovr.bench.real import prepared_work
from leovr.bench.config import BenchMapConfig
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.data.kitti_common import read_kitti_poses
from leovr.data.run_info import run_frame_png
from leovr.depth.fills import complete_depth
from leovr.errors import DataError
from leovr.eval.map_metrics import COVER_M, NEAR_M, distances_to_mesh, distances_to_points, map_scores
from leovr.geometry import back_project, transform_points
from leovr.pipeline.refine import run_refine
from leovr.pipeline.refine_input import completion_config, frame_sample
from leovr.pipeline.refine_metrics import FrameScore
from leovr.pipeline.tsdf_map import SIGMA_SCALE, TsdfMap, map_depth, peak_memory_mb
from odometry.loop.validate import umeyama


def run_map_bench(out: Path, cfg: BenchMapConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    from leovr.paths import kitti_raw_clips, shared_data_dir

    clips = [Path(c) for c in cfg.clips] if cfg.clips else kitti_raw_clips()
    if not clips:
        raise DataError(
            shared_data_dir(), "no KITTI raw drive found (set LEOVR_SHARED_DATA or `map.clips` in the bench config)"
        )
    settings = {**cfg.model_dump(), "quick": quick, "clips": [str(c) for c in clips]}
    work = Path(out).with_name(Path(out).stem + "_work")
    prepared_work(work, settings)
    shared = shared_data_dir().resolve()
    results, summary = {}, {}
    for clip in clips:
        seq = open_sequence(clip)
        n = min(len(seq), cfg.quick_frames) if quick else len(seq)
        for inp in cfg.inputs:
            key = f"{clip.name}_{inp}"
            entry = clip_map(seq, n, inp, cfg, work / key, progress)
            entry["development"] = shared in clip.resolve().parents
            results[key] = entry
            summary[key] = summary_of(entry)
    body = {"quick": quick, "near_m": NEAR_M, "cover_m": COVER_M, "results": results, "summary": summary}
    return write_bench(out, "map", body, started)


def summary_of(entry: dict) -> dict:
    """The headline ratios: the nearest-fill map's mean distance over the refined map's (accuracy, > 1 = the
    refined map is better), and completeness against the accumulated cheap returns and the nearest fill."""
    maps = entry["maps"]
    ref, near, acc = maps["refined"], maps["nearest"], maps["accumulated"]

    def ratio(a: float | None, b: float | None) -> float | None:
        return None if a is None or not b else round(a / b, 3)

    return {
        "accuracy_vs_nearest": ratio(near["accuracy_m"], ref["accuracy_m"]),
        "completeness_vs_accumulated": ratio(ref["completeness"], acc["completeness"]),
        "completeness_vs_nearest": ratio(ref["completeness"], near["completeness"]),
    }


def clip_map(seq, n: int, inp: str, cfg: BenchMapConfig, work: Path, progress: bool) -> dict:
    """One clip and input: refine, then the maps and their scores."""
    rcfg = RefineConfig(input=inp, end=n)
    frames: dict[int, FrameScore] = {}
    run_refine(seq, rcfg, work, progress=progress, collect=frames)
    poses = read_kitti_poses(work / "poses_kitti.txt")
    frame_dt = float(np.median(np.diff(seq.timestamps()[:n])))
    truth = heldout_world_points(seq, frames, poses, cfg.map.max_depth_m)
    settings = cfg.map.model_copy(update={"sigma_max": None})
    thresholds = sorted({None, cfg.map.sigma_max, *cfg.sigma_max_sweep}, key=lambda t: -1 if t is None else t)
    refined = {t: TsdfMap(cfg.map.model_copy(update={"sigma_max": t})) for t in thresholds}
    nearest, accumulated = TsdfMap(settings), []
    ccfg = completion_config(rcfg)
    t_fuse = 0.0
    for i in range(n):
        frame = seq[i]
        motion = np.linalg.inv(poses[i]) @ poses[i + 1] if i + 1 < n else None
        sample = frame_sample(seq, i, ccfg, motion, frame_dt, frame=frame)
        depth = read_depth_png(run_frame_png(work, "depth", i), shape=frame.shape)
        sigma = read_depth_png(run_frame_png(work, "sigma", i), SIGMA_SCALE, shape=frame.shape)
        t0 = time.perf_counter()
        for t, vol in refined.items():
            vol.add(frame.image, map_depth(depth, sigma, vol.s, float(frame.K[0, 0])), frame.K, poses[i])
        t_fuse += (time.perf_counter() - t0) / len(refined)
        nearest.add(
            frame.image,
            map_depth(complete_depth(sample.sparse, "nearest"), None, settings, float(frame.K[0, 0])),
            frame.K,
            poses[i],
        )
        v, u = np.nonzero((sample.sparse > 0) & (sample.sparse <= cfg.map.max_depth_m))
        cam = back_project(np.stack([u, v], 1).astype(float), sample.sparse[v, u].astype(float), frame.K)
        accumulated.append(transform_points(poses[i], cam))
    maps = {
        f"refined_sigma_{'all' if t is None else t}": map_scores(distances_to_mesh(vol.mesh(), truth))
        for t, vol in refined.items()
    }
    default = cfg.map.sigma_max
    maps["refined"] = maps[f"refined_sigma_{'all' if default is None else default}"]
    maps["nearest"] = map_scores(distances_to_mesh(nearest.mesh(), truth))
    maps["accumulated"] = map_scores(distances_to_points(np.concatenate(accumulated), truth))
    truth_poses = "ground truth (rigidly aligned to the run's)" if seq.has_poses else "run"
    return {
        "frames": n,
        "input": inp,
        "truth_points": len(truth),
        "poses": truth_poses,
        "maps": maps,
        "seconds_per_frame": round(t_fuse / n, 4),
        "peak_memory_mb": round(peak_memory_mb(), 1),
        "blocks": refined[default].blocks,
    }


def camera_marks(poses: np.ndarray, reach_m: float = 10.0) -> np.ndarray:
    """Each camera's centre and the points `reach_m` along its three axes (F x 4 x 4 -> 4F x 3): a rigid fit to them
    aligns the cameras' orientation too, which the centres of a nearly straight drive leave open (the roll about it)."""
    centres = poses[:, :3, 3]
    return np.concatenate([centres] + [centres + reach_m * poses[:, :3, k] for k in range(3)])


def heldout_world_points(seq, frames: dict[int, FrameScore], run_poses: np.ndarray, max_depth_m: float) -> np.ndarray:
    """Every scored held-out return within the maps' reach (`max_depth_m` from its camera) in the run's world: placed
    with the ground-truth poses where the clip has them, moved onto the run's trajectory by the rigid fit of the
    ground-truth cameras to the run's (as the ATE aligns: the maps are scored on their shape, not on the frame the
    run's first pose set); else with the run's poses."""
    out, K, idx = [], seq[0].K, sorted(frames)
    if seq.has_poses and idx:
        truth = np.stack([seq.pose(i) for i in idx])
        placed = np.einsum("ij,fjk->fik", umeyama(camera_marks(truth), camera_marks(run_poses[idx])), truth)
    else:
        placed = run_poses[idx]
    for T, i in zip(placed, idx):
        fs = frames[i]
        near = fs.gt <= max_depth_m
        rows, cols = fs.pick[0][near], fs.pick[1][near]
        cam = back_project(np.stack([cols, rows], 1).astype(float), fs.gt[near].astype(float), K)
        out.append(transform_points(T, cam))
    return np.concatenate(out) if out else np.zeros((0, 3))
