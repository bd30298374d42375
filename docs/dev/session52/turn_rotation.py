"""Session 52 development check (issue 16, loop laps): where the LiDAR path's heading error comes from. On the
*tuning* laps kept by `tools/loop_tuning_dev.py --keep DIR` (seeds 3000/3001), per step: the rotation error
(degrees) of leovr's poses before loop closure, of KISS-ICP's poses as the front end kept them, and of the
images' own epipolar rotation (LK tracks, essential matrix, USAC_ACCURATE), split into turning steps (true
rotation > 2 degrees) and the rest; and the yaw error summed over the lap.

    .venv/bin/python docs/dev/session52/turn_rotation.py DIR
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from odometry.mono_vo import corners, follow, gray, relative_motion  # noqa: E402


def angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def rel(P: np.ndarray, k: int) -> np.ndarray:
    return invert_T(P[k - 1]) @ P[k]


def main() -> None:
    keep = Path(sys.argv[1])
    for run in sorted(keep.glob("run_*")):
        if not (run / "loops.json").exists():
            continue
        tag = run.name[4:]
        seq = open_sequence(keep / f"seq_{tag}")
        state = json.loads((run / "progress.json").read_text())
        idx = sorted(int(k) for k in state["poses_no_loop"])
        get = lambda name: np.stack([np.array(state[name][str(i)]).reshape(4, 4) for i in idx])  # noqa: E731
        est = get("poses_no_loop")
        icp = get("icp_poses") if all(str(i) in state["icp_poses"] for i in idx) else None
        gt = np.stack([seq[i].T_world_cam for i in idx])
        K = seq[0].K
        rows = []
        prev = gray(seq[idx[0]].image)
        yaw_sum = {"leovr": 0.0, "icp": 0.0, "image": 0.0}
        for k in range(1, len(idx)):
            cur = gray(seq[idx[k]].image)
            p0 = corners(prev, 2000)
            p1, ok = follow(prev, cur, p0)
            motion, _ = relative_motion(p0[ok], p1[ok], K, method=cv2.USAC_ACCURATE)
            prev = cur
            g = rel(gt, k)
            row = {"turn": angle(g[:3, :3]), "leovr": angle(g[:3, :3].T @ rel(est, k)[:3, :3])}
            if icp is not None:
                row["icp"] = angle(g[:3, :3].T @ rel(icp, k)[:3, :3])
            row["image"] = angle(g[:3, :3].T @ motion[:3, :3]) if motion is not None else np.nan
            # signed yaw error (about the camera's y axis), summed: the heading the lap drifts by
            for name, P in (("leovr", est), ("icp", icp)):
                if P is not None:
                    E = g[:3, :3].T @ rel(P, k)[:3, :3]
                    yaw_sum[name] += float(np.degrees(np.arctan2(E[0, 2], E[2, 2])))
            if motion is not None:
                E = g[:3, :3].T @ motion[:3, :3]
                yaw_sum["image"] += float(np.degrees(np.arctan2(E[0, 2], E[2, 2])))
            rows.append(row)
        turn = np.array([r["turn"] for r in rows]) > 2.0
        out = {"lap": tag, "steps": len(rows), "turning": int(turn.sum())}
        for name in ("leovr", "icp", "image"):
            if name not in rows[0]:
                continue
            e = np.array([r[name] for r in rows])
            out[name] = {"turn_median": round(float(np.nanmedian(e[turn])), 3), "turn_max": round(float(np.nanmax(e[turn])), 3),
                         "straight_median": round(float(np.nanmedian(e[~turn])), 3),
                         "yaw_sum_deg": round(yaw_sum[name], 2)}
        worst = np.argsort([-r["leovr"] for r in rows])[:6]
        out["worst_steps"] = [(int(idx[k + 1]), round(rows[k]["turn"], 2), round(rows[k]["leovr"], 2), round(rows[k]["image"], 2))
                              for k in worst]  # (frame, true turn, leovr error, image error) in degrees
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
