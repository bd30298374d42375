"""Session 52 development check (issue 16): every decision of the pair gate (`refine.pair_gate_deg`) on a development
sequence, with each pair's, the initial pose's and the matches' rotation error against the truth (degrees); and, with
`--steps LO HI`, the final per-step yaw of the run's poses over frames LO..HI against the truth. Tuning laps and
validation drives only.

    .venv/bin/python docs/dev/session52/pair_decisions.py SEQ [--end N] [--steps LO HI] [--cfg '{"pair_factors": false}']
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import odometry.window_graph as wg  # noqa: E402
from leovr.config import RefineConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T, rotation_angle_deg as ang  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402


def yaw(R: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(R[0, 2], R[2, 2])))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence")
    ap.add_argument("--end", type=int, default=None)
    ap.add_argument("--steps", type=int, nargs=2, default=None)
    ap.add_argument("--cfg", default="{}", help="RefineConfig overrides as JSON")
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    gt = {i: seq[i].T_world_cam for i in range(len(seq))}
    agrees = wg.WindowGraph._pair_agrees

    def logged(self, f, j, T, second):
        ok = agrees(self, f, j, T, second)
        init = invert_T(self.poses[j]) @ f.T_init
        true = (invert_T(gt[j]) @ gt[f.index])[:3, :3]
        if ang(T[:3, :3].T @ init[:3, :3]) > self.cfg.pair_gate_deg:
            sec = None
            if second and second[0] is not None:
                R_ref = (invert_T(self.poses[j]) @ self.poses[f.matches_prev[0]])[:3, :3] @ second[0]
                sec = round(ang(R_ref.T @ true), 2)
            print(json.dumps({"frame": f.index, "pair_to": j, "kept": ok, "pair_err": round(ang(T[:3, :3].T @ true), 2),
                              "init_err": round(ang(init[:3, :3].T @ true), 2), "matches_err": sec}), flush=True)
        return ok

    wg.WindowGraph._pair_agrees = logged
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, RefineConfig(end=a.end, **json.loads(a.cfg)), Path(tmp) / "run", progress=False)
        state = json.loads((Path(tmp) / "run" / "progress.json").read_text())
    if a.steps:
        P = {int(k): np.array(v).reshape(4, 4) for k, v in state["poses"].items()}
        for i in range(*a.steps):
            if i in P and i - 1 in P:
                print(json.dumps({"frame": i, "true_yaw": round(yaw((invert_T(gt[i - 1]) @ gt[i])[:3, :3]), 2),
                                  "yaw": round(yaw((invert_T(P[i - 1]) @ P[i])[:3, :3]), 2)}))


if __name__ == "__main__":
    main()
