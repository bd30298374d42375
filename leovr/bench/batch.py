"""`leovr bench batch`: wall time of `leovr batch` (refine job) with 1 and with 2 workers on the same
rendered sequences, each task holding one CPU and one thread. Wall time is end to end, as a user sees it:
starting the local Ray instance, every task, and the summary. The sequences (a seed used for nothing
else) are rendered once into `<stem>_work/drives`; each timed run starts from an empty output folder."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from leovr.bench.common import write_bench
from leovr.bench.config import BenchBatchConfig
from leovr.config import LeovrConfig, SimulateConfig
from leovr.pipeline.batch import run_batch
from leovr.pipeline.batch_manifest import read_batch
from leovr.sim.simulate import simulate


def run_batch_bench(out: Path, bcfg: BenchBatchConfig, progress: bool = True) -> dict:
    """Both timed runs of `leovr batch` on the product's default settings (configs/default.yaml)."""
    started = time.time()
    cfg = LeovrConfig()
    work = Path(out).with_name(Path(out).stem + "_work")
    drives = work / "drives"
    for n in range(bcfg.sequences):
        d = drives / f"drive{n}"
        if not (d / "sequence.yaml").is_file():
            simulate(
                SimulateConfig(scenario="city_loop", lidar=bcfg.lidar, frames=bcfg.frames, seed=bcfg.seed + n),
                d,
                progress=False,
            )
    items = read_batch(drives)
    wall: dict[str, float] = {}
    task_s: dict[str, float] = {}
    for workers in (1, 2):
        run = work / f"workers{workers}"
        shutil.rmtree(run, ignore_errors=True)
        c = cfg.model_copy(deep=True)
        c.batch.job, c.batch.workers, c.batch.cpus_per_task, c.batch.address = "refine", workers, 1, None
        t0 = time.perf_counter()
        rows = run_batch(items, c, run, progress=progress)
        wall[str(workers)] = round(time.perf_counter() - t0, 2)
        task_s[str(workers)] = round(sum(float(r.get("wall_s") or 0) for r in rows), 2)
        failed = [r for r in rows if r["status"] != "done"]
        if failed:
            raise RuntimeError(f"bench batch: {len(failed)} sequence(s) failed: {failed[0].get('error')}")
    frames = bcfg.sequences * bcfg.frames
    speedup = wall["1"] / wall["2"]
    body = {
        "sequences": bcfg.sequences,
        "frames": frames,
        "wall_s": wall,
        "task_s_sum": task_s,  # the tasks' own time, summed: above wall x workers means tasks slowed each other
        "speedup": round(speedup, 3),
        # what the machine allowed in this run: two tasks at once each ran `task_slowdown` x slower than
        # alone (both CPU-bound, one thread each), so a scheduler with no cost of its own would have reached
        # `ceiling_speedup`; `fixed_s` is the rest of each wall time (Ray's start and stop, idle workers)
        "task_slowdown": round(task_s["2"] / task_s["1"], 3),
        "ceiling_speedup": round(2.0 * task_s["1"] / task_s["2"], 3),
        "fixed_s": {"1": round(wall["1"] - task_s["1"], 2), "2": round(wall["2"] - task_s["2"] / 2, 2)},
        "frames_per_core_hour": round(frames * 3600.0 / (2 * wall["2"]), 1),  # 2 workers, one core each
        "settings": {
            "lidar": bcfg.lidar,
            "frames_per_sequence": bcfg.frames,
            "seed": bcfg.seed,
            "cpus_per_task": 1,
            "refine": "defaults (configs/default.yaml)",
        },
        "target_speedup": bcfg.target_speedup,
        "targets_met": {"speedup": bool(speedup >= bcfg.target_speedup)},
    }
    return write_bench(out, "batch", body, started)
