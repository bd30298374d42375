"""The KITTI raw clip's development frames against a reference trajectory (issue 14, session 49; development only).

    tools/kitti_photo_dev.py steps RUN [RUN ...]     each run's path length and mean step error against KISS-ICP
                                                     on the full HDL-64 scan (the held-out sensor: a reference,
                                                     never an input; cached in runs/kitti_kiss_full.npy)
    tools/kitti_photo_dev.py sweep RUN graph|kiss    the photometric correction post hoc on the run's refined depth
                                                     (a `tools/field_dev.py kitti TAG photometric_field=false` run),
                                                     with the run's poses or the reference's; MAE on the run's scored
                                                     pixels, split by where the sweep pushed (farther / nearer)
env for sweep: CHECK (max_bias_log), SHARE (min_backed_share), FAR (far_log), FARGAIN (far_gain); defaults: the
shipped settings.
Figures: docs/benchmarks.md, "Photometric correction outside the cone", session 49 and 50 paragraphs.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from leovr.config import CompleteConfig, RefineConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.geometry import invert_T
from leovr.paths import kitti_raw_dir
from leovr.pipeline.kiss_baseline import kiss_icp_trajectory
from leovr.pipeline.refine import completion_config, frame_sample, frame_score
from odometry.photo_field import PhotoFieldSettings, free_nodes, photometric_correction, photometric_offsets

CACHE = Path("runs/kitti_kiss_full.npy")


def reference(seq) -> np.ndarray:
    if not CACHE.exists():
        CACHE.parent.mkdir(parents=True, exist_ok=True)
        np.save(CACHE, kiss_icp_trajectory(seq, list(range(len(seq))), CompleteConfig(input="full")))
    return np.load(CACHE)


def run_poses(run: Path) -> np.ndarray:
    est = np.loadtxt(run / "poses_kitti.txt").reshape(-1, 3, 4)
    return np.concatenate([est, np.tile([[[0, 0, 0, 1.0]]], (len(est), 1, 1))], 1)


def steps(runs: list[str]) -> None:
    F = reference(open_sequence(kitti_raw_dir()))
    for r in runs:
        est = run_poses(Path(r))
        n = len(est)
        err = [np.linalg.norm((invert_T(est[i]) @ est[i + 1])[:3, 3] - (invert_T(F[i]) @ F[i + 1])[:3, 3]) for i in range(n - 1)]
        print(Path(r).name, f"path {np.linalg.norm(np.diff(est[:, :3, 3], axis=0), axis=1).sum():.2f} m, reference "
              f"{np.linalg.norm(np.diff(F[:n, :3, 3], axis=0), axis=1).sum():.2f} m, mean step error {np.mean(err):.3f} m")


def sweep(run: Path, source: str) -> None:
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input="mid40"))
    est = run_poses(run)
    n = len(est)
    if source == "kiss":
        est = reference(seq)[:n]
    d = PhotoFieldSettings()
    s = replace(d, max_bias_log=float(os.environ.get("CHECK", d.max_bias_log)), far_log=float(os.environ.get("FAR", d.far_log)),
                far_gain=float(os.environ.get("FARGAIN", d.far_gain)),
                min_backed_share=float(os.environ.get("SHARE", d.min_backed_share)))
    gray = [cv2.cvtColor(seq[j].image, cv2.COLOR_RGB2GRAY) for j in range(n)]
    acc: dict = {}
    biases, shares = [], []
    for i in range(n):
        js = [i - o for o in (1, 2, 3, -1, -2, -3) if 0 <= i - o < n]
        depth = read_depth_png(run / "depth" / f"{i:06d}.png")
        free = free_nodes(frame_sample(seq, i, ccfg, truth=False).sparse, s)
        stats: dict = {}
        off = photometric_offsets(depth, gray[i], [(gray[j], invert_T(est[j]) @ est[i]) for j in js], seq[i].K, free, s, stats)
        biases.append(stats.get("bias", np.nan))
        shares.append(stats.get("backed", 0) / max(stats.get("eligible", 0), 1))
        fs = frame_score(seq, ccfg, run, i, True)
        fs.add("photo", photometric_correction(depth, off, s))
        ratio = fs.pred["photo"] / np.maximum(fs.pred["refined"], 1e-6)
        for part, m in (("farther", ratio > 1.02), ("nearer", ratio < 0.98), ("all", np.ones_like(ratio, bool))):
            for k in ("refined", "photo"):
                a = acc.setdefault((part, k), [0.0, 0])
                a[0] += np.abs(fs.pred[k][m] - fs.gt[m]).sum()
                a[1] += int(m.sum())
    b = np.array(biases)
    print(run.name, source, " ".join(f"{p}_{k}={v[0] / max(v[1], 1):.3f} ({v[1]} px)" for (p, k), v in acc.items()),
          f"check bias median {np.nanmedian(b):.3f}, frames passing the bias test {np.mean(np.abs(b) <= s.max_bias_log):.2f}, "
          f"share of the nodes with returns that chose clearly: median {np.median(shares):.2f}")


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "steps":
        steps(sys.argv[2:])
    elif len(sys.argv) == 4 and sys.argv[1] == "sweep":
        sweep(Path(sys.argv[2]), sys.argv[3])
    else:
        sys.exit(__doc__)
