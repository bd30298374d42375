"""Session 56 (issue 16), development data only: directions of travel from a rigid vehicle model. A vehicle's
reference point (the rear axle's centre for a car; the simulator's path point) moves along the chord at half its
step's rotation from its forward axis; the camera, mounted at an offset m from it, moves by
    t_k = s_k Rhalf_k f + (I - R_k) m
in the camera frame (f: the vehicle's forward axis in camera coordinates, R_k the step's rotation, Rhalf_k its half).
Session 51's `nh.py` had m = 0 and lost the city loop (0.048 -> 0.238 m): the camera is not over the axle.
Here f and m are fitted over the recording (least squares with Huber weights, s_k = the smoothed step length),
on leovr's camera-only motion alone with the shipped smoothed lengths; the directions of travel are then the
model's, or a blend. Sim(3) ATE in m; `true_dir` is the bound with the reference's directions.

    .venv/bin/python docs/dev/session56/lever_dir.py -- SEQ ...
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation as Rot

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from planar_dir import run_motion, with_dirs  # noqa: E402
from step_length_dev import chain, dev_runs  # noqa: E402

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from odometry.step_length import rescale_steps, smooth_log_lengths  # noqa: E402


def half(R):
    return Rot.from_rotvec(0.5 * Rot.from_matrix(R).as_rotvec()).as_matrix()


def fit_vehicle(steps, L, huber_m=0.02, iterations=5, with_m=True):
    """f (unit, camera frame) and m (camera offset from the reference point, up to the part no rotation sees)."""
    use = [k for k, T in enumerate(steps) if np.isfinite(L[k]) and L[k] > 0.05 and np.linalg.norm(T[:3, 3]) > 1e-9]
    A, b = [], []
    for k in use:
        T = steps[k]
        d = T[:3, 3] / np.linalg.norm(T[:3, 3])
        A.append(np.hstack([L[k] * half(T[:3, :3]), (np.eye(3) - T[:3, :3]) if with_m else np.zeros((3, 3))]))
        b.append(L[k] * d)
    A, b = np.vstack(A), np.concatenate(b)
    w = np.ones(len(b))
    for _ in range(iterations):
        sw = np.sqrt(w)
        x = np.linalg.lstsq(A * sw[:, None], b * sw, rcond=None)[0]
        r = np.abs(A @ x - b)
        w = np.where(r < huber_m, 1.0, huber_m / np.maximum(r, 1e-12))
    f, m = x[:3], x[3:]
    return f / np.linalg.norm(f), m


def model_dirs(steps, L, f, m, blend=1.0):
    out = []
    for k, T in enumerate(steps):
        n = np.linalg.norm(T[:3, 3])
        if n < 1e-9 or not np.isfinite(L[k]):
            out.append(T[:3, 3] / max(n, 1e-12))
            continue
        t = L[k] * half(T[:3, :3]) @ f + (np.eye(3) - T[:3, :3]) @ m
        v = blend * t / np.linalg.norm(t) + (1 - blend) * T[:3, 3] / n
        out.append(v / np.linalg.norm(v))
    return out


def lateral_dirs(steps, L, f, m, up):
    """The model's direction across the vehicle's up axis (yaw plane), the measured one's along it (pitch: the
    body bounces on its suspension and the road's slope changes, which a rigid model does not see)."""
    model = model_dirs(steps, L, f, m)
    out = []
    for T, dm in zip(steps, model):
        n = np.linalg.norm(T[:3, 3])
        if n < 1e-9:
            out.append(dm)
            continue
        d = T[:3, 3] / n
        v = dm - (dm @ up) * up + (d @ up) * up
        out.append(v / np.linalg.norm(v))
    return out


def up_axis(steps, f):
    """The vehicle's up axis in the camera frame: the mean rotation axis of the turning steps (sign: camera -y),
    made orthogonal to f; the camera's -y where the recording does not turn."""
    ax = [Rot.from_matrix(T[:3, :3]).as_rotvec() for T in steps]
    ax = [a if a @ np.array([0, -1.0, 0]) >= 0 else -a for a in ax if np.linalg.norm(a) > np.radians(0.5)]
    u = np.sum(ax, axis=0) if len(ax) >= 3 else np.array([0, -1.0, 0])
    u = u - (u @ f) * f
    return u / np.linalg.norm(u)


def main():
    for path, seq, ref, ref_name, cfg, gen in dev_runs(sys.argv[1:]):
        res = run_motion(path, seq, cfg, gen)
        steps = [r[0] for r in res]
        readings = [r[1] for r in res]
        ref_steps = [invert_T(ref[k - 1]) @ ref[k] for k in range(1, len(ref))]
        L = np.exp(smooth_log_lengths(readings, cfg.mono_length_change_sigma_m))
        ate = lambda st: round(trajectory_metrics(rescale_steps(chain(st), L), ref, "sim3")["ate_m"], 4)
        tdir = [g[:3, 3] / max(np.linalg.norm(g[:3, 3]), 1e-12) if np.linalg.norm(T[:3, 3]) > 1e-9 else T[:3, 3]
                for T, g in zip(steps, ref_steps)]
        row = {"sequence": Path(path).name[:16], "smoothed": ate(steps), "true_dir": ate(with_dirs(steps, tdir))}
        f0, _ = fit_vehicle(steps, L, with_m=False)
        row["axle_only"] = ate(with_dirs(steps, model_dirs(steps, L, f0, np.zeros(3))))
        f, m = fit_vehicle(steps, L)
        for blend in (1.0, 0.5):
            row[f"lever_{blend}"] = ate(with_dirs(steps, model_dirs(steps, L, f, m, blend)))
        up = up_axis(steps, f)
        row["lateral"] = ate(with_dirs(steps, lateral_dirs(steps, L, f, m, up)))
        row["up"] = np.round(up, 3).tolist()
        # the model fitted on the reference's own motion: how well it can describe the truth at all
        Lr = np.array([np.linalg.norm(g[:3, 3]) for g in ref_steps])
        fr, mr = fit_vehicle(ref_steps, Lr)
        row["f"], row["m"], row["f_ref"], row["m_ref"] = (np.round(f, 3).tolist(), np.round(m, 2).tolist(),
                                                          np.round(fr, 3).tolist(), np.round(mr, 2).tolist())
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
