"""Development check (KITTI raw clip, frames 0-37 only): how many of the earlier Mid-40-like returns that
`refine` adds to a frame's generator input land at a wrong depth, by their age in frames, and how many of
the wrong and of the right ones each filter drops.

Wrong: more than max(1 m, 10 %) away from the full HDL-64 scan's nearest fill at the pixel (judged only
where a full-scan return lies within 2 px, and only on pixels the frame's own cheap scan leaves empty).
Filters:
- `freespace`: the shipped check (`leovr.lidar.accumulate.RangeImage`): any later scan up to and including
  the frame's own sees free space in front of the return or a surface clearly in front of it;
- `neighbour`: no return of the previous or next scan within 0.1 m + 2 % of the range (KD-tree);
- `photo`: the 5 x 5 grey patch around the return differs by more than 0.08 (mean absolute, 0-1 scale)
  between the image it was measured in and the current one.

    .venv/bin/python tools/history_check_dev.py RUN [--icp] [--past 12]

RUN: a finished `leovr refine ../shared/data/kitti_raw --input mid40 --end 38` whose poses place the
scans; `--icp` places them with KISS-ICP on the full HDL-64 scan instead.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.geometry import invert_T
from leovr.lidar.accumulate import RangeImage, ScanHistory
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample

FILTERS = ("freespace", "neighbour", "photo")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("--past", type=int, default=12)
    ap.add_argument("--end", type=int, default=38)
    ap.add_argument("--icp", action="store_true")
    a = ap.parse_args()
    if a.end > 38:
        raise SystemExit("frames 38-47 are the clip's inductive test frames: development stops at 38")
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input="mid40"))
    S = [frame_sample(seq, i, ccfg) for i in range(a.end)]
    T_cl = S[0].frame.T_cam_lidar
    if a.icp:
        from odometry.initial_pose import LidarOdometry

        lo = LidarOdometry(T_cl)
        P = [lo.register(s.frame.points) for s in S]
    else:
        P = read_kitti_poses(a.run / "poses_kitti.txt")[: a.end]
    shipped = ScanHistory(0)  # margins and bins as shipped
    lidar = [np.asarray(s.kept_points[:, :3], np.float64) for s in S]
    cam = [x @ T_cl[:3, :3].T + T_cl[:3, 3] for x in lidar]
    world = [c @ P[j][:3, :3].T + P[j][:3, 3] for j, c in enumerate(cam)]
    seen = [RangeImage.of(x, shipped.bin_deg) for x in lidar]
    trees = [cKDTree(w) for w in world]
    gray = [grey(s.frame.image) for s in S]
    K = S[0].frame.K
    H, W = S[0].frame.shape
    T_lc = invert_T(T_cl)

    def neighbour_ok(j: int) -> np.ndarray:
        r = 0.1 + 0.02 * np.linalg.norm(cam[j], axis=1)
        ok = np.zeros(len(world[j]), bool)
        for o in (j - 1, j + 1):
            if 0 <= o < len(world):
                d, _ = trees[o].query(world[j], distance_upper_bound=float(r.max()))
                ok |= d <= r
        return ok

    neighbour = [neighbour_ok(j) for j in range(len(world))]
    stats: dict[int, dict[str, float]] = {}
    for i in range(a.past, a.end):
        f = S[i].frame
        full = sparse_depth(f.points, K, T_cl, f.shape)
        dist, (iv, iu) = distance_transform_edt(full <= 0, return_indices=True)
        dense = full[iv, iu]
        Ti = invert_T(P[i])
        for age in range(1, a.past + 1):
            j = i - age
            X = world[j] @ Ti[:3, :3].T + Ti[:3, 3]
            u, v, ok = project(X, K, H, W)
            ok[ok] &= (dist[v[ok], u[ok]] <= 2) & (S[i].sparse[v[ok], u[ok]] <= 0)
            X, u, v = X[ok], u[ok], v[ok]
            truth = dense[v, u]
            wrong = np.abs(X[:, 2] - truth) > np.maximum(1.0, 0.1 * truth)
            drop = {"freespace": np.zeros(len(X), bool), "neighbour": ~neighbour[j][ok]}
            for k in range(j + 1, i + 1):
                T = T_lc @ invert_T(P[k]) @ P[j]
                drop["freespace"] |= seen[k].contradicts(cam[j][ok] @ T[:3, :3].T + T[:3, 3],
                                                         shipped.margin_m, shipped.margin_rel)
            uj, vj, inj = project(cam[j][ok], K, H, W)
            drop["photo"] = inj & (patch_difference(gray[i], u, v, gray[j], uj, vj) > 0.08)
            st = stats.setdefault(age, {"n": 0, "wrong": 0, "behind": 0, **{f"{k}_{w}": 0 for k in FILTERS for w in ("wrong", "right")}})
            st["n"] += len(X)
            st["wrong"] += int(wrong.sum())
            st["behind"] += int((wrong & (X[:, 2] > truth)).sum())
            for k in FILTERS:
                st[f"{k}_wrong"] += int((wrong & drop[k]).sum())
                st[f"{k}_right"] += int((~wrong & drop[k]).sum())
    print("| age (frames) | returns | wrong | of them behind the surface | "
          + " | ".join(f"{k}: dropped of wrong / of right" for k in FILTERS) + " |")
    print("|---" * (4 + len(FILTERS)) + "|")
    for age, st in sorted(stats.items()):
        nw, nr = max(st["wrong"], 1), max(st["n"] - st["wrong"], 1)
        cells = [f"{100 * st[f'{k}_wrong'] / nw:.0f} % / {100 * st[f'{k}_right'] / nr:.0f} %" for k in FILTERS]
        print(f"| {age} | {st['n']} | {100 * st['wrong'] / st['n']:.1f} % | {100 * st['behind'] / nw:.0f} % | "
              + " | ".join(cells) + " |")


def grey(image: np.ndarray) -> np.ndarray:
    g = image.astype(np.float32)
    g = g.mean(2) if g.ndim == 3 else g
    return g / (255.0 if g.max() > 1.5 else 1.0)


def project(X: np.ndarray, K: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    z = np.maximum(X[:, 2], 1e-3)
    u = np.rint(K[0, 0] * X[:, 0] / z + K[0, 2]).astype(int)
    v = np.rint(K[1, 1] * X[:, 1] / z + K[1, 2]).astype(int)
    return u, v, (X[:, 2] > 0.5) & (u >= 0) & (u < W) & (v >= 0) & (v < H)


def patch_difference(gi, ui, vi, gj, uj, vj, r: int = 2) -> np.ndarray:
    H, W = gi.shape
    offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]
    a = np.stack([gi[np.clip(vi + dy, 0, H - 1), np.clip(ui + dx, 0, W - 1)] for dy, dx in offsets])
    b = np.stack([gj[np.clip(vj + dy, 0, H - 1), np.clip(uj + dx, 0, W - 1)] for dy, dx in offsets])
    return np.abs(a - b).mean(0)


if __name__ == "__main__":
    main()
