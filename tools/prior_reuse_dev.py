#!/usr/bin/env python3
"""Can a KITTI-size frame compute its classical prior once instead of twice? (issue 17, development only)

A frame larger than the generator's training focal length runs the network on a resampled copy: today
the prior is built twice, for the small input (the network's) and at full resolution (the one combined
with the network's upsampled residual). Arms, scored by the generator's MAE at the held-out beams:
- `twice`: the prior built on the small map for the network and again at full resolution (shipped
  before session 42);
- `sampled`: the full-resolution prior only; the network's input prior is it read at the small pixels
  (leovr.depth.inference.sampled_prior; shipped since session 42: predict_parts_full);
- `guide_small`: both priors, the full one with the image guide (EdgeAwareInterpolator) computed on the
  small frame and resized up, so the interpolator runs once.
Data: the KITTI raw clip's frames [0, --end) (default 38; never the inductive test frames 38-47).
`--prior-threads`: instead, the full-resolution prior alone (leovr.depth.prior.interpolated_fill with the
image) timed with OpenCV limited to one thread (everything in this thread) and to two (the image guide in
its helper thread beside the triangle lookup), and whether the two outputs are identical.

    .venv/bin/python tools/prior_reuse_dev.py --input vlp16 [--step 1]
    .venv/bin/python tools/prior_reuse_dev.py --prior-threads --step 2
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth import prior as P
from leovr.depth.inference import _pad32, load_generator, predict_parts_full, rescale_sparse
from leovr.depth.network import prior_for
from leovr.depth.runtime import for_inference
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.refine import completion_config, frame_sample


@torch.no_grad()
def run(model, image: np.ndarray, sparse: np.ndarray, scale: float, arm: str) -> np.ndarray:
    h, w = sparse.shape
    shape = (int(round(h * scale)), int(round(w * scale)))
    small = cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    ss = rescale_sparse(sparse, scale, shape)
    if arm == "sampled":
        return predict_parts_full(model, small, ss, sparse, scale, image)[0]
    img = torch.from_numpy(small).permute(2, 0, 1)[None].float() / 255.0
    sp = torch.from_numpy(ss)[None, None]
    sp_full = torch.from_numpy(np.ascontiguousarray(sparse, np.float32))[None, None]
    if arm == "twice":
        prior_small = prior_for(sp, img)
        prior_full = P.interpolated_fill(sparse, image=image)
    else:  # guide_small
        prior_small = prior_for(sp, img)
        guide = P.edge_aware_log_depth(ss, small)
        big = cv2.resize(guide, (w, h), interpolation=cv2.INTER_LINEAR)
        orig = P.edge_aware_log_depth
        P.edge_aware_log_depth = lambda s, i: big
        try:
            prior_full = P.interpolated_fill(sparse, image=image)
        finally:
            P.edge_aware_log_depth = orig
    image_p, sparse_p, prior_p = _pad32(img, sp, prior_small)
    parts = {k: v[..., :shape[0], :shape[1]] for k, v in model.parts(image_p, sparse_p, prior_p).items()}
    full = {k: F.interpolate(v, size=(h, w), mode="bilinear", align_corners=False) for k, v in parts.items()}
    return model.combine(full, torch.from_numpy(prior_full)[None, None], sp_full)[0, 0].numpy()


def prior_threads(a: argparse.Namespace) -> None:
    """Median ms of the full-resolution prior with OpenCV at one and at two threads; outputs identical?"""
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    ms: dict[int, list[float]] = {1: [], 2: []}
    same = True
    for i in range(0, a.end, a.step):
        s = frame_sample(seq, i, ccfg)
        maps = {}
        for threads in (1, 2):
            cv2.setNumThreads(threads)
            t0 = time.perf_counter()
            maps[threads] = P.interpolated_fill(s.sparse, image=s.frame.image)
            ms[threads].append((time.perf_counter() - t0) * 1000)
        same &= bool(np.array_equal(maps[1], maps[2]))
    print(json.dumps({"input": a.input, "frames": f"0-{a.end - 1} step {a.step}",
                      "median_ms": {f"opencv_threads_{k}": round(float(np.median(v)), 1) for k, v in ms.items()},
                      "identical": same}))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--input", default="vlp16")
    ap.add_argument("--end", type=int, default=38)
    ap.add_argument("--step", type=int, default=1)
    ap.add_argument("--arms", nargs="*", default=["twice", "sampled", "guide_small"])
    ap.add_argument("--prior-threads", action="store_true")
    a = ap.parse_args()
    assert a.end <= 38, "frames 38-47 are the inductive test frames"
    if a.prior_threads:
        prior_threads(a)
        return
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    seq = open_sequence(kitti_raw_dir())
    ccfg = completion_config(RefineConfig(input=a.input))
    model = for_inference(load_generator(shipped_checkpoint()))
    err = {k: 0.0 for k in a.arms}
    ms: dict[str, list[float]] = {k: [] for k in a.arms}
    n = 0
    for i in range(0, a.end, a.step):
        s = frame_sample(seq, i, ccfg)
        scale = ccfg.generator_focal_px / float(s.frame.K[0, 0])
        pick = s.gt > 0
        for arm in a.arms:
            t0 = time.perf_counter()
            d = run(model, s.frame.image, s.sparse, scale, arm)
            ms[arm].append((time.perf_counter() - t0) * 1000)
            err[arm] += float(np.abs(d[pick] - s.gt[pick]).sum())
        n += int(pick.sum())
    print(json.dumps({"input": a.input, "frames": f"0-{a.end - 1} step {a.step}", "points": n,
                      "mae_m": {k: round(e / n, 4) for k, e in err.items()},
                      "median_ms": {k: round(float(np.median(v)), 1) for k, v in ms.items()}}))


if __name__ == "__main__":
    main()
