#!/usr/bin/env python3
"""The classical prior on a dense scan, with the image guide given the returns near depth edges (the shipped
selection, `leovr/depth/prior.py`) against the guide given every return, and the nearest fill, on the same
held-out returns: every `--step`-th frame of each KITTI raw clip, a random tenth of its scan's returns held out
(seeded by the frame), the prior built from the rest. MAE per clip and the prior's time per frame.

    .venv/bin/python tools/eval_dense_prior.py [--data ../shared/data] [--step 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.depth import prior
from leovr.depth.classical import nearest_fill
from leovr.lidar.projection import sparse_depth


def held_out_split(depth: np.ndarray, seed: int, share: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map without a random `share` of its returns, and the rows and columns of those returns."""
    v, u = np.nonzero(depth > 0)
    held = np.random.default_rng(seed).random(len(u)) < share
    kept = depth.copy()
    kept[v[held], u[held]] = 0.0
    return kept, v[held], u[held]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data")
    ap.add_argument("--step", type=int, default=2)
    args = ap.parse_args()
    clips = sorted(p for p in args.data.glob("kitti_raw*") if p.is_dir())
    shipped = prior.DENSE_RETURNS
    for clip in clips:
        seq = open_sequence(clip)
        err: dict[str, list[np.ndarray]] = {"selected": [], "every return": [], "nearest fill": []}
        secs = {"selected": 0.0, "every return": 0.0}
        frames = range(0, len(seq), args.step)
        for n, i in enumerate(frames):
            f = seq[i]
            scan = sparse_depth(f.points[:, :3], f.K, f.T_cam_lidar, f.image.shape[:2])
            kept, rows, cols = held_out_split(scan, i)
            truth = scan[rows, cols]
            arms = [("selected", shipped), ("every return", 10**9)]
            # a frame's first prior pays for touching its memory: the arms take turns going first
            for name, dense in arms if n % 2 == 0 else arms[::-1]:
                prior.DENSE_RETURNS = dense
                t0 = time.perf_counter()
                filled = prior.interpolated_fill(kept, image=f.image)
                secs[name] += time.perf_counter() - t0
                err[name].append(np.abs(filled[rows, cols] - truth))
            prior.DENSE_RETURNS = shipped
            err["nearest fill"].append(np.abs(nearest_fill(kept)[rows, cols] - truth))
        parts = [f"{name} MAE {np.concatenate(e).mean():.4f} m" for name, e in err.items()]
        times = [f"{name} {1000 * s / len(frames):.0f} ms" for name, s in secs.items()]
        print(
            f"{clip.name} ({len(frames)} frames): " + ", ".join(parts) + "; prior time per frame: " + ", ".join(times)
        )


if __name__ == "__main__":
    main()
