"""Session 56 (issue 16), development data only: does the camera-only direction of travel gain from lying in the
road plane? leovr's camera-only motion alone (`MonoMotion`, road scale) per development clip; each step's
direction (previous camera frame) compared with the reference's, split into the component along the road's normal
(vertical) and across it; then the Sim(3) ATE of the motion with the shipped smoothed lengths, with each direction
as filtered, projected onto the road plane fitted in its frame (the last fitted normal where none), and with only
its vertical component taken from the reference.

    .venv/bin/python docs/dev/session56/planar_dir.py -- SEQ ...
"""
from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from step_length_dev import chain, dev_runs  # noqa: E402

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from leovr.pipeline.completion import EvalSample  # noqa: E402
from leovr.pipeline.refine import road_height  # noqa: E402
from odometry.mono_motion import MonoMotion  # noqa: E402
from odometry.step_length import rescale_steps, smooth_log_lengths  # noqa: E402


def run_motion(path, seq, cfg, gen):
    f = Path("runs/s56") / f"motion_normals_{Path(path).name}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    mm = MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg) or 1.65, ground_sigma_log=cfg.mono_ground_sigma_log)
    out = []
    for i in range(len(seq)):
        fr = seq[i]
        d, ls = gen(EvalSample(fr, np.zeros(fr.shape, np.float32), None, "none", None))
        s = mm.step(fr.image, d, ls)
        if s is not None:
            out.append((s.T_rel, s.length_reading, s.road_normal))
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_bytes(pickle.dumps(out))
    return out


def with_dirs(steps, dirs):
    out = []
    for T, d in zip(steps, dirs):
        T = T.copy()
        T[:3, 3] = d * np.linalg.norm(T[:3, 3])
        out.append(T)
    return out


def main():
    for path, seq, ref, ref_name, cfg, gen in dev_runs(sys.argv[1:]):
        res = run_motion(path, seq, cfg, gen)
        steps = [r[0] for r in res]
        readings = [r[1] for r in res]
        ref_steps = [invert_T(ref[k - 1]) @ ref[k] for k in range(1, len(ref))]
        n_last = np.array([0.0, 1.0, 0.0])
        vert, lat, planar, true_vert = [], [], [], []
        for T, g, (_, _, nrm) in zip(steps, ref_steps, res):
            n_last = nrm if nrm is not None else n_last
            d = T[:3, 3] / max(np.linalg.norm(T[:3, 3]), 1e-12)
            gd = g[:3, 3] / max(np.linalg.norm(g[:3, 3]), 1e-12)
            side = np.cross(n_last, gd)
            side /= max(np.linalg.norm(side), 1e-12)
            if np.linalg.norm(T[:3, 3]) > 1e-9 and np.linalg.norm(g[:3, 3]) > 0.02:
                vert.append(np.degrees(np.arcsin(np.clip((d - gd) @ n_last, -1, 1))))
                lat.append(np.degrees(np.arcsin(np.clip((d - gd) @ side, -1, 1))))
            p = d - (d @ n_last) * n_last
            planar.append(p / max(np.linalg.norm(p), 1e-12) if np.linalg.norm(T[:3, 3]) > 1e-9 else d)
            tv = d + ((gd - d) @ n_last) * n_last
            true_vert.append(tv / max(np.linalg.norm(tv), 1e-12) if np.linalg.norm(T[:3, 3]) > 1e-9 else d)
        L = np.exp(smooth_log_lengths(readings, cfg.mono_length_change_sigma_m))
        ate = lambda st: round(trajectory_metrics(rescale_steps(chain(st), L), ref, "sim3")["ate_m"], 4)
        vert, lat = np.array(vert), np.array(lat)
        print(json.dumps({"sequence": Path(path).name,
                          "vert_deg_mean_std": [round(float(vert.mean()), 3), round(float(vert.std()), 3)],
                          "lat_deg_mean_std": [round(float(lat.mean()), 3), round(float(lat.std()), 3)],
                          "smoothed": ate(steps), "planar": ate(with_dirs(steps, planar)),
                          "true_vertical": ate(with_dirs(steps, true_vert))}), flush=True)


if __name__ == "__main__":
    main()
