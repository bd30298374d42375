"""Session 54 development check (issue 16): the front end's initial-pose candidates (PnP, KISS-ICP) on a *tuning* lap
or validation drive with LiDAR: each candidate's step against the truth, its reprojection inliers (how
`choose_pose` picks) and the fraction of the frame's matches that satisfy its epipolar geometry (Sampson < 2 px).

    .venv/bin/python docs/dev/session54/trace_init.py SEQ --end N [--frames 110 111 112] [--cfg '{}']
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

import odometry.frontend as fe  # noqa: E402
from leovr.config import RefineConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T, rotation_angle_deg as ang  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402
from odometry.initial_pose import reprojection_inliers  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence")
    ap.add_argument("--end", type=int, required=True)
    ap.add_argument("--frames", type=int, nargs="*", default=None)
    ap.add_argument("--cfg", default="{}")
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    gt = {i: seq[i].T_world_cam for i in range(len(seq))}
    ctx: dict = {}
    process, choose = fe.FrontEnd.process, fe.choose_pose

    def traced_process(self, index, image, *args, **kw):
        ctx["index"], ctx["prev"] = index, self.prev.index if self.prev is not None else None
        ctx["graph"] = args[4] if len(args) > 4 else kw.get("graph")
        return process(self, index, image, *args, **kw)

    def traced_choose(cands, obj, img, K, px=2.0):
        best = choose(cands, obj, img, K, px)
        i, j = ctx["index"], ctx["prev"]
        if a.frames is None or i in a.frames:
            T_prev = ctx["graph"].pose(j)
            true = invert_T(gt[j]) @ gt[i]
            row = {"frame": i, "chosen": best.source if best else None, "n_matches": len(obj)}
            uv0 = ctx.get("uv0")
            for name, T in cands.items():
                if T is None:
                    continue
                rel = invert_T(T_prev) @ T
                e = invert_T(true) @ rel
                row[name] = {"step": np.round(rel[:3, 3], 2).tolist(), "err_m": round(float(np.linalg.norm(e[:3, 3])), 2),
                             "err_deg": round(ang(e[:3, :3]), 2), "inliers": int(reprojection_inliers(T, obj, img, K, px).sum())}
                if uv0 is not None and len(uv0) == len(img):
                    row[name]["epipolar"] = round(float(np.mean(fe.sampson_px(rel, uv0, img, K) < 2.0)), 2)
            row["true_step"] = np.round(true[:3, 3], 2).tolist()
            print(json.dumps(row), flush=True)
        return best

    match = fe.match

    def traced_match(fa, fb):
        ia, ib = match(fa, fb)
        ctx["uv0"] = fa.uv[ia].astype(np.float64)
        return ia, ib

    fe.FrontEnd.process, fe.choose_pose, fe.match = traced_process, traced_choose, traced_match
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, RefineConfig(end=a.end, **json.loads(a.cfg)), Path(tmp) / "run", progress=False)


if __name__ == "__main__":
    main()
