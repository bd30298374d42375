#!/usr/bin/env python3
"""Would a photometric term teach `leovr adapt` anything on the KITTI raw clip? (issue 14, development only)

For every scored pixel of frames 6, 8, ..., 30 (the development frames 0-37 only, neighbours included),
compare the photometric error (eq. 17, SSIM + L1, the minimum over the neighbours i +- OFFSET, monodepth2
style) of two depth maps warped with a finished run's poses: the generator's depth of that run, and the
held-out beams' depth (nearest-filled). Where the generator is far off, a useful photometric loss must
prefer the truth: the table gives, per bin of the generator's relative error, inside and outside a
38.4-degree cone, how often it does and the bin's share of the absolute error.

    .venv/bin/leovr refine ../shared/data/kitti_raw --input mid40 --end 38 --out runs/dev_mid40_0_38
    .venv/bin/python tools/photo_signal_dev.py runs/dev_mid40_0_38 --offsets 3 --scale 0.36
    .venv/bin/leovr refine ../shared/data/kitti_raw --input full --end 38 --out runs/dev_full_0_38
    .venv/bin/python tools/photo_signal_dev.py runs/dev_mid40_0_38 --poses runs/dev_full_0_38
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.depth.classical import nearest_fill
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample
from selfsup.losses import photometric_error
from selfsup.warp import warp_image


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run", type=Path, help="a `leovr refine` output folder (poses_kitti.txt, depth_generator/)")
    ap.add_argument("--input", default="mid40")
    ap.add_argument("--poses", type=Path, default=None, help="take the poses from this run instead (e.g. one on the full scan)")
    ap.add_argument("--offsets", type=int, nargs="+", default=[3])
    ap.add_argument("--scale", type=float, default=0.36, help="image scale (0.36: the generator's 260 px focal length)")
    a = ap.parse_args()
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    P = np.loadtxt((a.poses or a.run) / "poses_kitti.txt").reshape(-1, 3, 4)
    T = np.tile(np.eye(4), (len(P), 1, 1))
    T[:, :3] = P
    last = 30
    assert last + max(a.offsets) < 38, "frames 38-47 are the inductive test frames"
    cone = np.tan(np.radians(19.2))
    rel, prefer, outside, abs_err = [], [], [], []
    for i in range(6, last + 1, 2):
        s = frame_sample(seq, i, ccfg)
        f = s.frame
        h, w = f.shape
        hs, ws = int(round(h * a.scale)), int(round(w * a.scale))
        K = torch.from_numpy(np.diag([a.scale, a.scale, 1.0]) @ f.K).float()[None]

        def small(x: np.ndarray, interp: int) -> np.ndarray:
            return x if a.scale == 1 else cv2.resize(x, (ws, hs), interpolation=interp)

        def tensor_image(im: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(small(im, cv2.INTER_AREA)).permute(2, 0, 1).float()[None] / 255.0

        gen = read_depth_png(a.run / "depth_generator" / f"{i:06d}.png")
        maps = {"gen": gen, "truth": nearest_fill(s.gt)}
        err = {k: [] for k in maps}
        target = tensor_image(f.image)
        for o in a.offsets:
            for j in (i - o, i + o):
                source = tensor_image(seq[j].image)
                T_ji = torch.from_numpy(np.linalg.inv(T[j]) @ T[i]).float()[None]
                for k, d in maps.items():
                    depth = torch.from_numpy(small(d, cv2.INTER_NEAREST)).float()[None, None]
                    warped, ok = warp_image(source, depth, T_ji, K)
                    e = photometric_error(target, warped)[0, 0].numpy()
                    e[~ok[0, 0].numpy()] = np.inf
                    err[k].append(e)
        best = {k: np.min(v, 0) for k, v in err.items()}
        rows, cols = np.nonzero(s.gt > 0)
        rs = np.minimum((rows * a.scale).astype(int), hs - 1)
        cs = np.minimum((cols * a.scale).astype(int), ws - 1)
        truth, g = s.gt[rows, cols], gen[rows, cols]
        rel.append(np.abs(g - truth) / truth)
        abs_err.append(np.abs(g - truth))
        prefer.append(best["truth"][rs, cs] < best["gen"][rs, cs])
        outside.append(np.hypot(cols - f.K[0, 2], rows - f.K[1, 2]) > f.K[0, 0] * cone)
    rel, prefer, outside, abs_err = (np.concatenate(x) for x in (rel, prefer, outside, abs_err))
    print(f"offsets {a.offsets}, scale {a.scale}: share of the absolute error / P(photometric error prefers the truth)")
    print("| where | gen rel. error < 0.1 | 0.1-0.3 | 0.3-1 | >= 1 |")
    print("|---|---|---|---|---|")
    for name, sel in (("all", np.ones_like(outside)), ("outside the cone", outside), ("inside", ~outside)):
        cells = []
        for lo, hi in ((0, 0.1), (0.1, 0.3), (0.3, 1.0), (1.0, np.inf)):
            m = sel & (rel >= lo) & (rel < hi)
            cells.append(f"{abs_err[m].sum() / abs_err.sum():.2f} / {prefer[m].mean():.2f} (n {m.sum()})")
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
