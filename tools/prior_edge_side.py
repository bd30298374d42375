#!/usr/bin/env python3
"""The prior's side choice at depth edges, with and without the camera image (leovr.depth.prior).

Real (default): the KITTI raw clip's development frames (0-37 only; the inductive test frames 38-47 of
`leovr bench real` are never read). Held-out pixels inside a Delaunay triangle of the cheap input that
spans a depth edge ("edge"), and all held-out pixels: MAE of the nearest fill, the prior without the
image (nearest return at edges), the prior with it, the best corner (an oracle) and, with --generator,
the shipped generator over either prior. `--sim`: the simulator's validation split instead (dense
ground truth, each sequence's own scan, every 8th frame). `--set K=.. LAMBDA=.. SIGMA=..` overrides the
edge-aware interpolation's settings.

    .venv/bin/python tools/prior_edge_side.py [--input vlp16] [--step 2] [--generator] [--sim] [--set K=64 ...]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.spatial import Delaunay

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth import prior
from leovr.depth.classical import nearest_fill
from leovr.depth.dataset import split_entries
from leovr.depth.inference import load_generator, predict, predict_at_focal
from leovr.depth.runtime import for_inference
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root


def mae_table(err: dict, count: dict) -> dict:
    return {g: {"pixels": count[g]} | {f"{n}_mae_m": round(e / max(count[g], 1), 4) for n, e in d.items()}
            for g, d in err.items()}


def add(err: dict, count: dict, groups: dict, preds: dict, gt: np.ndarray) -> None:
    for g, sel in groups.items():
        count[g] = count.get(g, 0) + int(sel.sum())
        for name, p in preds.items():
            err.setdefault(g, {}).setdefault(name, 0.0)
            err[g][name] += float(np.abs(p[sel] - gt[sel]).sum())


def simulator(model, step: int) -> dict:
    out = {}
    for e in split_entries(default_root() / "default", "val"):
        err, count = out.setdefault(e["lidar"], ({}, {}))
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), step):
            f = seq[i]
            sp = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
            m = f.depth > 0
            preds = {"nearest": nearest_fill(sp), "prior": prior.interpolated_fill(sp),
                     "prior_image": prior.interpolated_fill(sp, image=f.image)}
            if model is not None:
                preds["generator"] = predict(model, f.image, sp, image_edges=False)[0]
                preds["generator_image"] = predict(model, f.image, sp)[0]
            add(err, count, {"all": np.ones(int(m.sum()), bool)}, {k: v[m] for k, v in preds.items()}, f.depth[m])
    return {lidar: mae_table(*ec) for lidar, ec in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--step", type=int, default=2)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--generator", action="store_true", help="also the shipped generator over either prior")
    ap.add_argument("--sim", action="store_true", help="the simulator's validation split (every --step-th frame)")
    ap.add_argument("--set", nargs="*", default=[], help="K=, LAMBDA=, SIGMA= of the edge-aware interpolation")
    a = ap.parse_args()
    for kv in a.set:
        k, v = kv.split("=")
        name = f"EDGE_AWARE_{k.upper()}"
        setattr(prior, name, type(getattr(prior, name))(float(v)))
    model = for_inference(load_generator(shipped_checkpoint())) if a.generator else None
    if a.sim:
        print(json.dumps({"data": f"simulator validation split, every {a.step}th frame", "set": a.set,
                          "groups": simulator(model, a.step)}, indent=1))
        return
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    err: dict[str, dict[str, float]] = {}
    count: dict[str, int] = {}
    ms = []
    for i in range(0, a.dev_end, a.step):
        s = frame_sample(seq, i, ccfg)
        rows, cols = np.nonzero(s.gt > 0)
        gt = s.gt[rows, cols]
        t0 = time.perf_counter()
        with_image = prior.interpolated_at(s.sparse, rows, cols, image=s.frame.image)
        ms.append(1000.0 * (time.perf_counter() - t0))
        preds = {"nearest": nearest_fill(s.sparse)[rows, cols], "prior": prior.interpolated_at(s.sparse, rows, cols),
                 "prior_image": with_image}
        if model is not None:
            for name, edges in (("generator", False), ("generator_image", True)):
                preds[name] = predict_at_focal(model, s.frame.image, s.sparse, float(s.frame.K[0, 0]),
                                               ccfg.generator_focal_px, edges)[0][rows, cols]
        v, u = np.nonzero(s.sparse > 0)
        tri = Delaunay(np.stack([u, v], 1).astype(float))
        simplex = tri.find_simplex(np.stack([cols, rows], 1).astype(float))
        corners = s.sparse[v, u][tri.simplices[np.maximum(simplex, 0)]]
        edge = (simplex >= 0) & (corners.max(1) >= prior.EDGE_RATIO * corners.min(1))
        preds["oracle_corner"] = np.where(edge, corners[np.arange(len(gt)), np.abs(corners - gt[:, None]).argmin(1)],
                                          preds["prior"])
        add(err, count, {"all": np.ones(len(gt), bool), "edge": edge}, preds, gt)
    print(json.dumps({"input": a.input, "frames": f"0-{a.dev_end - 1} step {a.step}", "set": a.set,
                      "prior_image_ms": round(float(np.median(ms)), 1), "groups": mae_table(err, count)}, indent=1))


if __name__ == "__main__":
    main()
