"""`leovr bench speed`: where `leovr refine` spends its time per frame, and whether the cost stays flat.

Two runs with the default refine settings: a rendered drive (448 x 256, 200 frames, a seed used for
nothing else) and the shared KITTI raw clip with VLP-16-like input. Per stage (generator, front end,
graph, and their sum) the median, p95 and max milliseconds per frame from the run's own timing.json;
end-to-end frames per second, both from the stage sum and from the run's wall clock (reading, scoring
and writing included); the graph's growth along the drive (median over the last quarter of the frames
over the median of the second quarter, when the window is full); the refined MAE and ATE of the same
run, so that speed is never quoted without its accuracy; and IP-Basic's milliseconds per frame on the
same frames' input, the yard stick for how fast this machine is at the time of the run."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from leovr.bench.common import write_bench
from leovr.config import BenchSpeedConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.depth.classical import complete_depth
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import TIMED, WALL, completion_config, frame_sample, run_refine
from leovr.sim.simulate import simulate

STAGES = (*TIMED, "total_ms", WALL)


def ipbasic_ms(seq, rcfg: RefineConfig, frames: list[int]) -> float:
    """Median IP-Basic time (ms) on the cheap input of `frames`; preparing the input is not timed."""
    ccfg = completion_config(rcfg)
    ms = []
    for i in frames:
        sparse = frame_sample(seq, i, ccfg).sparse
        t0 = time.perf_counter()
        complete_depth(sparse, "ipbasic")
        ms.append(1000.0 * (time.perf_counter() - t0))
    return float(np.median(ms))


def growth(series: list[float]) -> float | None:
    """Median of the last quarter of a per-frame series over the median of its second quarter: 1.0
    for a flat cost, above 1 for one that grows along the drive."""
    n = len(series)
    if n < 8:
        return None
    q = n // 4
    return float(np.median(series[-q:]) / max(np.median(series[q:2 * q]), 1e-9))


def speed_record(seq, rcfg: RefineConfig, run: Path, progress: bool) -> dict:
    """Refine `seq` into `run` and report its time per stage, frame rate, growth and accuracy."""
    t0 = time.perf_counter()
    metrics = run_refine(seq, rcfg, run, progress=progress)
    wall = time.perf_counter() - t0
    timing = json.loads((run / "timing.json").read_text())
    stats = {k: {s: round(v, 2) for s, v in timing["stats"][k].items()} for k in STAGES}
    frames = timing["series"]["frame"]
    median_total = stats["total_ms"]["median"]
    rec = {
        "frames": len(frames), "width": int(seq[0].shape[1]), "height": int(seq[0].shape[0]), "input": rcfg.input,
        "ms_per_frame": stats,
        "fps_stages": round(1000.0 / median_total, 3),  # from the median of the stage sum (a sequential run)
        "fps_frame_wall": round(1000.0 / stats[WALL]["median"], 3),  # the generator overlapping the graph
        "fps_wall": round(metrics["frames"] / wall, 3),  # reading, scoring and writing included
        "wall_s": round(wall, 2),
        "graph_p95_over_median": round(stats["graph_ms"]["p95"] / max(stats["graph_ms"]["median"], 1e-9), 3),
        "growth": {k: (round(g, 3) if (g := growth(timing["series"][k])) is not None else None) for k in STAGES},
        "ipbasic_ms_per_frame": round(ipbasic_ms(seq, rcfg, frames), 2),
    }
    rec["total_over_ipbasic"] = round(median_total / max(rec["ipbasic_ms_per_frame"], 1e-9), 1)
    rec["wall_over_ipbasic"] = round(stats[WALL]["median"] / max(rec["ipbasic_ms_per_frame"], 1e-9), 1)
    depth = metrics.get("depth", {})
    rec["mae_m"] = {m: round(depth[m]["mae_m"], 4) for m in ("nearest", "generator", "generator_frame", "refined") if m in depth}
    traj = metrics.get("trajectory", {})
    rec["ate_m"] = {m: round(t["ate_m"], 4) for m, t in traj.items()}
    return rec


def run_speed_bench(out: Path, cfg: BenchSpeedConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    frames = cfg.quick_frames if quick else cfg.frames
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        sim = SimulateConfig(scenario=cfg.scenario, lidar=cfg.lidar, frames=frames, seed=cfg.seed)
        simulate(sim, work / "drive", progress=progress)
        key = f"synthetic_{cfg.lidar}_{sim.width}x{sim.height}"
        base = RefineConfig(generator_runtime=cfg.generator_runtime)
        results[key] = speed_record(open_sequence(work / "drive"), base, work / "run_synthetic", progress)
        raw = Path(cfg.kitti_raw) if cfg.kitti_raw else kitti_raw_dir()
        if raw.exists():
            rcfg = base.model_copy(update={"input": cfg.kitti_input, "end": cfg.quick_frames if quick else None})
            results[f"kitti_raw_{cfg.kitti_input}"] = speed_record(open_sequence(raw), rcfg, work / "run_kitti", progress)
    # end to end: a frame's time on the run's clock (wall_ms), the generator overlapping the graph
    targets = {f"{key}_wall_median_ms<={cfg.target_ms_448:g}":
               results[key]["ms_per_frame"][WALL]["median"] <= cfg.target_ms_448,
               f"{key}_graph_p95/median<={cfg.target_graph_p95_over_median:g}":
               results[key]["graph_p95_over_median"] <= cfg.target_graph_p95_over_median}
    kitti = f"kitti_raw_{cfg.kitti_input}"
    if kitti in results:
        targets[f"{kitti}_wall_median_ms<={cfg.target_ms_kitti:g}"] = (
            results[kitti]["ms_per_frame"][WALL]["median"] <= cfg.target_ms_kitti)
    body = {"quick": quick, "scenario": cfg.scenario, "seed": cfg.seed, "generator_runtime": cfg.generator_runtime,
            "results": results, "targets_met": targets}
    return write_bench(out, "speed", body, started)
