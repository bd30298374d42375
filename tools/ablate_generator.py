#!/usr/bin/env python3
"""Ablation of the depth generator on the simulator test split (seeds never used for training):

- cross-attention on/off and partial convolutions vs a pre-interpolated LiDAR input, each variant
  trained with the same short schedule (configs/ablation/*.yaml, tools/train_ablation.sh);
- injection ratios 0.005, 0.01, 0.03, 0.1 of the ground-truth pixels as input (SLIM Table 2 layout);
- day vs night, with each sequence's own Mid-40 / VLP-16 scan as input.

Writes JSON and prints the Markdown tables that docs/benchmarks.md carries.

    .venv/bin/python tools/ablate_generator.py [--step 4] [--out docs/results/ablation.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.depth.dataset import split_entries
from leovr.depth.inference import load_generator, predict
from leovr.eval.depth_metrics import metrics_from_arrays
from leovr.lidar.projection import sparse_depth
from leovr.paths import shipped_checkpoint
from leovr.sim.dataset import default_root

RATIOS = (0.005, 0.01, 0.03, 0.1)
VARIANTS = {
    "full (partial conv + cross-attention)": "runs/ablation_full/best.pt",
    "no cross-attention": "runs/ablation_no_attention/best.pt",
    "pre-interpolated LiDAR input": "runs/ablation_interp/best.pt",
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", type=Path, default=default_root() / "default")
    ap.add_argument("--step", type=int, default=4, help="every n-th test frame")
    ap.add_argument("--out", type=Path, default=Path("docs/results/ablation.json"))
    args = ap.parse_args()
    models = {name: load_generator(p) for name, p in VARIANTS.items() if Path(p).is_file()}
    models["shipped generator"] = load_generator(shipped_checkpoint())
    conds = [f"{lidar}_{light}" for lidar in ("mid40", "vlp16") for light in ("day", "night")] + [f"ratio_{r}" for r in RATIOS]
    pairs = {m: {c: ([], []) for c in conds} for m in models}
    frames = 0
    for e in split_entries(args.dataset, "test"):
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), args.step):
            f = seq[i]
            frames += 1
            gt = f.depth.astype(np.float32)
            valid = gt > 0
            rgb = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, axis=2)
            inputs = {f"{e['lidar']}_{e['light']}": sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)}
            rng = np.random.default_rng([e["seed"], i, len(e["lidar"])])
            u = rng.random(gt.shape)
            if e["light"] == "day":  # ratio inputs on day frames only (SLIM's setting)
                inputs.update({f"ratio_{r}": np.where(u < r, gt, 0.0).astype(np.float32) for r in RATIOS})
            for name, model in models.items():
                for c, sp in inputs.items():
                    d = predict(model, rgb, sp)[0]
                    pairs[name][c][0].append(d[valid])
                    pairs[name][c][1].append(gt[valid])
    results = {}
    for name, per in pairs.items():
        results[name] = {}
        for c, (p, g) in per.items():
            if p:
                m = metrics_from_arrays(np.concatenate(p).astype(np.float64), np.concatenate(g).astype(np.float64))
                results[name][c] = {k: m[k] for k in ("mae_m", "rmse_m", "absrel", "delta1", "n")}
    doc = {"dataset": str(args.dataset), "split": "test", "frame_step": args.step, "frames": frames,
           "checkpoints": {**{k: v for k, v in VARIANTS.items() if k in models}, "shipped generator": str(shipped_checkpoint())},
           "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"test frames: {frames} (every {args.step}th)\n")
    print("| model | Mid-40 day | Mid-40 night | VLP-16 day | VLP-16 night |  (MAE m)")
    print("|---|---|---|---|---|")
    for name, r in results.items():
        print(f"| {name} | " + " | ".join(f"{r[c]['mae_m']:.3f}" for c in conds[:4]) + " |")
    print("\n| LiDAR encoder | " + " | ".join(f"ratio {x}" for x in RATIOS) + " |  (MAE / RMSE m)")
    print("|---" * (1 + len(RATIOS)) + "|")
    for name, r in results.items():
        print(f"| {name} | " + " | ".join(f"{r[f'ratio_{x}']['mae_m']:.3f} / {r[f'ratio_{x}']['rmse_m']:.3f}"
                                           for x in RATIOS) + " |")
    print(f"\n-> {args.out}")


if __name__ == "__main__":
    main()
