#!/usr/bin/env python3
"""Measure a generator checkpoint's int8 calibration table on simulator training frames and store it in
the checkpoint (`int8_ranges`), for `generator_runtime: onnxruntime_int8` (leovr.depth.quantize).

Only the training split is read (never validation or test sequences, never the real clips): every
`--step`-th frame of each training sequence, own scan as input, at the generator's focal length, as
inference runs it.

    .venv/bin/python tools/calibrate_int8.py                       # the shipped checkpoint
    .venv/bin/python tools/calibrate_int8.py --checkpoint runs/x/best.pt
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from leovr.config import CompleteConfig
from leovr.data import open_sequence
from leovr.data.io import atomic_write
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.runtime import InputRecorder, calibrate_generator
from leovr.paths import shipped_checkpoint
from leovr.pipeline.completion import prepare_sample
from leovr.sim.dataset import default_root


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped generator")
    ap.add_argument("--recipe", default="default", help="simulator dataset recipe (its train split is read)")
    ap.add_argument("--sequences", type=int, default=12, help="training sequences, spread over the split")
    ap.add_argument("--step", type=int, default=10, help="every n-th frame of each")
    ap.add_argument("--focal", type=float, default=260.0, help="the generator's focal length (px)")
    args = ap.parse_args()
    path = args.checkpoint or shipped_checkpoint()
    train = default_root() / args.recipe / "train"
    names = sorted(p.name for p in train.iterdir() if p.is_dir())
    if not names:
        raise SystemExit(f"{train}: no training sequences (run tools/make_dataset.py --recipe {args.recipe})")
    pick = names[:: max(1, len(names) // args.sequences)][: args.sequences]
    recorder = InputRecorder(load_generator(path))
    own_scan = CompleteConfig(input="full")
    t0 = time.time()
    for name in pick:
        seq = open_sequence(train / name)
        for i in range(0, len(seq), args.step):
            s = prepare_sample(seq[i], own_scan)
            predict_at_focal(recorder, s.frame.image, s.sparse, float(s.frame.K[0, 0]), args.focal, True)
    ranges = calibrate_generator(recorder.model, recorder.feeds)
    state = torch.load(path, map_location="cpu", weights_only=False)
    state["int8_ranges"] = ranges
    atomic_write(path, lambda tmp: torch.save(state, tmp))
    print(
        f"{path}: int8 ranges of {len(ranges['data'])} tensors from {len(recorder.feeds)} frames of "
        f"{len(pick)} training sequences ({time.time() - t0:.0f} s)"
    )


if __name__ == "__main__":
    main()
