#!/usr/bin/env python3
"""Where the classical prior's error lies, and what the image's side choice at depth edges does about it.

Real (default): the KITTI raw clip's development frames (0-37 only; the inductive test frames 38-47 of
`leovr bench real` are never read). Held-out pixels are grouped by the Delaunay triangle of the cheap
input they fall in: "smooth" (corner depths within EDGE_RATIO), "edge" (the triangle spans a depth edge)
and "outside" the input's hull. Per group: pixel count and MAE of the nearest fill, the prior with the
nearest return at depth edges (`prior`) and with the image's side (`prior_image`, leovr.depth.prior), the
shipped generator over either (`generator`, `generator_image`) and the best corner of the triangle (an
oracle: what a perfect foreground / background choice would give).
`--sim`: the simulator's validation split instead (dense truth, each sequence's own scan, all pixels).
`--set K=.. LAMBDA=.. SIGMA=..` overrides the edge-aware interpolation's settings; `--checkpoint` scores
other generator weights.

    .venv/bin/python tools/prior_error_split.py [--input vlp16] [--step 3] [--sim] [--set K=64 ...] [--checkpoint PT]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.spatial import Delaunay

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth import prior
from leovr.depth.classical import nearest_fill
from leovr.depth.dataset import split_entries
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.runtime import for_inference
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root


def predictions(model, image: np.ndarray, sparse: np.ndarray, focal: float, model_focal: float | None,
                rows: np.ndarray, cols: np.ndarray) -> dict[str, np.ndarray]:
    """Every method at the pixels (rows, cols)."""
    return {"nearest": nearest_fill(sparse)[rows, cols],
            "prior": prior.interpolated_at(sparse, rows, cols),
            "prior_image": prior.interpolated_at(sparse, rows, cols, image=image),
            "generator": predict_at_focal(model, image, sparse, focal, model_focal, False)[0][rows, cols],
            "generator_image": predict_at_focal(model, image, sparse, focal, model_focal, True)[0][rows, cols]}


def accumulate(err: dict, count: dict, groups: dict[str, np.ndarray], preds: dict[str, np.ndarray], gt: np.ndarray) -> None:
    for g, sel in groups.items():
        count[g] = count.get(g, 0) + int(sel.sum())
        for name, p in preds.items():
            err.setdefault(g, {}).setdefault(name, 0.0)
            err[g][name] += float(np.abs(p[sel] - gt[sel]).sum())


def table(err: dict, count: dict) -> dict:
    total = err["all"]["prior"]
    return {g: {"pixels": count[g], "share_of_prior_error": round(err[g]["prior"] / total, 3)}
            | {f"{name}_mae_m": round(e / max(count[g], 1), 3) for name, e in d.items()} for g, d in err.items()}


def simulator(model, step: int) -> dict:
    out = {}
    for e in split_entries(default_root() / "default", "val"):
        err, count = out.setdefault(e["lidar"], ({}, {}))
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), step):
            f = seq[i]
            sp = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
            rows, cols = np.nonzero(f.depth > 0)
            preds = predictions(model, f.image, sp, float(f.K[0, 0]), None, rows, cols)
            accumulate(err, count, {"all": np.ones(len(rows), bool)}, preds, f.depth[rows, cols])
    return {lidar: table(*ec) for lidar, ec in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--step", type=int, default=3)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--sim", action="store_true", help="the simulator's validation split (every --step-th frame)")
    ap.add_argument("--checkpoint", default=None, help="generator weights (default: the shipped checkpoint)")
    ap.add_argument("--set", nargs="*", default=[], help="K=, LAMBDA=, SIGMA= of the edge-aware interpolation")
    a = ap.parse_args()
    for kv in a.set:
        k, v = kv.split("=")
        name = f"EDGE_AWARE_{k.upper()}"
        setattr(prior, name, type(getattr(prior, name))(float(v)))
    model = for_inference(load_generator(a.checkpoint or shipped_checkpoint()))
    if a.sim:
        print(json.dumps({"data": f"simulator validation split, every {a.step}th frame", "set": a.set,
                          "groups": simulator(model, a.step)}, indent=1))
        return
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    err: dict[str, dict[str, float]] = {}
    count: dict[str, int] = {}
    for i in range(0, a.dev_end, a.step):
        s = frame_sample(seq, i, ccfg)
        rows, cols = np.nonzero(s.gt > 0)
        gt = s.gt[rows, cols]
        img = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, 2)
        preds = predictions(model, img, s.sparse, float(s.frame.K[0, 0]), ccfg.generator_focal_px, rows, cols)
        v, u = np.nonzero(s.sparse > 0)
        tri = Delaunay(np.stack([u, v], 1).astype(float))
        simplex = tri.find_simplex(np.stack([cols, rows], 1).astype(float))
        corners = s.sparse[v, u][tri.simplices[np.maximum(simplex, 0)]]
        edge = corners.max(1) >= prior.EDGE_RATIO * corners.min(1)
        preds["oracle_corner"] = np.where(simplex >= 0, corners[np.arange(len(gt)), np.abs(corners - gt[:, None]).argmin(1)],
                                          preds["nearest"])
        groups = {"all": np.ones(len(gt), bool), "smooth": (simplex >= 0) & ~edge, "edge": (simplex >= 0) & edge,
                  "outside": simplex < 0}
        accumulate(err, count, groups, preds, gt)
    print(json.dumps({"input": a.input, "frames": f"0-{a.dev_end - 1} step {a.step}", "set": a.set,
                      "groups": table(err, count)}, indent=1))


if __name__ == "__main__":
    main()
