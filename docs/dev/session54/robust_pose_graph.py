"""Session 54 development check (issue 16): robust odometry factors in the loop-closure pose graph, on the *tuning*
laps kept by `tools/loop_tuning_dev.py --keep DIR` (the loop benchmark's reported seeds are never read).

The shipped graph (before this session) trusts every odometry step with a Gaussian of 0.01 rad / 0.05 m; one gross
front-end failure (a step 5 m off) then holds the loops back. Each row re-solves the graph over the run's poses before
loop closure and its accepted loops with a robust kernel on the odometry factors and prints the SE(3) ATE.

    .venv/bin/python docs/dev/session54/robust_pose_graph.py DIR
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
from odometry.loop.pose_graph import build_pose_graph, diagonal, robust, solve_pose_graph  # noqa: E402
from pose_graph_dev import lap_data  # noqa: E402

M = gtsam.noiseModel.mEstimator
VARIANTS = {  # name: (kernel, constant, odometry sigmas rad / m)
    "gaussian (shipped before)": (None, 0, (0.01, 0.05)),
    "huber 1.345": (M.Huber, 1.345, (0.01, 0.05)),
    "cauchy 1": (M.Cauchy, 1.0, (0.01, 0.05)),
    "cauchy 2.385": (M.Cauchy, 2.385, (0.01, 0.05)),
    "cauchy 1, sigmas 0.005/0.1": (M.Cauchy, 1.0, (0.005, 0.1)),
    "cauchy 2.385, sigmas 0.005/0.1": (M.Cauchy, 2.385, (0.005, 0.1)),
    "tukey 4.685": (M.Tukey, 4.685, (0.01, 0.05)),
    "geman-mcclure 1": (M.GemanMcClure, 1.0, (0.01, 0.05)),
    "dcs 1": (M.DCS, 1.0, (0.01, 0.05)),
}


def solve(poses, loops, kernel, c, odo, loop_sigma=(0.02, 0.1)) -> np.ndarray:
    odo_n = robust(None if kernel is None else kernel.Create(c), diagonal(*odo))
    lc = robust(M.Huber.Create(1.345), diagonal(*loop_sigma))
    return solve_pose_graph(*build_pose_graph(poses, loops, lambda k: odo_n, lc), len(poses))


def solve_gnc(poses, loops, odo=(0.01, 0.05), loop_sigma=(0.02, 0.1)) -> np.ndarray:
    """gtsam's graduated non-convexity (TLS, default thresholds) over the Gaussian graph; the prior and the loop
    factors given as known inliers (the loops passed validation and the neighbour check)."""
    g, v = build_pose_graph(poses, loops, lambda k: diagonal(*odo), diagonal(*loop_sigma))
    p = gtsam.GncLMParams()
    p.setKnownInliers([0] + list(range(len(poses), g.size())))  # prior, then F - 1 odometry factors, then loops
    res = gtsam.GncLMOptimizer(g, v, p).optimize()
    return np.stack([res.atPose3(k).matrix() for k in range(len(poses))])


def main() -> None:
    keep = Path(sys.argv[1])
    tags = sorted(p.name[4:] for p in keep.glob("run_*") if (p / "loops.json").exists())
    laps = {t: lap_data(keep, t) for t in tags}
    print("| variant | " + " | ".join(tags) + " | worst ratio |")
    print("|---|" + "---|" * (len(tags) + 1))
    print("| no loops | " + " | ".join(f"{trajectory_metrics(laps[t][0], laps[t][1], 'se3')['ate_m']:.3f}" for t in tags) + " | |")
    for name, (k, c, odo) in VARIANTS.items():
        ates, ratios = [], []
        for t in tags:
            before, ref, loops = laps[t]
            a1 = trajectory_metrics(solve(before, loops, k, c, odo), ref, "se3")["ate_m"]
            ates.append(a1)
            ratios.append(a1 / trajectory_metrics(before, ref, "se3")["ate_m"])
        print(f"| {name} | " + " | ".join(f"{a:.3f}" for a in ates) + f" | {max(ratios):.2f} |", flush=True)
    ates = [trajectory_metrics(solve_gnc(laps[t][0], laps[t][2]), laps[t][1], "se3")["ate_m"] for t in tags]
    ratios = [a / trajectory_metrics(laps[t][0], laps[t][1], "se3")["ate_m"] for a, t in zip(ates, tags)]
    print("| GNC, loops known inliers | " + " | ".join(f"{a:.3f}" for a in ates) + f" | {max(ratios):.2f} |", flush=True)


if __name__ == "__main__":
    main()
