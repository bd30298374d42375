#!/usr/bin/env python3
"""The fixed cost of one `leovr batch` command on a local Ray instance, measured apart from the work:
starting Ray (1 CPU), a first task that imports leovr's refinement and loads the shipped generator
(what every fresh worker pays), and shutting Ray down. With --idle, also the CPU time that an idle
local Ray instance (2 CPUs, two finished workers) takes over 20 s; with --task DRIVE, the CPU and wall
time of one refine task run in this process with one thread (as `leovr batch` runs it), to tell a
task that uses more than one core from two tasks slowing each other.

    .venv/bin/python tools/ray_overhead.py [--idle] [--task DRIVE]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from leovr.pipeline.batch import LOCAL_SYSTEM_CONFIG


def first_task() -> float:
    t = time.perf_counter()
    import gtsam  # noqa: F401
    import torch  # noqa: F401

    import leovr.pipeline.refine  # noqa: F401
    import odometry.frontend  # noqa: F401
    import odometry.window_graph  # noqa: F401
    from leovr.depth.inference import load_generator
    from leovr.paths import shipped_checkpoint

    load_generator(shipped_checkpoint())
    return time.perf_counter() - t


def _ray_cpu_seconds() -> float:
    """CPU seconds used so far by this process and every process of the local Ray instance."""
    import psutil  # installed with rerun-sdk

    total = 0.0
    for p in psutil.process_iter(["pid", "cmdline"]):
        try:
            if p.pid == os.getpid() or "ray" in " ".join(p.info["cmdline"] or []):
                t = p.cpu_times()
                total += t.user + t.system
        except psutil.Error:
            pass
    return total


def _pid() -> int:
    return os.getpid()


def idle_cpu(seconds: float = 20.0) -> float:
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
             _system_config=LOCAL_SYSTEM_CONFIG)
    ray.get([ray.remote(_pid).remote() for _ in range(2)])
    time.sleep(3)
    a = _ray_cpu_seconds()
    time.sleep(seconds)
    used = _ray_cpu_seconds() - a
    ray.shutdown()
    return used


def task_cpu(drive: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one refine task on `drive`, one thread, default settings."""
    from leovr.config import LeovrConfig
    from leovr.pipeline.batch import job_section, run_sequence, task_settings
    from leovr.pipeline.batch_manifest import read_batch

    it = read_batch(drive)[0]
    sec = job_section(LeovrConfig(), "refine", it)
    out = Path(tempfile.mkdtemp())
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.time()
    run_sequence(it, "refine", sec, out, 1, task_settings("refine", sec, it.path))
    r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.time()
    shutil.rmtree(out, ignore_errors=True)
    return t1 - t0, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--idle", action="store_true")
    ap.add_argument("--task", type=Path, default=None)
    a = ap.parse_args()
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    t0 = time.perf_counter()
    import ray

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False,
             _system_config=LOCAL_SYSTEM_CONFIG)  # as `leovr batch` starts it
    t1 = time.perf_counter()
    inside = ray.get(ray.remote(first_task).remote())
    t2 = time.perf_counter()
    ray.shutdown()
    t3 = time.perf_counter()
    print(f"start {t1 - t0:.1f} s, first task {t2 - t1:.1f} s (imports and generator in the worker {inside:.1f} s), "
          f"shutdown {t3 - t2:.1f} s")
    if a.idle:
        print(f"idle local Ray instance: {idle_cpu():.2f} CPU s in 20 s")
    if a.task is not None:
        wall, cpu = task_cpu(a.task)
        print(f"one refine task, one thread: {wall:.1f} s wall, {cpu:.1f} s CPU")


if __name__ == "__main__":
    main()
