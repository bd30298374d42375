"""`leovr bench refine`: IP-Basic, the generator and the refined depth, LeoVR's trajectory against
KISS-ICP's, the time per stage and a window-length ablation, on simulator test sequences (Mid-40 and
VLP-16, city loop, straight avenue and the dynamic scenario), every KITTI raw drive under ../shared/data
(simulated cheap inputs; trajectories where a drive has poses) and the KITTI odometry clip (no LiDAR: ATE after Sim(3)
alignment). Every trajectory is
scored beside the textbook monocular VO of the same frames (`mono_vo`, Sim(3)-aligned), and every ATE
carries its alignment scale (1.0 under SE(3); near 1.0 under Sim(3) when the metric scale is right)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from leovr.bench.common import depth_entry, write_bench
from leovr.bench.config import BenchRefineConfig
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.dataset import split_entries
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.paths import kitti_odometry_dir, kitti_raw_clips, shared_data_dir
from leovr.pipeline.refine import run_refine
from leovr.pipeline.refine_outputs import TIMED
from leovr.sim.dataset import Recipe, default_root, make_dataset

QUICK_RECIPE = Recipe("refine_quick", {"test": 3}, ("mid40", "vlp16"), ("day",), 8)
# generator_frame and the accumulated fills: cone LiDARs only
DEPTH_METHODS = (
    "nearest",
    "ipbasic",
    "nearest_accumulated",
    "ipbasic_accumulated",
    "generator",
    "generator_frame",
    "refined",
)
TRAJ_KEYS = ("ate_m", "rpe_m", "scale", "align", "frames")


def _traj(runs: list[dict]) -> dict:
    """Per trajectory method: mean ATE, RPE and alignment scale over the runs, and each run's."""
    out = {}
    for name in ("kiss_icp", "mono_vo", "leovr"):
        rs = [r["trajectory"][name] for r in runs if name in r.get("trajectory", {})]
        if rs:
            out[name] = {k: float(np.mean([r[k] for r in rs])) for k in ("ate_m", "rpe_m", "scale")}
            out[name]["per_sequence"] = [{k: r[k] for k in TRAJ_KEYS} for r in rs]
    return out


def run_refine_bench(out: Path, cfg: BenchRefineConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    base = RefineConfig(checkpoint=cfg.checkpoint, window=cfg.window, compare=True)
    if quick:
        root = make_dataset(QUICK_RECIPE, Path(cfg.dataset) if cfg.dataset else None, progress=progress)
    else:
        root = Path(cfg.dataset) if cfg.dataset else default_root() / "default"
    frames = cfg.quick_frames if quick else cfg.frames
    results, trajectory, timing, windows = {}, {}, {}, {}
    development: dict[str, bool] = {}  # KITTI raw drive -> whether it is development data (under ../shared/data)
    all_runs: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)

        def refine(seq_path: Path, rcfg: RefineConfig, tag: str, pool: dict | None = None) -> dict:
            seq = open_sequence(seq_path)
            end = min(len(seq), frames) if frames else None
            m = run_refine(seq, rcfg.model_copy(update={"end": end}), work / tag, progress=progress, pool=pool)
            all_runs.append(m)
            return m

        entries = [e for e in split_entries(root, "test") if e["light"] == "day"]
        for lidar in cfg.synthetic_lidars:
            pool = {m: DepthMetricAccumulator(base.bins) for m in DEPTH_METHODS}
            runs = [
                refine(e["path"], base.model_copy(update={"input": "full"}), f"{lidar}_{e['scenario']}", pool)
                for e in entries
                if e["lidar"] == lidar
            ]
            results[f"synthetic_{lidar}"] = {
                m: depth_entry({**a.result(), "ms_per_frame": None}) for m, a in pool.items() if not a.empty
            }
            for m in results[f"synthetic_{lidar}"]:
                results[f"synthetic_{lidar}"][m]["per_sequence_mae_m"] = {
                    Path(r["sequence"]).name: r["depth"][m]["mae_m"] for r in runs
                }
            trajectory[f"synthetic_{lidar}"] = _traj(runs)
        ablate = next(e for e in entries if e["lidar"] == "mid40")
        for w in cfg.windows:
            m = refine(ablate["path"], base.model_copy(update={"input": "full", "window": w}), f"window{w}")
            windows[str(w)] = {
                "refined_mae_m": m["depth"]["refined"]["mae_m"],
                "generator_mae_m": m["depth"]["generator"]["mae_m"],
                "ate_m": m["trajectory"]["leovr"]["ate_m"],
                "graph_ms": m["timing"]["graph_ms"],
            }
        shared = shared_data_dir().resolve()
        clips = [Path(c) for c in cfg.kitti_raw_clips] if cfg.kitti_raw_clips is not None else kitti_raw_clips()
        for raw in [c for c in clips if c.exists()]:
            development[raw.name] = shared in raw.resolve().parents
            for inp in cfg.kitti_inputs:
                m = refine(raw, base.model_copy(update={"input": inp}), f"{raw.name}_{inp}")
                results[f"{raw.name}_{inp}"] = {
                    k: depth_entry({**v, "ms_per_frame": None}) for k, v in m["depth"].items()
                }
                if "trajectory" in m:  # a drive with poses: leovr and KISS-ICP on the same input
                    trajectory[f"{raw.name}_{inp}"] = {
                        k: {kk: v[kk] for kk in TRAJ_KEYS} for k, v in m["trajectory"].items()
                    }
        odo = Path(cfg.kitti_odometry) if cfg.kitti_odometry else kitti_odometry_dir()
        if odo.exists():
            m = refine(odo, base, "kitti_odometry")
            trajectory["kitti_odometry"] = {
                k: {kk: m["trajectory"][k][kk] for kk in TRAJ_KEYS}
                for k in ("mono_vo", "leovr")
                if k in m["trajectory"]
            }
    for k in TIMED:
        timing[k] = float(np.mean([r["timing"][k] for r in all_runs]))
    body = {
        "quick": quick,
        "synthetic_dataset": str(root),
        "frames_per_sequence": frames,
        "window": cfg.window,
        "results": results,
        "trajectory": trajectory,
        "timing": timing,
        "kitti_raw_development": development,
        "window_ablation": {"sequence": str(ablate["path"]), "results": windows},
    }
    return write_bench(out, "refine", body, started)
