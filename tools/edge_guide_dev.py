#!/usr/bin/env python3
"""What a pixel inside a depth-edge triangle of the classical prior should take (issue 14, development only).

The prior (leovr.depth.prior) interpolates inside smooth Delaunay triangles of the cheap input; a triangle
whose corner depths differ by EDGE_RATIO (1.5) or more counts as a depth edge. Rules scored on its pixels:
- `corner`: the corner nearest the image-guided fit (OpenCV's EdgeAwareInterpolator), where it is nearer
  that fit than the nearest return (the rule before session 41);
- `fit_clamped`: the fit's own depth, clamped to the corners' range;
- `fit_between<T>`: the fit's own depth where it lies strictly between the corners and their ratio is
  below T, else `corner` (shipped with T = leovr.depth.prior.EDGE_GUIDE_MAX_RATIO);
- `plane_between3`: the same pixels, but the triangle's planar (inverse-depth affine) value.
Data: `kitti` the KITTI raw clip's frames 0-36 step 2 (never the inductive test frames 38-47), held-out
beams with the evaluation's parallax filter, or all of them (`--no-filter`); `sim` the simulator's day
validation drives (seeds 2000-2002, every 4th frame, each drive's own scan, dense truth).

    .venv/bin/python tools/edge_guide_dev.py kitti --input vlp16 [--no-filter]
    .venv/bin/python tools/edge_guide_dev.py sim --lidar vlp16
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth import prior as P
from leovr.depth.dataset import split_entries
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root


def edge_rules(sparse: np.ndarray, rows: np.ndarray, cols: np.ndarray, image: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """Each rule's depth at (rows, cols), the indices of the edge-triangle pixels, and their corner ratio."""
    valid = sparse > 0
    tri = P.triangle_lookup(sparse, rows, cols)
    out, edge, z, g, c, simplex = tri.depth.astype(np.float64), tri.edge, tri.z, tri.g, tri.c, tri.simplex
    guide = P.edge_aware_log_depth(sparse, image)[rows[edge], cols[edge]]
    edge, guide = edge[np.isfinite(guide)], guide[np.isfinite(guide)]
    zc = z[simplex[edge]]
    cost = np.abs(np.log(zc) - guide[:, None])
    switch = cost.min(1) < np.abs(np.log(out[edge]) - guide)
    corner = out.copy()
    corner[edge[switch]] = zc[np.arange(len(edge)), cost.argmin(1)][switch]
    lo, hi = np.log(zc.min(1)), np.log(zc.max(1))
    ratio = zc.max(1) / zc.min(1)
    between = (guide > lo) & (guide < hi)
    rules = {"corner": corner}
    rules["fit_clamped"] = corner.copy()
    rules["fit_clamped"][edge] = np.exp(np.clip(guide, lo, hi))
    for t in (2.0, 3.0, 4.0, np.inf):
        m = between & (ratio < t)
        rules[f"fit_between{t:g}"] = corner.copy()
        rules[f"fit_between{t:g}"][edge[m]] = np.exp(guide[m])
    se = simplex[edge]
    plane = 1.0 / np.maximum(g[se, 0] * cols[edge] + g[se, 1] * rows[edge] + c[se], 1e-6)
    m = between & (ratio < 3.0) & np.isfinite(plane)
    rules["plane_between3"] = corner.copy()
    rules["plane_between3"][edge[m]] = plane[m]
    measured = valid[rows, cols]
    for r in rules.values():
        r[measured] = sparse[rows[measured], cols[measured]]
    return rules, edge, ratio


def frames(a: argparse.Namespace):
    """(sparse input, image, rows, cols, truth) of every scored frame."""
    if a.data == "kitti":
        seq = open_sequence(kitti_raw_dir())
        ccfg = completion_config(RefineConfig(input=a.input))
        for i in range(0, 38, 2):
            s = frame_sample(seq, i, ccfg)
            gt = s.gt
            if a.no_filter:
                f = s.frame
                held = simulate_cheap_sensor(f.points, parse_input(ccfg.input), f.index, ccfg.seed, f.K, f.T_cam_lidar,
                                             f.shape).heldout
                gt = sparse_depth(held, f.K, f.T_cam_lidar, f.shape)
            r, c = np.nonzero(gt > 0)
            yield s.sparse, s.frame.image, r, c, gt[r, c]
        return
    for e in split_entries(default_root() / "default", "val"):
        if e["lidar"] != a.lidar or "night" in str(e["path"]):
            continue
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), 4):
            f = seq[i]
            r, c = np.nonzero(f.depth > 0)
            yield sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape), f.image, r, c, f.depth[r, c]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", choices=["kitti", "sim"])
    ap.add_argument("--input", default="vlp16", help="kitti: the cheap input simulated from the HDL-64 scan")
    ap.add_argument("--lidar", default="vlp16", help="sim: the validation drives' sensor")
    ap.add_argument("--no-filter", action="store_true", help="kitti: every held-out beam, no parallax filter")
    a = ap.parse_args()
    err: dict[str, np.ndarray] = {}
    n = np.zeros(4)  # pixels: all, edge, edge with ratio < 3, edge with ratio >= 3
    for sparse, image, r, c, gt in frames(a):
        rules, edge, ratio = edge_rules(sparse, r, c, image)
        groups = [slice(None), edge, edge[ratio < 3], edge[ratio >= 3]]
        n += [len(gt), len(edge), (ratio < 3).sum(), (ratio >= 3).sum()]
        for name, d in rules.items():
            err[name] = err.get(name, np.zeros(4)) + [np.abs(d[g] - gt[g]).sum() for g in groups]
    print(json.dumps({"data": a.data, "input": a.input if a.data == "kitti" else a.lidar, "parallax_filter": not a.no_filter,
                      "pixels": dict(zip(["all", "edge", "edge_ratio_below_3", "edge_ratio_3_up"], n.astype(int).tolist())),
                      "mae_m": {k: dict(zip(["all", "edge", "edge_ratio_below_3", "edge_ratio_3_up"], np.round(e / np.maximum(n, 1), 4).tolist()))
                                for k, e in err.items()}}, indent=1))


if __name__ == "__main__":
    main()
