"""Session 54 development check (issue 16): every decision of the initial-pose step gate (`refine.initial_step_gate_m`)
on a *tuning* lap or validation drive: the candidate's step and the window graph's last step against the truth,
the deviation and the tolerance, and whether it was kept.

    .venv/bin/python docs/dev/session54/gate_decisions.py SEQ [--end N] [--from F] [--cfg '{}']
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
from leovr.geometry import invert_T  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequence")
    ap.add_argument("--end", type=int, default=None)
    ap.add_argument("--from", dest="start", type=int, default=0)
    ap.add_argument("--cfg", default="{}")
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    gt = {i: seq[i].T_world_cam for i in range(len(seq))}
    now = {}
    process, drivable = fe.FrontEnd.process, fe.drivable

    def traced_process(self, index, *args, **kw):
        now["i"], now["j"] = index, self.prev.index if self.prev is not None else None
        now["k"] = self.prev_prev
        return process(self, index, *args, **kw)

    def traced(T_rel, last, tol_m, tol_rel):
        ok = drivable(T_rel, last, tol_m, tol_rel)
        i, j, k = now["i"], now["j"], now["k"]
        if i >= a.start:
            true, true_last = invert_T(gt[j]) @ gt[i], invert_T(gt[k]) @ gt[j]
            print(json.dumps({"frame": i, "kept": ok, "dev": round(float(np.linalg.norm(T_rel[:3, 3] - last[:3, 3])), 2),
                              "tol": round(tol_m + tol_rel * float(np.linalg.norm(last[:3, 3])), 2),
                              "cand_err_m": round(float(np.linalg.norm(T_rel[:3, 3] - true[:3, 3])), 2),
                              "last_err_m": round(float(np.linalg.norm(last[:3, 3] - true_last[:3, 3])), 2),
                              "cand": np.round(T_rel[:3, 3], 2).tolist(), "last": np.round(last[:3, 3], 2).tolist()}), flush=True)
        return ok

    fe.FrontEnd.process, fe.drivable = traced_process, traced
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, RefineConfig(end=a.end, **json.loads(a.cfg)), Path(tmp) / "run", progress=False)


if __name__ == "__main__":
    main()
