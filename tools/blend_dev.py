#!/usr/bin/env python3
"""Does `leovr adapt`'s masked task (no ground truth) rank network / prior blends as the held-out beams do?

On the KITTI raw clip's development frames 0-37 only (never the inductive test frames 38-47): the MAE of
exp(w log network + (1 - w) log prior) for w in 0, 0.25, ..., 1, once at the hidden returns of adapt's
masked splits (what `selfsup.adapt.choose_blend` sees) and once at the held-out beams (every 2nd frame).

    .venv/bin/python tools/blend_dev.py vlp16|mid40 [CHECKPOINT]
"""

from __future__ import annotations

import sys

import numpy as np
import torch
import torch.nn.functional as F

from leovr.config import AdaptConfig, RefineConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.prior import interpolated_at
from leovr.depth.runtime import for_inference
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from selfsup.adapt import _forward, batches, input_frames

WEIGHTS = (0.0, 0.25, 0.5, 0.75, 1.0)


def blend_mae(net: np.ndarray, prior: np.ndarray, target: np.ndarray) -> dict[float, float]:
    return {w: round(float(np.abs(np.exp(w * np.log(net) + (1 - w) * np.log(prior)) - target).mean()), 3) for w in WEIGHTS}


def main() -> None:
    inp = sys.argv[1]
    ck = sys.argv[2] if len(sys.argv) > 2 else shipped_checkpoint()
    seq = open_sequence(kitti_raw_dir())
    model = load_generator(ck)
    frames = input_frames([seq], AdaptConfig(input=inp, end=38), progress=False)
    net, pri, tgt = [], [], []
    with torch.no_grad():
        for b in batches([(fr, s) for fr in frames for s in fr.splits], 4):
            parts = _forward(model, torch.stack([fr.image for fr, _ in b]), torch.stack([s.sparse for _, s in b]),
                             torch.stack([s.prior for _, s in b]))
            for k, (_, s) in enumerate(b):
                at = {n: F.grid_sample(v[k:k + 1], s.grid[None, None], mode="bilinear", align_corners=False) for n, v in parts.items()}
                net.append(model.combine(at, s.prior_at.view(1, 1, 1, -1), s.measured_at.view(1, 1, 1, -1)).view(-1).numpy())
                pri.append(s.prior_at.numpy())
                tgt.append(s.target.numpy())
    masked = blend_mae(*map(np.concatenate, (net, pri, tgt)))
    ccfg = completion_config(RefineConfig(input=inp))
    run = for_inference(model)
    net, pri, tgt = [], [], []
    for i in range(0, 38, 2):
        s = frame_sample(seq, i, ccfg)
        rows, cols = np.nonzero(s.gt > 0)
        img = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, 2)
        net.append(predict_at_focal(run, img, s.sparse, float(s.frame.K[0, 0]), ccfg.generator_focal_px, True)[0][rows, cols])
        pri.append(interpolated_at(s.sparse, rows, cols, image=img))
        tgt.append(s.gt[rows, cols])
    print(inp, ck, "masked task:", masked, "held-out beams:", blend_mae(*map(np.concatenate, (net, pri, tgt))))


if __name__ == "__main__":
    main()
