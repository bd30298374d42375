"""Session 54 development check (issue 16): how one frame's pose evolves through the window graph on a *tuning* lap
(or a validation drive): its initial pose (the front end's) as a step from the previous frame's current estimate, and
that step after every window update while the frame is in the window, against the truth.

    .venv/bin/python docs/dev/session54/trace_steps.py SEQ --end N --frames 111 112 [--cfg '{"pair_factors": false}']
        [--cv 112]   (frame 112's initial pose forced to constant velocity)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import odometry.window_graph as wg  # noqa: E402
from leovr.config import RefineConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T, rotation_angle_deg as ang  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence")
    ap.add_argument("--end", type=int, required=True)
    ap.add_argument("--frames", type=int, nargs="+", required=True)
    ap.add_argument("--cfg", default="{}")
    ap.add_argument("--cv", type=int, nargs="*", default=[], help="frames whose initial pose is forced to constant velocity")
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    gt = {i: seq[i].T_world_cam for i in range(len(seq))}
    watch = set(a.frames)
    add = wg.WindowGraph.add_frame

    def fmt(i: int, T_prev: np.ndarray, T: np.ndarray) -> str:
        d, t = invert_T(T_prev) @ T, invert_T(gt[i - 1]) @ gt[i]
        e = invert_T(t) @ d
        return f"step {np.round(d[:3, 3], 2)} (true {np.round(t[:3, 3], 2)}) err {np.linalg.norm(e[:3, 3]):.2f} m {ang(e[:3, :3]):.2f} deg"

    def traced(self, f):
        if f.index in watch and f.index - 1 in self.poses:
            print(f"frame {f.index} init:   {fmt(f.index, self.poses[f.index - 1], f.T_init)}", flush=True)
        out = add(self, f)
        for i in sorted(watch):
            if i in self.poses and i - 1 in self.poses:
                print(f"  after adding {f.index}: frame {i} {fmt(i, self.poses[i - 1], self.poses[i])}", flush=True)
        return out

    wg.WindowGraph.add_frame = traced
    import odometry.frontend as fe
    process, choose = fe.FrontEnd.process, fe.choose_pose
    now = {}

    def traced_process(self, index, *args, **kw):
        now["i"] = index
        return process(self, index, *args, **kw)

    fe.FrontEnd.process = traced_process
    fe.choose_pose = lambda *args, **kw: None if now.get("i") in a.cv else choose(*args, **kw)
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, RefineConfig(end=a.end, **json.loads(a.cfg)), Path(tmp) / "run", progress=False)


if __name__ == "__main__":
    main()
