#!/usr/bin/env python3
"""Choose the classical prior's depth-edge ratio on the simulator's *validation* split (never on the
KITTI clip the benchmarks report): MAE of `interpolated_fill` for several ratios, each sequence's own
LiDAR scan (Mid-40 and VLP-16, day and night) and the uniform-ratio inputs the generator trains on.

    .venv/bin/python tools/prior_edge_ratio.py [--step 4] [--out runs/prior_edge_ratio.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.depth.dataset import split_entries
from leovr.depth.prior import interpolated_fill
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.lidar.projection import sparse_depth
from leovr.sim.dataset import default_root

RATIOS = (1.1, 1.25, 1.5, 2.0, 3.0, float("inf"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=int, default=8, help="every n-th frame of each validation sequence")
    ap.add_argument("--out", type=Path, default=Path("runs/prior_edge_ratio.json"))
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    accs: dict[str, dict[str, DepthMetricAccumulator]] = {}
    for e in split_entries(default_root() / "default", "val"):
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), args.step):
            f = seq[i]
            inputs = {e["lidar"]: sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)}
            inputs["ratio"] = np.where(rng.random(f.depth.shape) < rng.uniform(0.005, 0.05), f.depth, 0).astype(np.float32)
            for name, sp in inputs.items():
                a = accs.setdefault(name, {})
                a.setdefault("nearest", DepthMetricAccumulator()).add(nearest_fill(sp), f.depth)
                for r in RATIOS:
                    a.setdefault(f"interp_{r:g}", DepthMetricAccumulator()).add(interpolated_fill(sp, r), f.depth)
    res = {name: {m: round(acc.result()["mae_m"], 4) for m, acc in a.items()} for name, a in accs.items()}
    # criterion: the lowest mean MAE relative to the nearest fill over the input kinds
    rel = {f"interp_{r:g}": float(np.mean([res[n][f"interp_{r:g}"] / res[n]["nearest"] for n in res])) for r in RATIOS}
    res["mean_vs_nearest"] = {k: round(v, 4) for k, v in rel.items()}
    res["chosen"] = min(rel, key=rel.get)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
