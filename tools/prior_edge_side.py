#!/usr/bin/env python3
"""The prior's side choice at depth edges, with and without the camera image, on the real KITTI raw clip's
development frames (0-37 only; the inductive test frames 38-47 of `leovr bench real` are never read).
Held-out pixels inside a Delaunay triangle of the cheap input that spans a depth edge ("edge"), and all
held-out pixels: MAE of the nearest fill, the prior without the image (nearest return at edges), the
prior with it (leovr.depth.prior: the corner nearest an edge-aware interpolation), and the best corner
(an oracle). `--set K=.. LAMBDA=.. SIGMA=..` overrides the edge-aware interpolation's settings.

    .venv/bin/python tools/prior_edge_side.py [--input vlp16] [--step 2] [--set K=64 ...]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.spatial import Delaunay

from leovr.depth import prior
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--step", type=int, default=2)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--set", nargs="*", default=[], help="K=, LAMBDA=, SIGMA= of the edge-aware interpolation")
    a = ap.parse_args()
    for kv in a.set:
        k, v = kv.split("=")
        setattr(prior, f"EDGE_AWARE_{k.upper()}", type(getattr(prior, f"EDGE_AWARE_{k.upper()}"))(float(v)))
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
        v, u = np.nonzero(s.sparse > 0)
        tri = Delaunay(np.stack([u, v], 1).astype(float))
        simplex = tri.find_simplex(np.stack([cols, rows], 1).astype(float))
        corners = s.sparse[v, u][tri.simplices[np.maximum(simplex, 0)]]
        edge = (simplex >= 0) & (corners.max(1) >= prior.EDGE_RATIO * corners.min(1))
        preds["oracle_corner"] = np.where(edge, corners[np.arange(len(gt)), np.abs(corners - gt[:, None]).argmin(1)],
                                          preds["prior"])
        for g, sel in {"all": np.ones(len(gt), bool), "edge": edge}.items():
            count[g] = count.get(g, 0) + int(sel.sum())
            for name, p in preds.items():
                err.setdefault(g, {}).setdefault(name, 0.0)
                err[g][name] += float(np.abs(p[sel] - gt[sel]).sum())
    out = {g: {"pixels": count[g]} | {f"{n}_mae_m": round(e / max(count[g], 1), 4) for n, e in d.items()}
           for g, d in err.items()}
    print(json.dumps({"input": a.input, "frames": f"0-{a.dev_end - 1} step {a.step}", "set": a.set,
                      "prior_image_ms": round(float(np.median(ms)), 1), "groups": out}, indent=1))


if __name__ == "__main__":
    main()
