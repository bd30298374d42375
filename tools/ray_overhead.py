#!/usr/bin/env python3
"""The fixed cost of one `leovr batch` command on a local Ray instance, measured apart from the work:
starting Ray (1 CPU), a first task that imports leovr's refinement and loads the shipped generator
(what every fresh worker pays), and shutting Ray down.

    .venv/bin/python tools/ray_overhead.py
"""

from __future__ import annotations

import os
import time


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


def main() -> None:
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    t0 = time.perf_counter()
    import ray

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
    t1 = time.perf_counter()
    inside = ray.get(ray.remote(first_task).remote())
    t2 = time.perf_counter()
    ray.shutdown()
    t3 = time.perf_counter()
    print(f"start {t1 - t0:.1f} s, first task {t2 - t1:.1f} s (imports and generator in the worker {inside:.1f} s), "
          f"shutdown {t3 - t2:.1f} s")


if __name__ == "__main__":
    main()
