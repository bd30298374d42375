#!/usr/bin/env python3
"""Development check (issue 14): choose the side of a depth edge by photometric consistency with the
neighbouring frames. For a held-out pixel inside a Delaunay triangle of the cheap input that spans a
depth edge, each corner depth is a hypothesis; the pixel's patch is warped into frames i +- k with
KISS-ICP poses (from the cheap scan) under each hypothesis, and the hypothesis whose warped patches
match best (ZNCC, best over the neighbours) wins. Scored on the evaluation beams of development frames
0-37 only (the inductive test frames 38-47 of `leovr bench real` are never read).

    .venv/bin/python tools/edge_photo_dev.py [--input vlp16] [--step 2] [--offsets -6 -3 3 6] [--patch 5]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import Delaunay

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.prior import EDGE_RATIO, interpolated_at
from leovr.lidar.cheap_sensor import vlp16_mask
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample
from odometry.initial_pose import LidarOdometry
from odometry.mono_vo import gray


def cheap_points(s) -> np.ndarray:
    """The cheap sensor's whole 360-degree scan (VLP-16-like: every 4th ring), what KISS-ICP gets in refine."""
    pts = s.frame.points
    return pts[vlp16_mask(pts)]


def patch_costs(ref: np.ndarray, others: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, rows: np.ndarray,
                cols: np.ndarray, depth: np.ndarray, half: int) -> np.ndarray:
    """1 - ZNCC of each pixel's patch against its warp into every other frame (fronto-parallel patch at
    `depth`); returns (n_others, n) with inf where the warp leaves the image."""
    dv, du = np.mgrid[-half:half + 1, -half:half + 1]
    pu = cols[:, None] + du.ravel()[None]
    pv = rows[:, None] + dv.ravel()[None]
    a = map_coordinates(ref, [pv.ravel(), pu.ravel()], order=1, mode="nearest").reshape(pu.shape)
    a = a - a.mean(1, keepdims=True)
    Kinv = np.linalg.inv(K)
    rays = Kinv @ np.stack([pu.ravel(), pv.ravel(), np.ones(pu.size)])
    X = rays * np.repeat(depth, pu.shape[1])[None]
    out = np.full((len(others), len(rows)), np.inf)
    H, W = ref.shape
    for k, (img, T_j_i) in enumerate(others):
        Y = T_j_i[:3, :3] @ X + T_j_i[:3, 3:4]
        z = np.maximum(Y[2], 1e-3)
        u = (K[0, 0] * Y[0] / z + K[0, 2]).reshape(pu.shape)
        v = (K[1, 1] * Y[1] / z + K[1, 2]).reshape(pu.shape)
        inside = ((u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)).all(1) & (Y[2].reshape(pu.shape) > 0.5).all(1)
        b = map_coordinates(img, [v.ravel(), u.ravel()], order=1, mode="nearest").reshape(pu.shape)
        b = b - b.mean(1, keepdims=True)
        zncc = (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1) + 1e-6)
        out[k] = np.where(inside, 1.0 - zncc, np.inf)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--step", type=int, default=2)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--offsets", type=int, nargs="+", default=[-6, -3, 3, 6])
    ap.add_argument("--patch", type=int, default=5)
    ap.add_argument("--poses", default="cheap", choices=["cheap", "full"], help="KISS-ICP on the cheap scan or (diagnosis) the full one")
    ap.add_argument("--margin", type=float, default=0.0, help="cost margin a far/other corner needs over the nearest")
    a = ap.parse_args()
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    n = a.dev_end
    samples = [frame_sample(seq, i, ccfg) for i in range(n)]
    odo = LidarOdometry(samples[0].frame.T_cam_lidar)
    poses = [odo.register(cheap_points(s) if a.poses == 'cheap' else s.frame.points) for s in samples]
    grays = [gray(s.frame.image).astype(np.float32) for s in samples]
    steps = np.linalg.norm(np.diff(np.array([p[:3, 3] for p in poses]), axis=0), axis=1)
    print(json.dumps({"step_m_median": round(float(np.median(steps)), 3), "path_m": round(float(steps.sum()), 2)}))
    tot = {"prior": 0.0, "photo": 0.0, "oracle": 0.0, "n": 0, "all_prior": 0.0, "all_photo": 0.0, "all_n": 0,
           "undecided": 0}
    for i in range(0, n, a.step):
        s = samples[i]
        rows, cols = np.nonzero(s.gt > 0)
        gt = s.gt[rows, cols]
        prior = interpolated_at(s.sparse, rows, cols)
        v, u = np.nonzero(s.sparse > 0)
        tri = Delaunay(np.stack([u, v], 1).astype(float))
        simplex = tri.find_simplex(np.stack([cols, rows], 1).astype(float))
        corners = s.sparse[v, u][tri.simplices[np.maximum(simplex, 0)]]
        edge = (simplex >= 0) & (corners.max(1) >= EDGE_RATIO * corners.min(1))
        e = np.nonzero(edge)[0]
        others = [(grays[i + o], np.linalg.inv(poses[i + o]) @ poses[i]) for o in a.offsets if 0 <= i + o < n]
        cost = np.stack([patch_costs(grays[i], others, s.frame.K, rows[e], cols[e], corners[e, c], a.patch // 2).min(0)
                         for c in range(3)], 1)  # (n_edge, 3)
        near = np.abs(corners[e] - prior[e, None]).argmin(1)  # the corner the prior took
        best = cost.argmin(1)
        gain = cost[np.arange(len(e)), near] - cost[np.arange(len(e)), best]
        choice = np.where(np.isfinite(cost[np.arange(len(e)), best]) & (gain > a.margin), best, near)
        tot["undecided"] += int((choice == near).sum())
        photo = prior.copy()
        photo[e] = corners[e, choice]
        oracle = corners[e, np.abs(corners[e] - gt[e, None]).argmin(1)]
        tot["prior"] += float(np.abs(prior[e] - gt[e]).sum())
        tot["photo"] += float(np.abs(photo[e] - gt[e]).sum())
        tot["oracle"] += float(np.abs(oracle - gt[e]).sum())
        tot["n"] += len(e)
        tot["all_prior"] += float(np.abs(prior - gt).sum())
        tot["all_photo"] += float(np.abs(photo - gt).sum())
        tot["all_n"] += len(gt)
    print(json.dumps({"offsets": a.offsets, "patch": a.patch, "margin": a.margin, "edge_pixels": tot["n"],
                      "edge_prior": round(tot["prior"] / tot["n"], 3), "edge_photo": round(tot["photo"] / tot["n"], 3),
                      "edge_oracle": round(tot["oracle"] / tot["n"], 3), "kept_nearest": round(tot["undecided"] / tot["n"], 3),
                      "all_prior": round(tot["all_prior"] / tot["all_n"], 3), "all_photo": round(tot["all_photo"] / tot["all_n"], 3)}))


if __name__ == "__main__":
    main()
