#!/usr/bin/env python3
"""Development check for issue 14: can a small classifier, trained without ground truth, pick the
right corner of a Delaunay triangle that spans a depth edge (where the prior takes the nearest return)?

Each edge pixel is described by the triangle's geometry (corner depths sorted near to far, barycentric
weights, offsets to the corners) and the image between the pixel and each corner (Lab colour
difference, largest colour change and image gradient crossed on the way); a small MLP scores the
corners, trained by the expected absolute error of the chosen corner.

On the KITTI raw clip's development frames 0-37 (the inductive test frames 38-47 are never read).
Training targets, one source per run:
- default: returns hidden from the cheap input by `masked_split` (`--keep-one-in K`: keep one ring in K);
- `--temporal N`: the cheap input of frames within +-N, registered by KISS-ICP on that input;
- `--sim`: the simulator's validation VLP-16 drives with their dense truth;
- `--supervised` (diagnosis only, reads the evaluation beams): beams of the first half, score the second.
Scored: the evaluation's held-out beams inside an edge triangle of the cheap input. Prints MAE there for
the prior (nearest return), nearest / farthest corner, the classifier and the oracle corner, and the
overall prior MAE with the classifier's choice.

    .venv/bin/python tools/edge_side_dev.py [--input vlp16] [--step 2] [--splits 3] [--temporal 6]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial import Delaunay, QhullError
from torch import nn

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.depth.prior import EDGE_RATIO, interpolated_at
from leovr.eval.heldout import parallax_filter
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample
from selfsup.masked_lidar import MaskedSplit, masked_split, ring_gap_px, stored_rings

PATH_SAMPLES = 8


@dataclass
class EdgePixels:
    """The pixels of a query that lie in an edge triangle, with the triangle's corners sorted near to far."""

    index: np.ndarray  # into the query's rows / cols
    rows: np.ndarray
    cols: np.ndarray
    corner_depth: np.ndarray  # n x 3 metres, ascending
    nearest_corner: np.ndarray  # n, which sorted corner is nearest in the image
    prior: np.ndarray  # n, the prior's value (the nearest return)
    features: np.ndarray  # n x F float32
    target: np.ndarray | None = None


def _image_cues(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed Lab colour (H x W x 3, float32, L in 0-100) and gradient magnitude (H x W, per 255)."""
    rgb = image if image.ndim == 3 else np.repeat(image[..., None], 3, 2)
    blur = cv2.GaussianBlur(rgb, (5, 5), 0)
    lab = cv2.cvtColor(blur.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    gray = cv2.cvtColor(blur, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    grad = np.hypot(cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3))
    return lab, grad


def edge_pixels(sparse: np.ndarray, image: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                edge_ratio: float = EDGE_RATIO) -> EdgePixels:
    """The query pixels (rows, cols) that lie in an edge triangle of `sparse`, with their features."""
    sparse = np.asarray(sparse, np.float32)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    v, u = np.nonzero(sparse > 0)
    empty = EdgePixels(np.zeros(0, np.int64), rows[:0], cols[:0], np.zeros((0, 3), np.float32), np.zeros(0, np.int64),
                       np.zeros(0, np.float32), np.zeros((0, N_FEATURES), np.float32))
    if len(u) < 3 or len(rows) == 0:
        return empty
    try:
        tri = Delaunay(np.stack([u, v], 1).astype(np.float64))
    except QhullError:
        return empty
    pix = np.stack([cols, rows], 1).astype(np.float64)
    simplex = tri.find_simplex(pix)
    inside = np.nonzero(simplex >= 0)[0]
    idx = tri.simplices[simplex[inside]]
    depth = sparse[v, u][idx]
    edge = depth.max(1) >= edge_ratio * depth.min(1)
    measured = sparse[rows[inside], cols[inside]] > 0
    keep = edge & ~measured
    inside, idx, depth = inside[keep], idx[keep], depth[keep]
    if len(inside) == 0:
        return empty
    order = np.argsort(depth, 1)
    idx = np.take_along_axis(idx, order, 1)
    depth = np.take_along_axis(depth, order, 1)
    T = tri.transform[simplex[inside]]
    b = np.einsum("nij,nj->ni", T[:, :2], pix[inside] - T[:, 2])
    bary = np.take_along_axis(np.concatenate([b, 1.0 - b.sum(1, keepdims=True)], 1), order, 1)
    r, c = rows[inside], cols[inside]
    cu, cv = u[idx].astype(np.float64), v[idx].astype(np.float64)
    du, dv = cu - c[:, None], cv - r[:, None]
    dist = np.hypot(du, dv)
    side = np.stack([np.hypot(cu[:, i] - cu[:, j], cv[:, i] - cv[:, j]) for i, j in ((0, 1), (1, 2), (0, 2))], 1)
    scale = np.maximum(side.max(1), 1.0)[:, None]
    lab, grad = _image_cues(image)
    h, w = sparse.shape
    colour = np.linalg.norm(lab[cv.astype(int), cu.astype(int)] - lab[r, c][:, None, :], axis=2) / 100.0
    t = (np.arange(1, PATH_SAMPLES + 1) / (PATH_SAMPLES + 1))[None, None, :]
    pu = np.clip(np.rint(c[:, None, None] + du[..., None] * t), 0, w - 1).astype(np.int64)
    pv = np.clip(np.rint(r[:, None, None] + dv[..., None] * t), 0, h - 1).astype(np.int64)
    g = grad[pv, pu]
    path_colour = np.linalg.norm(lab[pv, pu] - lab[r, c][:, None, None, :], axis=3).max(2) / 100.0
    nearest_corner = dist.argmin(1)
    feats = np.concatenate([
        np.log(depth[:, 1:] / depth[:, :1]), np.log(depth[:, :1]), bary, du / scale, dv / scale, dist / scale,
        np.log(scale), colour, path_colour, g.max(2), g.mean(2), np.eye(3)[nearest_corner], (r / h)[:, None],
    ], 1).astype(np.float32)
    prior = nearest_fill(sparse)[r, c]
    return EdgePixels(inside, r, c, depth, nearest_corner, prior, feats)


N_FEATURES = 2 + 1 + 3 + 3 + 3 + 3 + 1 + 3 + 3 + 3 + 3 + 3 + 1


class SideModel(nn.Module):
    """A small MLP: edge-pixel features -> a score per sorted corner; with the features' standardisation."""

    def __init__(self, n_features: int = N_FEATURES, hidden: int = 64) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(n_features))
        self.register_buffer("std", torch.ones(n_features))
        self.net = nn.Sequential(nn.Linear(n_features, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net((x - self.mean) / self.std)


def train_side_model(data: list[EdgePixels], epochs: int = 300, lr: float = 3e-3, clip_m: float = 20.0,
                     seed: int = 0) -> SideModel:
    """Fit the corner choice by the expected absolute error of the chosen corner against the hidden returns."""
    torch.manual_seed(seed)
    x = torch.from_numpy(np.concatenate([d.features for d in data]))
    cd = torch.from_numpy(np.concatenate([d.corner_depth for d in data]))
    t = torch.from_numpy(np.concatenate([d.target for d in data if d.target is not None]))
    err = (cd - t[:, None]).abs().clamp(max=clip_m)
    model = SideModel(x.shape[1])
    model.mean.copy_(x.mean(0))
    model.std.copy_(x.std(0).clamp(min=1e-6))
    opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=1e-4)
    for _ in range(epochs):
        opt.zero_grad()
        loss = (torch.softmax(model(x), 1) * err).sum(1).mean()
        loss.backward()
        opt.step()
    return model


def choose(model: SideModel, e: EdgePixels) -> np.ndarray:
    """The chosen corner's depth per edge pixel (metres)."""
    if len(e.rows) == 0:
        return np.zeros(0, np.float32)
    with torch.no_grad():
        k = model(torch.from_numpy(e.features)).argmax(1).numpy()
    return e.corner_depth[np.arange(len(k)), k]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--splits", type=int, default=3)
    ap.add_argument("--step", type=int, default=1)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--supervised", action="store_true",
                    help="diagnosis only: train on the evaluation beams of the first half, score the second")
    ap.add_argument("--keep-one-in", type=int, default=0, help="split: keep one ring in k (0: masked_split)")
    ap.add_argument("--sim", action="store_true", help="train on the simulator's validation VLP-16 drives (dense truth)")
    ap.add_argument("--temporal", type=int, default=0,
                    help="targets: the input scans of frames within +-N, registered by KISS-ICP on the input")
    ap.add_argument("--no-span-rings", action="store_true", help="hidden returns filtered with the 7 px window")
    a = ap.parse_args()
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    train: list[EdgePixels] = []
    samples = [frame_sample(seq, i, ccfg) for i in range(0, a.dev_end)]
    if a.temporal:
        from leovr.geometry import invert_T
        from odometry.initial_pose import LidarOdometry
        odo = LidarOdometry(samples[0].frame.T_cam_lidar)
        poses = [odo.register(s.kept_points) for s in samples]
        for i in range(0, a.dev_end, a.step):
            f = samples[i].frame
            T_cl = f.T_cam_lidar
            pts = []
            for j in range(max(0, i - a.temporal), min(a.dev_end, i + a.temporal + 1)):
                if j == i:
                    continue
                T = invert_T(T_cl) @ invert_T(poses[i]) @ poses[j] @ T_cl
                p = samples[j].kept_points[:, :3]
                pts.append(p @ T[:3, :3].T + T[:3, 3])
            hidden = sparse_depth(np.concatenate(pts), f.K, T_cl, f.shape)
            hidden[samples[i].sparse > 0] = 0
            union = np.where(samples[i].sparse > 0, samples[i].sparse, hidden)
            tgt = parallax_filter(hidden, union, 7, 0.15)
            img = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, 2)
            r, c = np.nonzero(tgt > 0)
            e = edge_pixels(samples[i].sparse, img, r, c)
            e.target = tgt[e.rows, e.cols]
            train.append(e)
    test: list[tuple[EdgePixels, np.ndarray, np.ndarray, np.ndarray]] = []
    for i in range(0, a.dev_end, a.step):
        s = samples[i]
        f = s.frame
        img = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, 2)
        for _ in range(a.splits):
            if a.keep_one_in:
                rings = stored_rings(s.kept_points)
                keep = rings % a.keep_one_in == rng.integers(0, a.keep_one_in)
                sparse = sparse_depth(s.kept_points[keep], f.K, f.T_cam_lidar, f.shape)
                hidden = sparse_depth(s.kept_points[~keep], f.K, f.T_cam_lidar, f.shape)
                win = (7, 7) if a.no_span_rings else (2 * ring_gap_px(s.sparse) + 1, 7)
                sp = MaskedSplit(sparse, parallax_filter(hidden, s.sparse, win, 0.15))
            else:
                sp = masked_split(s.kept_points, f.K, f.T_cam_lidar, f.shape, rng, span_rings=not a.no_span_rings,
                                  every=s.sparse)
            r, c = np.nonzero(sp.target > 0)
            e = edge_pixels(sp.sparse, img, r, c)
            e.target = sp.target[e.rows, e.cols]
            train.append(e)
        rows, cols = np.nonzero(s.gt > 0)
        e = edge_pixels(s.sparse, img, rows, cols)
        e.target = s.gt[e.rows, e.cols]
        test.append((e, s.gt[rows, cols], interpolated_at(s.sparse, rows, cols), np.stack([rows, cols], 1)))
    if a.sim:
        train = []
        ref = completion_config(RefineConfig(input="full"))
        for d in sorted((Path.home() / ".cache/leovr/datasets/default/val").glob("*_vlp16_day_*")):
            sq = open_sequence(d)
            for i in range(0, len(sq), 10):
                s = frame_sample(sq, i, ref)
                img = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, 2)
                r, c = np.nonzero(s.gt > 0)
                sel = rng.random(len(r)) < 0.2
                e = edge_pixels(s.sparse, img, r[sel], c[sel])
                e.target = s.gt[e.rows, e.cols]
                train.append(e)
    if a.supervised:
        half = len(test) // 2
        train = [t[0] for t in test[:half]]
        test = test[half:]
    def labels(es: list[EdgePixels]) -> list[float]:
        lab = np.concatenate([np.abs(e.corner_depth - e.target[:, None]).argmin(1) for e in es])
        near = np.concatenate([e.nearest_corner for e in es])
        return [round(float(np.mean(lab == k)), 3) for k in range(3)] + [round(float(np.mean(lab == near)), 3)]
    print("best corner share near/mid/far + nearest-is-best: train", labels(train), "test", labels([t[0] for t in test]))
    model = train_side_model(train, epochs=a.epochs)
    tot = {k: 0.0 for k in ("prior", "near_corner", "far_corner", "learnt", "oracle")}
    n_edge = 0
    all_prior, all_learnt, n_all = 0.0, 0.0, 0
    for e, gt, prior, rc in test:
        if len(e.rows) == 0:
            continue
        t = e.target
        pick = choose(model, e)
        tot["prior"] += np.abs(e.prior - t).sum()
        tot["near_corner"] += np.abs(e.corner_depth[:, 0] - t).sum()
        tot["far_corner"] += np.abs(e.corner_depth[:, 2] - t).sum()
        tot["learnt"] += np.abs(pick - t).sum()
        tot["oracle"] += np.abs(e.corner_depth - t[:, None]).min(1).sum()
        n_edge += len(t)
        full = prior.copy()
        full[e.index] = pick
        all_prior += np.abs(prior - gt).sum()
        all_learnt += np.abs(full - gt).sum()
        n_all += len(gt)
    res = {f"edge_{k}_mae_m": round(float(v) / max(n_edge, 1), 3) for k, v in tot.items()}
    res |= {"edge_pixels": n_edge, "all_pixels": n_all, "all_prior_mae_m": round(float(all_prior) / n_all, 3),
            "all_learnt_mae_m": round(float(all_learnt) / n_all, 3), "train_pixels": int(sum(len(e.rows) for e in train))}
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
