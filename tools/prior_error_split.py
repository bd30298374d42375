#!/usr/bin/env python3
"""Where the classical prior's error lies on the real KITTI raw clip (development frames 0-37 only; the
inductive test frames 38-47 of `leovr bench real` are never read): held-out pixels inside a Delaunay
triangle of the cheap input whose corner depths agree ("smooth"), inside one that spans a depth edge
(corner depths differ by EDGE_RATIO or more: the prior takes the nearest return there), and outside
the input's hull. Per group: pixel count and MAE of the nearest fill, the prior, the shipped generator,
and the best corner of the triangle (an oracle: what a perfect foreground / background choice would give).

    .venv/bin/python tools/prior_error_split.py [--input vlp16] [--step 3]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.spatial import Delaunay

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.prior import EDGE_RATIO, interpolated_at
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--step", type=int, default=3)
    ap.add_argument("--dev-end", type=int, default=38)
    a = ap.parse_args()
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    model = load_generator(shipped_checkpoint())
    err: dict[str, dict[str, float]] = {}
    count: dict[str, int] = {}
    for i in range(0, a.dev_end, a.step):
        s = frame_sample(seq, i, ccfg)
        rows, cols = np.nonzero(s.gt > 0)
        gt = s.gt[rows, cols]
        img = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, 2)
        preds = {"nearest": nearest_fill(s.sparse)[rows, cols], "prior": interpolated_at(s.sparse, rows, cols),
                 "generator": predict_at_focal(model, img, s.sparse, float(s.frame.K[0, 0]), ccfg.generator_focal_px)[0][rows, cols]}
        v, u = np.nonzero(s.sparse > 0)
        tri = Delaunay(np.stack([u, v], 1).astype(float))
        simplex = tri.find_simplex(np.stack([cols, rows], 1).astype(float))
        corners = s.sparse[v, u][tri.simplices[np.maximum(simplex, 0)]]
        edge = corners.max(1) >= EDGE_RATIO * corners.min(1)
        groups = {"all": np.ones(len(gt), bool), "smooth": (simplex >= 0) & ~edge, "edge": (simplex >= 0) & edge,
                  "outside": simplex < 0}
        preds["oracle_corner"] = np.where(simplex >= 0, corners[np.arange(len(gt)), np.abs(corners - gt[:, None]).argmin(1)],
                                          preds["nearest"])
        for g, sel in groups.items():
            count[g] = count.get(g, 0) + int(sel.sum())
            for name, p in preds.items():
                err.setdefault(g, {}).setdefault(name, 0.0)
                err[g][name] += float(np.abs(p[sel] - gt[sel]).sum())
    total = err["all"]["prior"]
    out = {g: {"pixels": count[g], "share_of_prior_error": round(err[g]["prior"] / total, 3)}
           | {f"{name}_mae_m": round(e / max(count[g], 1), 3) for name, e in d.items()} for g, d in err.items()}
    print(json.dumps({"input": a.input, "frames": f"0-{a.dev_end - 1} step {a.step}", "groups": out}, indent=1))


if __name__ == "__main__":
    main()
