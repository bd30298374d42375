"""Session 52 development check (issue 16): how often the pair motions' essential matrices fail on a tuning lap, with
the LK tracks as shipped (`odometry.motion_stereo.track`) and started from the flow a constant rate of turn predicts
(the same pair one frame earlier, from the truth here: a stand-in for the graph's poses; points at infinity,
K R K^-1). Rotation only (the LiDAR length is not needed for it).

    .venv/bin/python docs/dev/session52/pair_init_flow.py LAP_SEQ
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
from leovr.geometry import invert_T, rotation_angle_deg  # noqa: E402
from odometry.mono_vo import gray  # noqa: E402
from odometry.motion_stereo import MotionStereoSettings, detect_corners, essential_motion, track  # noqa: E402


def track_from(g0: np.ndarray, g1: np.ndarray, c: np.ndarray, guess: np.ndarray, s: MotionStereoSettings):
    lk = dict(winSize=(s.lk_window_px, s.lk_window_px), maxLevel=s.lk_levels, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, s.lk_iterations, 0.01))
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(g0, g1, c, guess.astype(np.float32).copy(), **lk)
    lk.pop("flags")
    p0, st0, _ = cv2.calcOpticalFlowPyrLK(g1, g0, p1, None, **lk)
    ok = (st1[:, 0] == 1) & (st0[:, 0] == 1) & (np.linalg.norm(p0 - c, axis=1) < s.track_check_px)
    return p1, ok


def main() -> None:
    seq = open_sequence(sys.argv[1])
    s = MotionStereoSettings()
    K = seq[0].K
    Tw = [seq[i].T_world_cam for i in range(len(seq))]
    grays = [gray(seq[i].image) for i in range(len(seq))]
    rows = []
    for i in range(2, len(seq)):
        c = detect_corners(grays[i], s)
        if c is None:
            continue
        for j in (i - 1, i - 2, i - 3):
            if j < 1:
                continue
            R_true = (invert_T(Tw[j]) @ Tw[i])[:3, :3]
            R_pred = (invert_T(Tw[j - 1]) @ Tw[i - 1])[:3, :3]
            h = (K @ R_pred @ np.linalg.inv(K))
            ch = np.c_[c, np.ones(len(c))] @ h.T
            guess = ch[:, :2] / ch[:, 2:]
            out = {"i": i, "j": j, "turn": rotation_angle_deg(R_true)}
            for name, (p, ok) in (("shipped", track(grays[i], grays[j], c, s)),
                                  ("init_flow", track_from(grays[i], grays[j], c, guess, s))):
                Rt = essential_motion(c, p, ok, K)  # as `pair_motion` reads the rotation, without the LiDAR length
                out[name] = np.nan if Rt is None else rotation_angle_deg(Rt[:, :3].T @ R_true)
            rows.append(out)
    for name in ("shipped", "init_flow"):
        e = np.array([r[name] for r in rows])
        turn = np.array([r["turn"] for r in rows]) > 2.0
        print(json.dumps({"variant": name, "pairs": len(rows), "failed_or_none": int(np.isnan(e).sum()),
                          "over_3deg": int((e > 3).sum()), "over_3deg_in_turns": int((e[turn] > 3).sum()),
                          "turn_pairs": int(turn.sum()), "median_turn": round(float(np.nanmedian(e[turn])), 3),
                          "median_straight": round(float(np.nanmedian(e[~turn])), 3)}))


if __name__ == "__main__":
    main()
