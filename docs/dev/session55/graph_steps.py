#!/usr/bin/env python3
"""Per-frame breakdown of the window graph's update on a development drive, run sequentially (one thread, so
nothing else shares the core): the update's time, gtsam's iterations and linear solves ("intermediate steps"),
and the problem's size (observations, new landmarks, values). Session 55 found the slowest updates are those
whose third Levenberg-Marquardt iteration fails and is solved again at higher damping.

    .venv/bin/python docs/dev/session55/graph_steps.py DRIVE OUT.json [RefineConfig field=value ...]

The drive of session 55: `leovr simulate --scenario city_loop --lidar mid40 --frames 200 --seed 2100 --out DRIVE`
(a seed used for nothing else; the bench speed drive is seed 3200).
"""

from __future__ import annotations

import ast
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)  # refine then runs the generator in the main thread: no overlap

import odometry.window_graph as wg  # noqa: E402
from leovr.config import RefineConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402

ROWS: list[dict] = []


class TimedSmoother:
    """The smoother, with each update's time, iterations and solves kept for the frame being added."""

    def __init__(self, smoother) -> None:
        self.smoother, self.last = smoother, {}

    def __getattr__(self, name):
        return getattr(self.smoother, name)

    def update(self, *args):
        t0 = time.perf_counter()
        result = self.smoother.update(*args)
        self.last = {"update_ms": 1000 * (time.perf_counter() - t0), "iterations": result.getIterations(),
                     "solves": result.getIntermediateSteps()}
        return result


def main() -> None:
    drive, out, *fields = sys.argv[1:]
    cfg = RefineConfig(**{k: ast.literal_eval(v) for k, v in (f.split("=", 1) for f in fields)})
    post, add = wg.WindowGraph.__post_init__, wg.WindowGraph.add_frame

    def post_init(self) -> None:
        post(self)
        self.smoother = TimedSmoother(self.smoother)

    def add_frame(self, f):
        t0 = time.perf_counter()
        done = add(self, f)
        ROWS.append({"frame": f.index, "total_ms": 1000 * (time.perf_counter() - t0), **self.smoother.last,
                     "observations": len(f.observations), "new_landmarks": len(f.new_landmarks),
                     "values": self.smoother.getLinearizationPoint().size()})
        return done

    wg.WindowGraph.__post_init__, wg.WindowGraph.add_frame = post_init, add_frame
    with tempfile.TemporaryDirectory() as tmp:
        m = run_refine(open_sequence(Path(drive)), cfg, Path(tmp) / "run", progress=False)
    Path(out).write_text(json.dumps(ROWS))
    total = np.array([r["total_ms"] for r in ROWS])
    solves = np.array([r["solves"] for r in ROWS])
    print(f"graph update ms median {np.median(total):.1f} p95 {np.percentile(total, 95):.1f} "
          f"p95/median {np.percentile(total, 95) / np.median(total):.3f}; refined MAE {m['depth']['refined']['mae_m']:.4f} "
          f"ATE {m['trajectory']['leovr']['ate_m']:.4f}")
    for k, n in sorted(collections.Counter(solves.tolist()).items()):
        print(f"  {n:4d} updates with {k} solves: median {np.median(total[solves == k]):.1f} ms")
    for key in ("observations", "new_landmarks", "values"):
        v = np.array([r[key] for r in ROWS], float)
        print(f"  {key}: median {np.median(v):.0f}, correlation with the update's time {np.corrcoef(v[10:], total[10:])[0, 1]:.2f}")


if __name__ == "__main__":
    main()
