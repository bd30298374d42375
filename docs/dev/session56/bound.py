"""Session 56 (issue 16), development data only: the camera-only motion alone with the shipped smoothed lengths,
each step's direction, rotation, both, or length replaced by the reference's (Sim(3) ATE in m).

    .venv/bin/python docs/dev/session56/bound.py SEQ ...
"""
import sys, json
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent)); sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from planar_dir import run_motion, with_dirs
from step_length_dev import chain, dev_runs
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from odometry.step_length import rescale_steps, smooth_log_lengths
for path, seq, ref, ref_name, cfg, gen in dev_runs(sys.argv[1:]):
    res = run_motion(path, seq, cfg, gen)
    steps = [r[0] for r in res]; readings = [r[1] for r in res]
    ref_steps = [invert_T(ref[k - 1]) @ ref[k] for k in range(1, len(ref))]
    L = np.exp(smooth_log_lengths(readings, cfg.mono_length_change_sigma_m))
    Lt = np.array([np.linalg.norm(g[:3,3]) for g in ref_steps])
    ate = lambda st, LL=L: round(trajectory_metrics(rescale_steps(chain(st), LL), ref, "sim3")["ate_m"], 4)
    tdir = [g[:3,3]/max(np.linalg.norm(g[:3,3]),1e-12) if np.linalg.norm(T[:3,3])>1e-9 else T[:3,3] for T,g in zip(steps,ref_steps)]
    trot = []
    for T,g in zip(steps,ref_steps):
        X=T.copy(); X[:3,:3]=g[:3,:3]; trot.append(X)
    print(json.dumps({"seq":Path(path).name[:14],"smoothed":ate(steps),"true_dir":ate(with_dirs(steps,tdir)),
      "true_rot":ate(trot),"true_rot_dir":ate(with_dirs(trot,tdir)),"true_len":ate(steps,Lt)}),flush=True)
