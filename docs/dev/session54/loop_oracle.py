"""Session 54 development check (issue 16, Mid-40 loop laps; *tuning* laps only, kept by
`tools/loop_tuning_dev.py --keep DIR`): what limits the loop closure's ATE ratio.

For each kept lap: ATE before / after the shipped pose graph, then the same graph with (a) the loops' measured
relative poses replaced by the truth, (b) a Gaussian graph with each odometry step's sigma set from its true error (an oracle weighting),
(c) both. Prints where the accepted loops are and the per-step error profile.

    .venv/bin/python docs/dev/session54/loop_oracle.py DIR
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


def graph(poses, loops, sig_rot, sig_tr, loop_sigma=(0.02, 0.1)):
    """Gaussian pose graph with per-step sigmas (arrays of len(poses) - 1)."""
    lc = robust(gtsam.noiseModel.mEstimator.Huber.Create(1.345), diagonal(*loop_sigma))
    return solve_pose_graph(*build_pose_graph(poses, loops, lambda k: diagonal(sig_rot[k - 1], sig_tr[k - 1]), lc), len(poses))


def main() -> None:
    keep = Path(sys.argv[1])
    for run in sorted(keep.glob("run_*")):
        if not (run / "loops.json").exists():
            continue
        tag = run.name[4:]
        before, ref, loops = lap_data(keep, tag)
        ate = lambda P: trajectory_metrics(P, ref, "se3")["ate_m"]  # noqa: E731
        true_loops = [(i, j, invert_T(ref[j]) @ ref[i]) for i, j, _ in loops]
        rot_err, tr_err, yaw = [], [], []
        for k in range(1, len(before)):
            d_est, d_ref = invert_T(before[k - 1]) @ before[k], invert_T(ref[k - 1]) @ ref[k]
            e = invert_T(d_ref) @ d_est
            rot_err.append(np.linalg.norm(gtsam.Rot3(e[:3, :3]).ypr()))
            tr_err.append(np.linalg.norm(e[:3, 3]))
            yaw.append(np.degrees(np.linalg.norm(gtsam.Rot3(d_ref[:3, :3]).ypr())))
        rot_err, tr_err, yaw = map(np.asarray, (rot_err, tr_err, yaw))
        orot, otr = np.maximum(rot_err, 2e-4), np.maximum(tr_err, 5e-3)
        print(f"{tag}: {len(before)} poses, {len(loops)} loops, frames i {sorted({i for i, _, _ in loops})}, "
              f"j {sorted({j for _, j, _ in loops})}")
        print(f"  ATE no loops {ate(before):.3f}  as shipped (optimise_pose_graph defaults) {ate(optimise_pose_graph(before, loops)):.3f}  "
              f"the same, true loops {ate(optimise_pose_graph(before, true_loops)):.3f}  "
              f"oracle sigmas {ate(graph(before, loops, orot, otr)):.3f}  both {ate(graph(before, true_loops, orot, otr)):.3f}  "
              f"oracle rot only {ate(graph(before, true_loops, orot, np.full(len(otr), 0.05))):.3f}")
        loop_err = [(np.degrees(np.linalg.norm(gtsam.Rot3((invert_T(T) @ Tt)[:3, :3]).ypr())), np.linalg.norm((invert_T(T) @ Tt)[:3, 3]))
                    for (_, _, T), (_, _, Tt) in zip(loops, true_loops)]
        print("  loop errors deg/m:", " ".join(f"{a:.2f}/{b:.2f}" for a, b in loop_err))
        big = np.argsort(rot_err)[::-1][:8]
        print("  worst rot steps (step, err deg, true rot deg):",
              " ".join(f"{k + 1}:{np.degrees(rot_err[k]):.2f}/{yaw[k]:.1f}" for k in sorted(big)))
        print(f"  rot err sum {np.degrees(rot_err.sum()):.2f} deg, in turns (>2 deg) {np.degrees(rot_err[yaw > 2].sum()):.2f}; "
              f"trans err rms {np.sqrt(np.mean(tr_err ** 2)):.3f} m, worst {tr_err.max():.3f} at {tr_err.argmax() + 1}")


if __name__ == "__main__":
    main()
