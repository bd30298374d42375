"""Session 57 development check (issue 16, Mid-40 loop laps; tuning / development laps only, kept by
`tools/loop_tuning_dev.py --keep DIR`): the Mid-40 window pass's steps in turns are off by 10-39 % in length
(a speed change no car makes in 0.1 s). Post-hoc, over the whole recording: (a) the step lengths smoothed as the
camera-only path does (`odometry.step_length.smooth_log_lengths`, each step's own length as its reading),
(b) the directions of travel from the rigid vehicle (`odometry.vehicle_motion.vehicle_directions`), (c) both;
ATE without loops and with the shipped loop pose graph.

    .venv/bin/python docs/dev/session57/lidar_step_smoothing.py DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from odometry.loop.pose_graph import optimise_pose_graph  # noqa: E402
from odometry.step_length import LengthReading, rescale_steps, smooth_log_lengths  # noqa: E402
from odometry.vehicle_motion import vehicle_directions  # noqa: E402
from pose_graph_dev import lap_data  # noqa: E402


def smoothed(poses: np.ndarray, sigma_log: float, change_m: float) -> np.ndarray:
    L = np.linalg.norm((invert_T(poses[:-1]) @ poses[1:])[:, :3, 3], axis=1)
    reads = [LengthReading(float(np.log(x)), sigma_log) if x > 0.05 else None for x in L]
    return rescale_steps(poses, np.exp(smooth_log_lengths(reads, change_m)))


def main() -> None:
    keep = Path(sys.argv[1])
    tags = [r.name[4:] for r in sorted(keep.glob("run_*")) if (r / "loops.json").exists()]
    variants = {"as is": lambda P: P}
    for s in (0.05, 0.1, 0.2):
        for c in (0.02, 0.05):
            variants[f"lengths s{s} c{c}"] = lambda P, s=s, c=c: smoothed(P, s, c)
    variants["vehicle directions"] = vehicle_directions
    variants["lengths s0.1 c0.05 + vehicle"] = lambda P: vehicle_directions(smoothed(P, 0.1, 0.05))
    print("| variant | " + " | ".join(tags) + " |")
    for name, fn in variants.items():
        cells = []
        for tag in tags:
            before, ref, loops = lap_data(keep, tag)
            P = fn(before)
            a0 = trajectory_metrics(P, ref, "se3")["ate_m"]
            a1 = trajectory_metrics(optimise_pose_graph(P, loops), ref, "se3")["ate_m"]
            cells.append(f"{a0:.3f} / {a1:.3f} ({a1 / a0:.2f})")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
