"""`leovr bench loop`: loop closure on simulator `city_loop` drives long enough to come round (Mid-40 and
VLP-16, 80 km/h so a lap fits in about 110 frames) and on the shared real clips (no revisits: every
accepted loop there is a false one). The reported laps use seeds never used for tuning (`seeds`); the
seeds the validation thresholds were tuned on run too and are reported apart (`tuning_results`).

An accepted loop is true when its measured relative pose agrees with the ground truth (translation
within 1 m, rotation within 5 degrees), false otherwise. Revisit frames are frames with a ground-truth
camera within 5 m and 30 degrees of heading at least `loop_min_gap` frames earlier; a revisit frame with
no accepted loop within 5 frames counts as missed. `ate_ideal_loops_m`: the same pose graph given the true
relative poses at the accepted loops' frame pairs, the bound for the detected loops."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from leovr.bench.common import write_bench
from leovr.bench.config import BenchLoopConfig
from leovr.config import LoopConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T, rotation_angle_deg
from leovr.paths import kitti_odometry_dir, kitti_raw_clips, shipped_vocabulary
from leovr.pipeline.refine import run_refine
from leovr.sim.simulate import simulate


TRUE_LOOP_M = 1.0  # a loop is true when its measured relative pose is within these of the ground truth
TRUE_LOOP_DEG = 5.0


def loop_error(T_j_i: np.ndarray, T_world_i: np.ndarray, T_world_j: np.ndarray) -> tuple[float, float, bool]:
    """A loop's measured relative pose (camera i seen from camera j) against the ground-truth poses:
    translation error (m), rotation error (degrees), and whether that makes it a true loop."""
    dT = invert_T(invert_T(T_world_j) @ T_world_i) @ np.asarray(T_j_i)
    err_m, err_deg = float(np.linalg.norm(dT[:3, 3])), rotation_angle_deg(dT[:3, :3])
    return err_m, err_deg, err_m < TRUE_LOOP_M and err_deg < TRUE_LOOP_DEG


def loop_truth(run: Path, gt: list[np.ndarray] | None, min_gap: int) -> dict:
    """Count true / false / missed loops of a run from its loops.json and ground-truth poses."""
    doc = json.loads((run / "loops.json").read_text())
    accepted = [r for r in doc["loops"] if r["accepted"]]
    out = {"loops_accepted": len(accepted), "ms_per_query": doc["ms_per_query"]}
    if gt is None:  # the real clips: no revisits, so any accepted loop is false
        out.update(loops_true=0, loops_false=len(accepted), loops_missed=0, revisit_frames=0)
        return out
    true, errors = 0, []
    for r in accepted:
        i, j = r["frame"], r["candidate"]
        err_m, err_deg, ok = loop_error(np.array(r["T_j_i"]), gt[i], gt[j])
        true += int(ok)
        # each accepted loop's measured relative pose against the truth: how far off a false one is
        errors.append(
            {"frame": i, "candidate": j, "error_m": round(err_m, 3), "error_deg": round(err_deg, 3), "true": ok}
        )
    pos = np.stack([T[:3, 3] for T in gt])
    fwd = np.stack([T[:3, 2] for T in gt])
    revisit = [
        i
        for i in range(len(gt))
        if any(
            np.linalg.norm(pos[i] - pos[j]) < 5.0 and fwd[i] @ fwd[j] > np.cos(np.radians(30))
            for j in range(i - min_gap + 1)
        )
    ]
    covered = {r["frame"] for r in accepted}
    missed = sum(not any(abs(i - c) <= 5 for c in covered) for i in revisit)
    out.update(
        loops_true=true,
        loops_false=len(accepted) - true,
        loops_missed=missed,
        revisit_frames=len(revisit),
        accepted_errors=errors,
    )
    return out


def ideal_loop_ate(run: Path, gt: list[np.ndarray]) -> float | None:
    """The ATE the run's pose graph reaches given the true relative poses at the accepted loops' frame pairs
    (the same poses before loop closure, the same graph): the bound the detected loops are measured against.
    None without an accepted loop."""
    from leovr.eval.trajectory import trajectory_metrics
    from leovr.pipeline.refine_outputs import Progress
    from odometry.loop.pose_graph import optimise_pose_graph

    state = Progress.load(run / "progress.json")
    indices = sorted(state.poses_no_loop)
    at = {i: n for n, i in enumerate(indices)}
    loops = [
        (at[r["frame"]], at[r["candidate"]], invert_T(gt[r["candidate"]]) @ gt[r["frame"]])
        for r in json.loads((run / "loops.json").read_text())["loops"]
        if r["accepted"] and r["frame"] in at and r["candidate"] in at
    ]
    if not loops:
        return None
    corrected = optimise_pose_graph(state.stacked("poses_no_loop", indices), loops, state.covariances(indices))
    return float(trajectory_metrics(corrected, np.stack([gt[i] for i in indices]))["ate_m"])


def vocabulary_note() -> dict:
    """How the shipped vocabulary was trained (its JSON note), so the report says what it has seen."""
    note = shipped_vocabulary().with_suffix(".json")
    if not note.exists():
        return {}
    doc = json.loads(note.read_text())
    return {k: doc[k] for k in ("command", "images", "words", "real_clips_seen") if k in doc}


def run_loop_bench(out: Path, cfg: BenchLoopConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    results, tuning = {}, {}
    frames = cfg.quick_frames if quick else cfg.frames
    seeds = cfg.seeds[:1] if quick else cfg.seeds
    base = RefineConfig(input="full", loop=LoopConfig(enabled=True, min_gap=cfg.loop_min_gap))
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)

        def one(seq, rcfg: RefineConfig, tag: str) -> dict:
            m = run_refine(seq, rcfg, work / tag, progress=progress)
            gt = [seq[i].T_world_cam for i in range(m["frames"])]
            gt = gt if all(T is not None for T in gt) else None
            r = loop_truth(work / tag, gt, rcfg.loop.min_gap)
            t = m.get("trajectory", {})
            if "leovr" in t:
                r["ate_loop_m"] = t["leovr"]["ate_m"]
                r["ate_no_loop_m"] = t.get("leovr_no_loop", t["leovr"])["ate_m"]
                if gt is not None and (ideal := ideal_loop_ate(work / tag, gt)) is not None:
                    r["ate_ideal_loops_m"] = ideal
            return r

        def lap(lidar: str, seed: int) -> dict:
            sim = SimulateConfig(scenario="city_loop", lidar=lidar, frames=frames, seed=seed, speed_kmh=cfg.speed_kmh)
            simulate(sim, work / f"seq_{lidar}_{seed}", progress=progress)
            return one(open_sequence(work / f"seq_{lidar}_{seed}"), base, f"{lidar}_{seed}")

        for lidar in cfg.lidars:
            for seed in seeds:
                results[f"synthetic_{lidar}_s{seed}"] = lap(lidar, seed)
            for seed in [] if quick else cfg.tuning_seeds:
                tuning[f"synthetic_{lidar}_s{seed}"] = lap(lidar, seed)
        for raw in [Path(cfg.kitti_raw)] if cfg.kitti_raw else kitti_raw_clips():  # every shared drive
            if raw.exists():
                vlp16 = base.model_copy(update={"input": "vlp16"})
                results[f"{raw.name}_vlp16"] = one(open_sequence(raw), vlp16, raw.name)
        odo = Path(cfg.kitti_odometry) if cfg.kitti_odometry else kitti_odometry_dir()
        if odo.exists():
            results["kitti_odometry"] = one(open_sequence(odo), base, "kitti_odometry")
    body = {
        "quick": quick,
        "frames_per_synthetic_sequence": frames,
        "speed_kmh": cfg.speed_kmh,
        "loop_min_gap": cfg.loop_min_gap,
        "seeds": seeds,
        "results": results,
        "tuning_seeds": [] if quick else cfg.tuning_seeds,
        "tuning_results": tuning,
        "vocabulary": vocabulary_note(),
    }
    return write_bench(out, "loop", body, started)
