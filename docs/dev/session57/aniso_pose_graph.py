"""Session 57 development check (issue 16, loop laps; *tuning / development* laps only, kept by
`tools/loop_tuning_dev.py --keep DIR`): does the pose graph gain from per-axis odometry sigmas?

Session 54's oracle set each step's sigma from the norm of its true error (isotropic). Here:
(a) oracle per-axis: each tangent component's sigma from that component of the true error;
(b) realistic shapes: the translation sigma along the camera's forward axis (z) and/or proportional to the step length.

    .venv/bin/python docs/dev/session57/aniso_pose_graph.py DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from odometry.loop.pose_graph import build_pose_graph, diagonal, optimise_pose_graph, robust, solve_pose_graph  # noqa: E402
from pose_graph_dev import lap_data  # noqa: E402

M = gtsam.noiseModel.mEstimator


def solve(before, loops, noise_of_step, cauchy=1.0):
    lc = robust(M.Huber.Create(1.345), diagonal(0.02, 0.1))
    f = (lambda k: robust(M.Cauchy.Create(cauchy), noise_of_step(k))) if cauchy else noise_of_step
    return solve_pose_graph(*build_pose_graph(before, loops, f, lc), len(before))


def sig(v):
    return gtsam.noiseModel.Diagonal.Sigmas(np.asarray(v, float))


def main() -> None:
    keep = Path(sys.argv[1])
    rows = []
    for run in sorted(keep.glob("run_*")):
        if not (run / "loops.json").exists():
            continue
        tag = run.name[4:]
        before, ref, loops = lap_data(keep, tag)
        ate = lambda P: trajectory_metrics(P, ref, "se3")["ate_m"]  # noqa: E731
        err, lens = [], []
        for k in range(1, len(before)):
            d_est, d_ref = invert_T(before[k - 1]) @ before[k], invert_T(ref[k - 1]) @ ref[k]
            err.append(gtsam.Pose3.Logmap(gtsam.Pose3(invert_T(d_ref) @ d_est)))
            lens.append(np.linalg.norm(d_est[:3, 3]))
        err, lens = np.abs(np.asarray(err)), np.asarray(lens)
        floor = np.r_[np.full(3, 2e-4), np.full(3, 5e-3)]
        orac = np.maximum(err, floor)
        iso = np.c_[np.repeat(np.maximum(np.linalg.norm(err[:, :3], axis=1), 2e-4)[:, None], 3, 1),
                    np.repeat(np.maximum(np.linalg.norm(err[:, 3:], axis=1), 5e-3)[:, None], 3, 1)]
        L = np.median(lens)
        res = {
            "no loops": ate(before),
            "shipped": ate(optimise_pose_graph(before, loops)),
            "oracle iso (gauss)": ate(solve(before, loops, lambda k: sig(iso[k - 1]), None)),
            "oracle per-axis (gauss)": ate(solve(before, loops, lambda k: sig(orac[k - 1]), None)),
            "fwd x3": ate(solve(before, loops, lambda k: sig([.01, .01, .01, .05, .05, .15]))),
            "fwd x5": ate(solve(before, loops, lambda k: sig([.01, .01, .01, .05, .05, .25]))),
            "len-prop": ate(solve(before, loops, lambda k: sig([.01, .01, .01] + [0.05 * max(lens[k - 1], 0.2 * L) / L] * 3))),
            "len-prop fwd x3": ate(solve(before, loops, lambda k: sig([.01, .01, .01, .05, .05, .15 * max(lens[k - 1], 0.2 * L) / L]))),
            "yaw loose x3": ate(solve(before, loops, lambda k: sig([.01, .03, .01, .05, .05, .05]))),
        }
        print(tag, " ".join(f"{k}={v:.3f}" for k, v in res.items()), flush=True)
        rows.append((tag, res))
    names = list(rows[0][1])
    print("| variant | " + " | ".join(t for t, _ in rows) + " |")
    for n in names:
        print(f"| {n} | " + " | ".join(f"{r[n]:.3f} ({r[n] / r['no loops']:.2f})" for _, r in rows) + " |")


if __name__ == "__main__":
    main()
