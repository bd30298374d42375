#!/usr/bin/env python3
"""Micro-benchmarks behind the issue-17 steps in docs/benchmarks.md ("Refinement speed"), on one frame of a
development drive (never the bench drives): the network on torch vs ONNX Runtime (interleaved rounds), the
network right after the classical prior with BLAS threads free vs limited to one, the prior itself, and
one depth-consistency evaluation (300 samples, 8 x 14 field, with and without Jacobians).

    .venv/bin/python tools/speed_parts.py [SEQ] [--input full] [--frame 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from leovr.config import CompleteConfig
from leovr.data import open_sequence
from leovr.depth.inference import forward_padded, load_generator
from leovr.depth.network import prior_for
from leovr.depth.prior import interpolated_fill
from leovr.depth.runtime import for_inference
from leovr.geometry import make_T
from leovr.paths import shipped_checkpoint
from leovr.pipeline.completion import prepare_sample
from leovr.sim.dataset import default_root
from odometry.depth_field import CorrectionGrid
from odometry.factors import DepthConsistency, FrameDepth


def ms(fn, n: int = 8) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return 1000.0 * (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence", nargs="?", default=str(default_root() / "default" / "val" / "city_loop_mid40_day_s2000"))
    ap.add_argument("--input", default="full")
    ap.add_argument("--frame", type=int, default=5)
    a = ap.parse_args()
    sample = prepare_sample(open_sequence(a.sequence)[a.frame], CompleteConfig(method="generator", input=a.input))
    print(f"{a.sequence} frame {a.frame}: {sample.sparse.shape[1]}x{sample.sparse.shape[0]}, {(sample.sparse > 0).sum()} returns")
    model = load_generator(shipped_checkpoint())
    onnx = for_inference(model, "onnxruntime")
    img = torch.from_numpy(sample.frame.image).permute(2, 0, 1)[None].float().contiguous() / 255.0
    sp = torch.from_numpy(sample.sparse)[None, None]
    pr = prior_for(sp)
    with torch.inference_mode():
        rounds = {"torch": [], "onnxruntime": []}
        for _ in range(3):
            rounds["torch"].append(ms(lambda: forward_padded(model, img, sp, pr)))
            rounds["onnxruntime"].append(ms(lambda: forward_padded(onnx, img, sp, pr)))
        print("network (prior given), ms per round:", {k: [round(x) for x in v] for k, v in rounds.items()})
        for label, limit in (("BLAS threads free", None), ("BLAS single-threaded", 1)):
            with threadpool_limits(limits=limit, user_api="blas"):
                after = []
                for _ in range(8):
                    prior_for(sp)
                    t0 = time.perf_counter()
                    forward_padded(model, img, sp, pr)
                    after.append(1000.0 * (time.perf_counter() - t0))
                print(f"torch network right after the prior, {label}: {np.median(after):.0f} ms")
    with threadpool_limits(limits=1, user_api="blas"):
        print(f"prior (interpolated_fill): {ms(lambda: interpolated_fill(sample.sparse)):.1f} ms")
    h, w = sample.sparse.shape
    K = sample.frame.K
    rng = np.random.default_rng(0)
    log_depth = np.log(rng.uniform(5, 30, (h, w))).astype(np.float32)
    g = CorrectionGrid(8, 14, h, w)
    dc = DepthConsistency(FrameDepth(log_depth, g), FrameDepth(log_depth, g), K, 0.05)
    dc.set_samples(rng.uniform(0, w - 1, 300), rng.uniform(0, h - 1, 300))
    Ti, Tj, c = make_T(t=[0.2, -0.1, 1.0]), np.eye(4), np.zeros(g.size)
    print(f"depth consistency, 300 samples: with Jacobians {ms(lambda: dc.evaluate(Ti, Tj, c, c, True, poses=True), 300):.3f} ms, "
          f"residual only {ms(lambda: dc._residual(Ti, Tj, c, c), 300):.3f} ms")


if __name__ == "__main__":
    main()
