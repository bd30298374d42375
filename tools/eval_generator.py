#!/usr/bin/env python3
"""Compare nearest fill, IP-Basic (with and without its final hole fill) and the shipped generator on
the same validation frames (the ones the trainer validates on), with MAE and time per frame measured
in one run.

    .venv/bin/python tools/eval_generator.py [--dataset DIR] [--frames 120] [--checkpoint PATH]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from leovr.depth.classical import IPBasicConfig, ipbasic, nearest_fill
from leovr.depth.dataset import DepthSamples, split_sequences
from leovr.depth.inference import load_generator, predict
from leovr.depth.prior import interpolated_fill
from leovr.paths import shipped_checkpoint
from leovr.sim.dataset import default_root


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", type=Path, default=default_root() / "default")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--seed", type=int, default=1, help="the trainer's validation seed (train seed + 1)")
    ap.add_argument("--checkpoint", type=Path, default=shipped_checkpoint())
    args = ap.parse_args()
    model = load_generator(args.checkpoint)
    samples = DepthSamples(
        split_sequences(args.dataset, "val"), max_frames=args.frames, seed=args.seed, random_input=False
    )
    methods = {
        "nearest": lambda img, sp: nearest_fill(sp),
        "ipbasic": lambda img, sp: ipbasic(sp),
        "ipbasic_without_final_fill": lambda img, sp: ipbasic(sp, IPBasicConfig(fill_remaining=False)),
        "interp": lambda img, sp: interpolated_fill(sp),  # the classical prior, nearest return at depth edges
        "interp_image": lambda img, sp: interpolated_fill(sp, image=img),  # the image's side (the generator's prior)
        "generator": lambda img, sp: predict(model, img, sp)[0],
    }
    err = {m: 0.0 for m in methods}
    secs = {m: 0.0 for m in methods}
    n = 0
    for j in range(len(samples)):
        b = samples[j]
        img = (b["image"].permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
        sp, gt = b["sparse"][0].numpy(), b["gt"][0].numpy()
        valid = gt > 0
        n += int(valid.sum())
        for m, fn in methods.items():
            t0 = time.perf_counter()
            d = fn(img, sp)
            secs[m] += time.perf_counter() - t0
            err[m] += float(np.abs(np.where(valid, d, 0) - gt)[valid].sum())  # empty predictions count in full
    out = {
        m: {
            "mae_m": err[m] / n,
            "ms_per_frame": 1000 * secs[m] / len(samples),
            "time_vs_ipbasic": secs[m] / secs["ipbasic"],
        }
        for m in methods
    }
    print(json.dumps({"frames": len(samples), "pixels": n, "results": out}, indent=2))


if __name__ == "__main__":
    main()
