#!/usr/bin/env python3
"""Choose `leovr adapt` settings on a development split of the KITTI raw clip, never on its test frames.

Adapts on frames [0, --adapt-end) of the clip with the given AdaptConfig overrides, then scores the
start and adapted generators and the nearest fill on the held-out beams of frames [--adapt-end,
--dev-end) (the generator alone, no graph). Frames from --dev-end on (38-47: the inductive test frames
of `leovr bench real`) are never read. Appends one JSON line per run to --log.

    .venv/bin/python tools/adapt_dev.py --name anchor --set anchor_weight=1.0 [--input vlp16]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml

from leovr.config import AdaptConfig, RefineConfig
from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from selfsup.adapt import adapt


def scores(seq, frames: range, inp: str, models: dict, focal: float | None) -> dict:
    """MAE (m) of each model and the nearest fill at the held-out beams, pooled over `frames`, with the
    0-20 m and >20 m bins."""
    ccfg = completion_config(RefineConfig(input=inp))
    err: dict[str, dict[str, float]] = {}
    count = {"all": 0, "0-20": 0, "20+": 0}
    for i in frames:
        s = frame_sample(seq, i, ccfg)
        pick = s.gt > 0
        gt = s.gt[pick]
        bins = {"all": np.ones(len(gt), bool), "0-20": gt < 20, "20+": gt >= 20}
        img = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, 2)
        preds = {"nearest": nearest_fill(s.sparse)[pick]}
        for name, m in models.items():
            preds[name] = predict_at_focal(m, img, s.sparse, float(s.frame.K[0, 0]), focal)[0][pick]
        for b, sel in bins.items():
            count[b] += int(sel.sum())
            for name, p in preds.items():
                err.setdefault(name, {}).setdefault(b, 0.0)
                err[name][b] += float(np.abs(p[sel] - gt[sel]).sum())
    return {name: {b: e / max(count[b], 1) for b, e in d.items()} for name, d in err.items()} | {"n": count}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", required=True)
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--set", nargs="*", default=[], help="AdaptConfig overrides key=value (YAML values)")
    ap.add_argument("--adapt-end", type=int, default=30)
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--work", type=Path, default=Path("runs/adapt_dev"))
    ap.add_argument("--log", type=Path, default=Path("runs/adapt_dev.jsonl"))
    args = ap.parse_args()
    over = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.set)}
    cfg = AdaptConfig(input=args.input, end=args.adapt_end, **over)
    seq = open_sequence(kitti_raw_dir())
    t0 = time.time()
    out = args.work / f"{args.input}_{args.name}"
    record = adapt([seq], cfg, out, resume=True, progress=False)
    minutes = (time.time() - t0) / 60
    models = {"start": load_generator(shipped_checkpoint()), "adapted": load_generator(out / "generator.pt")}
    res = scores(seq, range(args.adapt_end, args.dev_end), args.input, models, cfg.generator_focal_px)
    line = {"name": args.name, "input": args.input, "overrides": over, "adapt": record, "wall_minutes": round(minutes, 2),
            "dev_frames": [args.adapt_end, args.dev_end - 1], "scores": res,
            "adapted_vs_nearest": res["adapted"]["all"] / res["nearest"]["all"],
            "start_vs_nearest": res["start"]["all"] / res["nearest"]["all"]}
    args.log.parent.mkdir(parents=True, exist_ok=True)
    with open(args.log, "a") as fh:
        fh.write(json.dumps(line) + "\n")
    print(json.dumps(line, indent=1))


if __name__ == "__main__":
    main()
