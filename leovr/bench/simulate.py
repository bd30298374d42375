"""`leovr bench simulate`: rendering speed of camera + depth + LiDAR per frame."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from leovr.bench.common import write_bench
from leovr.bench.config import BenchSimulateConfig
from leovr.config import SimulateConfig
from leovr.sim.simulate import simulate


def run_simulate_bench(out: Path, cfg: BenchSimulateConfig, progress: bool = True) -> dict:
    """Frames per second for each LiDAR model (writing included); the first LiDAR fills the top-level keys."""
    started = time.time()
    per = {}
    for lidar in cfg.lidars:
        sim = SimulateConfig(lidar=lidar, frames=cfg.frames)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            r = simulate(sim, Path(tmp) / "seq", progress=progress)
            wall = time.perf_counter() - t0
        per[lidar] = {
            "frames_per_s": r["frames_per_s"],
            "render_s_per_frame": r["s_per_frame"],
            "wall_s_per_frame_with_writing": wall / cfg.frames,
            "frames": cfg.frames,
        }
    first = cfg.lidars[0]
    body = {
        "frames_per_s": per[first]["frames_per_s"],
        "width": sim.width,
        "height": sim.height,
        "lidar": first,
        "scenario": sim.scenario,
        "per_lidar": per,
    }
    return write_bench(out, "simulate", body, started)
