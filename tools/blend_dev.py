#!/usr/bin/env python3
"""Does `leovr adapt`'s masked task (no ground truth) rank network / prior blends as the held-out beams do?

On the KITTI raw clip's development frames 0-37 only (never the inductive test frames 38-47): the MAE of
exp(w log network + (1 - w) log prior) for w in 1, 0.75, ..., 0 (selfsup.adapt.BLENDS), once at the
hidden returns of adapt's masked splits (`selfsup.adapt.choose_blend` on every development frame) and once
at the held-out beams (every 2nd frame).

    .venv/bin/python tools/blend_dev.py vlp16|mid40 [CHECKPOINT]
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from leovr.config import AdaptConfig, RefineConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.network import blend_log_depth
from leovr.depth.prior import interpolated_at
from leovr.depth.runtime import for_inference
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from selfsup.adapt import BLENDS, choose_blend, input_frames


def main() -> None:
    inp = sys.argv[1]
    ck = sys.argv[2] if len(sys.argv) > 2 else shipped_checkpoint()
    seq = open_sequence(kitti_raw_dir())
    model = load_generator(ck)
    # what adapt sees, on every development frame's masked splits instead of its validation frames only
    masked = choose_blend(model, input_frames([seq], AdaptConfig(input=inp, end=38), progress=False))[1]
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
    net, pri, tgt = (torch.from_numpy(np.concatenate(x)) for x in (net, pri, tgt))
    beams = {w: float((blend_log_depth(net, pri, w) - tgt).abs().mean()) for w in BLENDS}
    print(inp, ck, "masked task:", {w: round(e, 3) for w, e in masked.items()},
          "held-out beams:", {w: round(e, 3) for w, e in beams.items()})


if __name__ == "__main__":
    main()
