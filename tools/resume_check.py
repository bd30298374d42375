#!/usr/bin/env python3
"""Run-to-run noise against resume: refine the shared KITTI clip (VLP-16-like input, first N frames)
twice uninterrupted (A, B), and once killed after K finished frames then resumed (C); print how far B
and C lie from A (poses, refined depth, landmarks, frames timed).

    .venv/bin/python tools/resume_check.py --frames 12 --kill-after 6 --work /tmp/resume_check
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.run_info import read_run_depth
from leovr.paths import kitti_raw_dir
from leovr.pipeline import refine


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--kill-after", type=int, default=6)
    ap.add_argument("--work", type=Path, default=Path("/tmp/resume_check"))
    a = ap.parse_args()
    shutil.rmtree(a.work, ignore_errors=True)
    seq, cfg = open_sequence(kitti_raw_dir()), RefineConfig(input="vlp16", end=a.frames)
    for name in "AB":
        refine.run_refine(seq, cfg, a.work / name, progress=False)
    save, calls = refine.Progress.save, []

    def killed(self, path):
        save(self, path)
        calls.append(path)
        if len(calls) == a.kill_after:
            raise KeyboardInterrupt

    refine.Progress.save = killed
    try:
        refine.run_refine(seq, cfg, a.work / "C", progress=False)
    except KeyboardInterrupt:
        pass
    refine.Progress.save = save
    refine.run_refine(seq, cfg, a.work / "C", resume=True, progress=False)
    A = a.work / "A"
    for name in "BC":
        X = a.work / name
        pose = np.abs(np.loadtxt(A / "poses_kitti.txt") - np.loadtxt(X / "poses_kitti.txt")).max()
        depth = max(
            np.abs(read_run_depth(A, "depth", i) - read_run_depth(X, "depth", i)).max() for i in range(a.frames)
        )
        la, lx = np.load(A / "landmarks.npy"), np.load(X / "landmarks.npy")
        timed = json.loads((X / "timing.json").read_text())["frames_timed"]
        print(
            f"{name} vs A: poses max {pose:.1e} m, refined depth max {depth:.3f} m, "
            f"landmarks {len(lx)} (A {len(la)}), frames timed {timed}"
        )


if __name__ == "__main__":
    main()
