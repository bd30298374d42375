"""Development check of the camera-only poses, on development data only (simulator validation
sequences and the KITTI raw clip, whose reference is KISS-ICP on its full HDL-64 scan): the textbook
VO (`mono_vo`), leovr's monocular motion alone (`mono_motion`), and, with --refine, `leovr refine
--input none`. ATE after Sim(3) alignment and its scale. The KITTI odometry clip, which the benchmark
reports, is never read here.

    .venv/bin/python tools/mono_dev.py [--refine] [--frames N] [--set F=V ...] [--cfg F=V ...] -- SEQ [SEQ ...]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height, run_refine
from odometry.initial_pose import LidarOdometry
from odometry.mono_motion import MonoMotion
from odometry.mono_vo import mono_vo_poses


def reference(seq, n: int) -> tuple[np.ndarray, str]:
    frames = [seq[i] for i in range(n)]
    if all(f.T_world_cam is not None for f in frames):
        return np.stack([invert_T(frames[0].T_world_cam) @ f.T_world_cam for f in frames]), "ground truth"
    icp = LidarOdometry(frames[0].T_cam_lidar)
    return np.stack([icp.register(f.points) for f in frames]), "KISS-ICP on the full scan"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--refine", action="store_true")
    ap.add_argument("--set", nargs="*", default=[], help="MonoMotion field=value (over the config's)")
    ap.add_argument("--cfg", nargs="*", default=[], help="RefineConfig field=value (for --refine)")
    a = ap.parse_args()
    cfg = RefineConfig(input="none", **{k: float(v) for k, v in (s.split("=") for s in a.cfg)})
    gen = generator_method(completion_config(cfg))
    kw = {k: float(v) for k, v in (s.split("=") for s in a.set)}
    for path in a.sequences:
        seq = open_sequence(path)
        n = min(len(seq), a.frames or len(seq))
        ref, ref_name = reference(seq, n)
        K = seq[0].K
        row = {"sequence": Path(path).name, "frames": n, "reference": ref_name}
        row["mono_vo"] = trajectory_metrics(mono_vo_poses((seq[i].image for i in range(n)), K), ref, "sim3")
        mm = MonoMotion(K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                        camera_height=road_height(seq, cfg), ground_sigma_log=cfg.mono_ground_sigma_log)
        for k, v in kw.items():
            setattr(mm, k, v)
        poses, sources = [np.eye(4)], []
        for i in range(n):
            f = seq[i]
            d, ls = gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
            s = mm.step(f.image, d, ls)
            if s is not None:
                poses.append(poses[-1] @ s.T_rel)
                sources.append(s.scale_source)
        row["mono_motion"] = trajectory_metrics(np.stack(poses), ref, "sim3")
        row["mono_motion"]["sources"] = {k: sources.count(k) for k in set(sources)}
        if a.refine:
            with tempfile.TemporaryDirectory() as tmp:
                run_refine(seq, cfg.model_copy(update={"end": n}), Path(tmp), progress=False, score=False)
                est = read_kitti_poses(Path(tmp) / "poses_kitti.txt")
                row["leovr"] = trajectory_metrics(est, ref, "sim3")
        print(json.dumps({k: ({kk: (round(vv, 3) if isinstance(vv, float) else vv) for kk, vv in v.items()}
                              if isinstance(v, dict) else v) for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
