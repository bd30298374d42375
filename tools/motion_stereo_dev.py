#!/usr/bin/env python3
"""Development runs for motion stereo (odometry/motion_stereo.py): the shipped generator on each frame's
own cheap scan, with and without the triangulated corners, scored on the same pixels.

KITTI (default): the raw clip's development frames (0 to --dev-end - 1, neighbours from the same range;
the inductive test frames 38-47 of `leovr bench real` are never read), Mid-40-like input, held-out beams.
`--sim`: the simulator's Mid-40 validation drives (seeds 2000-2002, dense truth). Prints the MAE of the
nearest fill and the generator without / with the corners over all pixels, pixels more than 20 px from
a return ("out") and those with truth beyond 40 m there, and the corners' own error against truth within
one pixel; `--set NAME=VALUE` overrides a MotionStereoSettings field.

    .venv/bin/python tools/motion_stereo_dev.py [--sim] [--step 3] [--set min_parallax_px=8 offsets=2,4,8]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np
from scipy.ndimage import distance_transform_edt, maximum_filter

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.depth.classical import nearest_fill
from leovr.depth.dataset import split_entries
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.runtime import for_inference
from leovr.paths import kitti_raw_dir, shipped_checkpoint
from leovr.pipeline.completion import with_truth
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root
from odometry.motion_stereo import GrayImages, MotionStereoSettings, corrected_depth, motion_stereo_depth, neighbour_frames


def settings_from(pairs: list[str]) -> MotionStereoSettings:
    s = MotionStereoSettings()
    kw = {}
    for kv in pairs:
        k, v = kv.split("=")
        cur = getattr(s, k)
        kw[k] = tuple(int(x) for x in v.split(",")) if isinstance(cur, tuple) else type(cur)(float(v))
    return dataclasses.replace(s, **kw)


def score_sequence(seq, ccfg, frames: list[int], model, s: MotionStereoSettings, acc: dict, tri: list, ms: list) -> None:
    images = GrayImages(lambda j: seq[j].image, keep=4 * max(s.offsets) + 4)
    for i in frames[::ARGS.step]:
        sample = with_truth(frame_sample(seq, i, ccfg), ccfg)
        t0 = time.perf_counter()
        images.put(i, sample.frame.image)
        extra = motion_stereo_depth(i, neighbour_frames(i, frames, s.offsets), images, sample.frame.K, sample.sparse, s=s)
        ms.append(1000 * (time.perf_counter() - t0))
        gt = sample.gt
        near = maximum_filter(gt, size=3)
        v, u = np.nonzero(extra > 0)
        has = near[v, u] > 0
        tri.append(np.column_stack([near[v, u][has], extra[v, u][has]]))
        aug = np.where(sample.sparse > 0, sample.sparse, extra).astype(np.float32)
        rows, cols = np.nonzero(gt > 0)
        g = gt[rows, cols]
        out = distance_transform_edt(sample.sparse <= 0)[rows, cols] > 20
        focal = float(sample.frame.K[0, 0])
        gen = predict_at_focal(model, sample.frame.image, sample.sparse, focal, ccfg.generator_focal_px)[0]
        preds = {"nearest": nearest_fill(sample.sparse)[rows, cols], "generator": gen[rows, cols],
                 "generator_stereo": predict_at_focal(model, sample.frame.image, aug, focal, ccfg.generator_focal_px)[0][rows, cols]}
        if ARGS.oracle:  # the same corners at their true depth: is it the corners' error or their layout?
            true_aug = np.where(sample.sparse > 0, sample.sparse, np.where(extra > 0, gt, 0)).astype(np.float32)
            preds["generator_true_corners"] = predict_at_focal(model, sample.frame.image, true_aug, focal, ccfg.generator_focal_px)[0][rows, cols]
        for sig in ARGS.sigmas:  # a fraction of the focal length
            for sup in ARGS.supports:
                for rng in ARGS.ranges:
                    for edge in ARGS.edges:
                        tag = f"corrected_s{sig:g}_w{sup:g}" + (f"_r{rng:g}" if np.isfinite(rng) else "") + (f"_e{edge}" if edge else "")
                        full = corrected_depth(gen, extra, sig * focal, sup, rng, edge)
                        preds[tag] = full[rows, cols]
                        worst.setdefault(tag, []).append(float(full.max()))
        for gate in ARGS.gates:  # only corners that disagree with the generator by more than this (log)
            with np.errstate(divide="ignore", invalid="ignore"):
                off = np.abs(np.log(extra / gen))
            gated = np.where(sample.sparse > 0, sample.sparse, np.where((extra > 0) & (off > gate), extra, 0)).astype(np.float32)
            preds[f"stereo_gate{gate:g}"] = predict_at_focal(model, sample.frame.image, gated, focal, ccfg.generator_focal_px)[0][rows, cols]
        for name, p in preds.items():
            for group, sel in (("all", np.ones(len(g), bool)), ("out", out), ("out_beyond_40m", out & (g > 40)), ("beyond_60m", g > 60)):
                e = acc.setdefault(group, {}).setdefault(name, [0.0, 0, 0.0])
                e[0] += float(np.abs(p[sel] - g[sel]).sum())
                e[1] += int(sel.sum())
                e[2] += float(((p[sel] - g[sel]) ** 2).sum())
        print(f"frame {i}: {int((extra > 0).sum())} corners, {ms[-1]:.0f} ms, "
              + ", ".join(f"{k} {np.abs(p - g).mean():.3f}" for k, p in preds.items()), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sim", action="store_true")
    ap.add_argument("--step", type=int, default=3)
    ap.add_argument("--split", default="val", help="--sim: the split (val; train for more development drives)")
    ap.add_argument("--max-sequences", type=int, default=None)
    ap.add_argument("--scenario", default=None, help="--sim: only drives of this scenario (city_loop, straight, dynamic)")
    ap.add_argument("--dev-end", type=int, default=38)
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--oracle", action="store_true", help="also the corners at their true depth (diagnosis)")
    ap.add_argument("--sigmas", type=float, nargs="*", default=[], help="corrected_depth's sigma, x focal length")
    ap.add_argument("--ranges", type=float, nargs="*", default=[float("inf")], help="corrected_depth's range_log")
    ap.add_argument("--edges", type=int, nargs="*", default=[0], help="corrected_depth's edge_px")
    ap.add_argument("--gates", type=float, nargs="*", default=[])
    ap.add_argument("--supports", type=float, nargs="*", default=[0.5])
    global ARGS, worst
    worst = {}
    ARGS = ap.parse_args()
    s = settings_from(ARGS.set)
    model = for_inference(load_generator(shipped_checkpoint()))
    acc: dict = {}
    tri: list = []
    ms: list = []
    if ARGS.sim:
        ccfg = completion_config(RefineConfig(input="full"))
        entries = [e for e in split_entries(default_root() / "default", ARGS.split)
                   if e["lidar"] == "mid40" and ARGS.scenario in (None, e["scenario"])]
        for e in entries[: ARGS.max_sequences]:
            seq = open_sequence(e["path"])
            score_sequence(seq, ccfg, list(range(len(seq))), model, s, acc, tri, ms)
    else:
        seq = open_sequence(kitti_raw_dir())
        ccfg = completion_config(RefineConfig(input="mid40"))
        score_sequence(seq, ccfg, list(range(ARGS.dev_end)), model, s, acc, tri, ms)
    t = np.concatenate(tri) if tri else np.zeros((0, 2))
    rel = np.abs(t[:, 1] - t[:, 0]) / t[:, 0]
    print(json.dumps({
        "data": f"simulator Mid-40 {ARGS.split} drives" if ARGS.sim else f"KITTI raw frames 0-{ARGS.dev_end - 1}, Mid-40-like",
        "step": ARGS.step, "settings": dataclasses.asdict(s), "ms_per_frame_median": round(float(np.median(ms)), 1),
        "corners_with_truth": len(t), "corner_rel_error_median": round(float(np.median(rel)), 4) if len(t) else None,
        "corner_rel_error_p90": round(float(np.quantile(rel, 0.9)), 4) if len(t) else None,
        "mae_m": {grp: {k: round(e / max(n, 1), 4) for k, (e, n, _) in d.items()} | {"pixels": d["nearest"][1]}
                  for grp, d in acc.items()},
        "max_depth_m": {k: round(max(v), 1) for k, v in worst.items()},
        "rmse_m": {grp: {k: round((q / max(n, 1)) ** 0.5, 4) for k, (_, n, q) in d.items()} for grp, d in acc.items()}}, indent=1))


if __name__ == "__main__":
    main()
