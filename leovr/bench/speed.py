"""`leovr bench speed`: where `leovr refine` spends its time per frame, and whether the cost stays flat.

Runs with the default refine settings: a rendered drive (448 x 256, 200 frames, a seed used for nothing else)
and each real KITTI raw clip with each input (its own scan, VLP-16-like, Mid-40-like, camera only). Per stage
(generator, front end, graph, output, their sum, the frame's wall time and the process's CPU time, every thread)
the median, p95 and max milliseconds per frame from the run's own timing.json; end-to-end frames per second,
both from the stage sum and from the run's wall clock (reading, scoring and writing included); each stage's
growth along the drive (median over the last quarter of the frames over the median of the second quarter);
the refined MAE and ATE of the same run, so that speed is never quoted without its accuracy; and IP-Basic's
milliseconds per frame on the same frames' input, the yard stick for how fast this machine is at the time."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from leovr.bench.common import write_bench
from leovr.bench.config import BenchSpeedConfig
from leovr.config import RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.depth.fills import complete_depth
from leovr.paths import kitti_raw_clips
from leovr.pipeline.refine import run_refine
from leovr.pipeline.refine_input import completion_config, frame_sample
from leovr.pipeline.refine_outputs import CPU, TIMED, WALL
from leovr.sim.simulate import simulate

STAGES = (*TIMED, "total_ms", WALL, CPU)


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
    return float(np.median(series[-q:]) / max(np.median(series[q : 2 * q]), 1e-9))


def speed_record(seq, rcfg: RefineConfig, run: Path, progress: bool) -> dict:
    """Refine `seq` into `run` and report its time per stage, frame rate, growth and accuracy."""
    t0 = time.perf_counter()
    metrics = run_refine(seq, rcfg, run, progress=progress)
    wall = time.perf_counter() - t0
    timing = json.loads((run / "timing.json").read_text())
    stats = {k: {s: round(v, 2) for s, v in timing["stats"][k].items()} for k in STAGES if k in timing["stats"]}
    frames = timing["series"]["frame"]
    median_total = stats["total_ms"]["median"]
    rec = {
        "frames": len(frames),
        "width": int(seq[0].shape[1]),
        "height": int(seq[0].shape[0]),
        "input": rcfg.input,
        "ms_per_frame": stats,
        "fps_stages": round(1000.0 / median_total, 3),  # from the median of the stage sum (a sequential run)
        "fps_frame_wall": round(1000.0 / stats[WALL]["median"], 3),  # the generator overlapping the graph
        "fps_wall": round(metrics["frames"] / wall, 3),  # reading, scoring and writing included
        "wall_s": round(wall, 2),
        "p95_over_median": {k: round(v["p95"] / max(v["median"], 1e-9), 3) for k, v in stats.items()},
        "growth": {k: (round(g, 3) if (g := growth(timing["series"][k])) is not None else None) for k in stats},
        "ipbasic_ms_per_frame": round(ipbasic_ms(seq, rcfg, frames), 2),
    }
    rec["total_over_ipbasic"] = round(median_total / max(rec["ipbasic_ms_per_frame"], 1e-9), 1)
    rec["wall_over_ipbasic"] = round(stats[WALL]["median"] / max(rec["ipbasic_ms_per_frame"], 1e-9), 1)
    depth = metrics.get("depth", {})
    rec["mae_m"] = {
        m: round(depth[m]["mae_m"], 4) for m in ("nearest", "generator", "generator_frame", "refined") if m in depth
    }
    traj = metrics.get("trajectory", {})
    rec["ate_m"] = {m: round(t["ate_m"], 4) for m, t in traj.items()}
    return rec


def run_speed_bench(out: Path, cfg: BenchSpeedConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    frames = cfg.quick_frames if quick else cfg.frames
    results: dict[str, dict] = {}
    base = RefineConfig(generator_runtime=cfg.generator_runtime)
    clips = [Path(c) for c in cfg.clips] if cfg.clips is not None else kitti_raw_clips()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        sim = SimulateConfig(scenario=cfg.scenario, lidar=cfg.lidar, frames=frames, seed=cfg.seed)
        simulate(sim, work / "drive", progress=progress)
        key = f"synthetic_{cfg.lidar}_{sim.width}x{sim.height}"
        results[key] = speed_record(open_sequence(work / "drive"), base, work / "run_synthetic", progress)
        for clip in clips:
            seq = open_sequence(clip)
            for inp in cfg.real_inputs:
                rcfg = base.model_copy(update={"input": inp, "end": cfg.quick_frames if quick else None})
                results[f"{clip.name}_{inp}"] = speed_record(seq, rcfg, work / f"run_{clip.name}_{inp}", progress)
    # end to end: a frame's time on the run's clock (wall_ms), the generator overlapping the graph
    wall = {k: r["ms_per_frame"][WALL]["median"] for k, r in results.items()}
    targets = {f"{key}_wall_median_ms<={cfg.target_ms_448:g}": wall[key] <= cfg.target_ms_448}
    for stage in STAGES:
        ratio = results[key]["p95_over_median"].get(stage)
        if ratio is not None and stage != CPU:
            targets[f"{key}_{stage}_p95/median<={cfg.target_p95_over_median:g}"] = ratio <= cfg.target_p95_over_median
    for k, r in results.items():
        limit = cfg.target_ms_real.get(r["input"]) if k != key else None
        if limit is not None:
            targets[f"{k}_wall_median_ms<={limit:g}"] = wall[k] <= limit
    body = {
        "quick": quick,
        "scenario": cfg.scenario,
        "seed": cfg.seed,
        "generator_runtime": cfg.generator_runtime,
        "clips": [str(c) for c in clips],
        "results": results,
        "targets_met": targets,
    }
    return write_bench(out, "speed", body, started)
