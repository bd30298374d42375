#!/usr/bin/env python3
"""Development tool for the loop-closure pose graph (issue 16), on the *tuning* laps kept by
`tools/loop_tuning_dev.py --keep DIR` (seeds 3000 and 3001; the benchmark's reported seeds are never read).

For every kept lap it takes the run's poses before loop closure and its accepted loops (loops.json), solves
the global pose graph again with the options given, and prints the ATE (SE(3), as `leovr bench loop`) before
and after. `--stats` also prints the odometry's per-step errors against the truth, the figures the graph's
odometry noise should match.

    .venv/bin/python tools/pose_graph_dev.py runs/loop_dev [--stats] [--odo-rad R --odo-m M] [--odo-per-m P]
        [--loop-rad R --loop-m M]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from odometry.loop.pose_graph import optimise_pose_graph


def _angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def lap_data(keep: Path, tag: str) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, np.ndarray]]]:
    """(poses before loops, ground-truth poses relative to the first, accepted loops as pose-graph indices)."""
    run, seq = keep / f"run_{tag}", open_sequence(keep / f"seq_{tag}")
    state = json.loads((run / "progress.json").read_text())
    idx = sorted(int(k) for k in state["poses_no_loop"])
    before = np.stack([np.array(state["poses_no_loop"][str(i)]).reshape(4, 4) for i in idx])
    gt = [seq[i].T_world_cam for i in idx]
    ref = np.stack([invert_T(gt[0]) @ T for T in gt])
    at = {i: n for n, i in enumerate(idx)}
    loops = [(at[r["frame"]], at[r["candidate"]], np.array(r["T_j_i"]))
             for r in json.loads((run / "loops.json").read_text())["loops"] if r["accepted"]]
    return before, ref, loops


def step_stats(est: np.ndarray, ref: np.ndarray) -> dict:
    """Per-step relative pose errors of the odometry: rotation (deg) and translation (m, and per metre)."""
    rot, tr, length = [], [], []
    for k in range(1, len(est)):
        d_est, d_ref = invert_T(est[k - 1]) @ est[k], invert_T(ref[k - 1]) @ ref[k]
        e = invert_T(d_ref) @ d_est
        rot.append(_angle(e[:3, :3]))
        tr.append(np.linalg.norm(e[:3, 3]))
        length.append(np.linalg.norm(d_ref[:3, 3]))
    rot, tr, length = map(np.asarray, (rot, tr, length))
    return {"rot_rms_deg": float(np.sqrt(np.mean(rot ** 2))), "rot_median_deg": float(np.median(rot)),
            "trans_rms_m": float(np.sqrt(np.mean(tr ** 2))), "trans_median_m": float(np.median(tr)),
            "step_median_m": float(np.median(length))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("keep", type=Path)
    ap.add_argument("--stats", action="store_true")
    ap.add_argument("--odo-rad", type=float, default=0.01)
    ap.add_argument("--odo-m", type=float, default=0.05)
    ap.add_argument("--loop-rad", type=float, default=0.02)
    ap.add_argument("--loop-m", type=float, default=0.1)
    a = ap.parse_args()
    tags = sorted(p.name[4:] for p in a.keep.glob("run_*") if (p / "loops.json").exists())
    ratios = []
    for tag in tags:
        before, ref, loops = lap_data(a.keep, tag)
        after = optimise_pose_graph(before, loops, odo_sigma=(a.odo_rad, a.odo_m), loop_sigma=(a.loop_rad, a.loop_m))
        ate0 = trajectory_metrics(before, ref, "se3")["ate_m"]
        ate1 = trajectory_metrics(after, ref, "se3")["ate_m"]
        ratios.append(ate1 / ate0)
        line = f"{tag:14s} loops {len(loops):3d}  ATE {ate0:.3f} -> {ate1:.3f} m  ratio {ate1 / ate0:.3f}"
        if a.stats:
            line += "  " + json.dumps({k: round(v, 4) for k, v in step_stats(before, ref).items()})
        print(line, flush=True)
    print(f"mean ratio {np.mean(ratios):.3f}  worst {np.max(ratios):.3f}")


if __name__ == "__main__":
    main()
