#!/usr/bin/env python3
"""Development check of the camera-only step lengths (issue 16), on development data only (simulator
validation sequences, the KITTI raw clip against KISS-ICP on its full scan; the KITTI odometry clip that
the benchmark reports is never read here).

For each sequence it runs leovr's epipolar motion alone (`mono_motion`, the road's scale) and prints the
Sim(3) ATE of:
- `filtered`: the motion as the forward filter gives it;
- `true_rot` / `true_dir` / `true_len`: the motion with each step's rotation / direction of travel / length
  replaced by the reference's (which part of the error matters);
- `smooth_S`: the lengths solved again over the whole recording (`odometry.step_length`), the step length
  changing by S metres a frame.

    .venv/bin/python tools/step_length_dev.py [--grid S ...] -- SEQ [SEQ ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.step_length import rescale_steps, smooth_log_lengths

sys.path.insert(0, str(Path(__file__).parent))
from mono_dev import reference  # noqa: E402  (the development reference: truth, else KISS-ICP on the full scan)


def chain(steps: list[np.ndarray]) -> np.ndarray:
    poses = [np.eye(4)]
    for T in steps:
        poses.append(poses[-1] @ T)
    return np.stack(poses)


def motion_steps(seq, cfg: RefineConfig, gen) -> tuple[list[np.ndarray], list]:
    """leovr's camera-only motion alone over a sequence (the road's scale; 1.65 m where the sequence does not
    record its camera height): each step's T_rel and the length reading its filter used."""
    mm = MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg) or 1.65, ground_sigma_log=cfg.mono_ground_sigma_log)
    steps, readings = [], []
    for i in range(len(seq)):
        f = seq[i]
        d, ls = gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
        s = mm.step(f.image, d, ls)
        if s is not None:
            steps.append(s.T_rel)
            readings.append(s.length_reading)
    return steps, readings


def dev_runs(paths: list[str]):
    """Per development sequence: (path, sequence, reference poses, the reference's name, the camera-only config,
    its generator), the set-up every camera-only development script shares."""
    cfg = RefineConfig(input="none")
    gen = generator_method(completion_config(cfg))
    for path in paths:
        seq = open_sequence(path)
        ref, ref_name = reference(seq, len(seq))
        yield path, seq, ref, ref_name, cfg, gen


def swapped(est: list[np.ndarray], ref: list[np.ndarray], rot: bool, direction: bool, length: bool) -> np.ndarray:
    out = []
    for e, g in zip(est, ref):
        T = np.eye(4)
        T[:3, :3] = (g if rot else e)[:3, :3]
        d = (g if direction else e)[:3, 3]
        T[:3, 3] = d / max(np.linalg.norm(d), 1e-9) * np.linalg.norm((g if length else e)[:3, 3])
        out.append(T)
    return chain(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--grid", nargs="*", type=float, default=[0.002, 0.003, 0.005, 0.01])
    a = ap.parse_args()
    for path, seq, ref, ref_name, cfg, gen in dev_runs(a.sequences):
        n = len(seq)
        steps, readings = motion_steps(seq, cfg, gen)
        ref_steps = [invert_T(ref[k - 1]) @ ref[k] for k in range(1, n)]
        poses = chain(steps)
        row = {"sequence": Path(path).name, "reference": ref_name, "filtered": poses}
        for name, flags in (("true_rot", (1, 0, 0)), ("true_dir", (0, 1, 0)), ("true_len", (0, 0, 1))):
            row[name] = swapped(steps, ref_steps, *flags)
        for g in a.grid:
            row[f"smooth_{g}"] = rescale_steps(poses, np.exp(smooth_log_lengths(readings, g)))
        print(json.dumps({k: (round(trajectory_metrics(v, ref, "sim3")["ate_m"], 4) if isinstance(v, np.ndarray) else v)
                          for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
