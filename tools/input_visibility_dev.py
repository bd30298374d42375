#!/usr/bin/env python3
"""Does dropping cheap-input returns the camera may not see help the depth? (issue 14, development only)

The LiDAR sits 0.27 m behind and 0.08 m above the camera, so near object edges it sees background the
camera cannot; those returns land on foreground pixels. The evaluation drops such held-out points from
the ground truth (a nearer return within 7 x 7 px, `leovr.eval.heldout.parallax_filter`). This tool
applies the same window filter to the cheap input itself (each return against the input's own returns,
`--windows`, square, pixels at the frame's resolution, nearer by more than `--rel`) and scores the
nearest fill, the classical prior and the shipped generator with and without it:
- `kitti`: the KITTI raw clip's development frames 0-37 (every `--step`-th), held-out beams, parallax-
  filtered (the inductive test frames 38-47 are never read);
- `sim`: the simulator's day validation drives (seeds 2000-2002, each drive's own scan, dense rendered
  truth at every pixel, so a filter that also drops visible background is charged for it).

    .venv/bin/python tools/input_visibility_dev.py kitti --input vlp16 --windows 9 15 21
    .venv/bin/python tools/input_visibility_dev.py sim --lidar vlp16 --windows 3 5 7
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth import prior
from leovr.depth.classical import nearest_fill
from leovr.depth.dataset import split_entries
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.runtime import for_inference
from leovr.eval.heldout import parallax_filter
from leovr.lidar.projection import sparse_depth
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root


def frames(a: argparse.Namespace):
    """(image, sparse input, rows, cols, truth, focal, model focal) of every scored frame."""
    if a.data == "kitti":
        seq = open_sequence(kitti_raw_dir())
        ccfg = completion_config(RefineConfig(input=a.input))
        for i in range(0, 38, a.step):
            s = frame_sample(seq, i, ccfg)
            r, c = np.nonzero(s.gt > 0)
            yield s.frame.image, s.sparse, r, c, s.gt[r, c], float(s.frame.K[0, 0]), ccfg.generator_focal_px
        return
    for e in split_entries(default_root() / "default", "val"):
        if e["lidar"] != a.lidar or "night" in str(e["path"]):
            continue
        seq = open_sequence(e["path"])
        for i in range(0, len(seq), a.step):
            f = seq[i]
            r, c = np.nonzero(f.depth > 0)
            yield f.image, sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape), r, c, f.depth[r, c], float(f.K[0, 0]), None


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", choices=["kitti", "sim"])
    ap.add_argument("--input", default="vlp16", help="kitti: the cheap input simulated from the HDL-64 scan")
    ap.add_argument("--lidar", default="vlp16", help="sim: the validation drives' sensor")
    ap.add_argument("--step", type=int, default=2)
    ap.add_argument("--windows", type=int, nargs="+", default=[15])
    ap.add_argument("--rel", type=float, default=0.15)
    a = ap.parse_args()
    model = for_inference(load_generator(shipped_checkpoint()), "onnxruntime_int8")
    names = ["none"] + [f"window {w}" for w in a.windows]
    err = {k: dict(nearest=0.0, prior=0.0, generator=0.0, returns_dropped=0.0) for k in names}
    pixels = returns = 0
    for image, sparse, r, c, gt, focal, model_focal in frames(a):
        pixels += len(gt)
        returns += int((sparse > 0).sum())
        for name, w in zip(names, [None] + a.windows):
            sp = sparse if w is None else parallax_filter(sparse, sparse, w, a.rel)
            e = err[name]
            e["returns_dropped"] += float((sparse > 0).sum() - (sp > 0).sum())
            e["nearest"] += float(np.abs(nearest_fill(sp)[r, c] - gt).sum())
            e["prior"] += float(np.abs(prior.interpolated_at(sp, r, c, image=image) - gt).sum())
            e["generator"] += float(np.abs(predict_at_focal(model, image, sp, focal, model_focal, True)[0][r, c] - gt).sum())
    table = {k: {m: round(v / (returns if m == "returns_dropped" else pixels), 4) for m, v in e.items()} for k, e in err.items()}
    print(json.dumps({"data": a.data, "input": a.input if a.data == "kitti" else a.lidar, "step": a.step, "rel": a.rel,
                      "pixels": pixels, "mae_m": table}, indent=1))


if __name__ == "__main__":
    main()
