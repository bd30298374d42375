"""`leovr bench loop` scores each accepted loop against the ground-truth relative pose."""

from __future__ import annotations

import json

import numpy as np

from leovr.bench.loop import loop_truth


def _pose(x: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


def test_loop_truth_counts_a_loop_measured_too_far_off_as_false_and_says_by_how_much(tmp_path):
    # a straight drive out and back along the same line: frame 40 revisits frame 0
    gt = [_pose(0.0, float(k)) for k in range(21)] + [_pose(0.0, float(20 - (k - 20))) for k in range(21, 41)]
    good = np.linalg.inv(gt[0]) @ gt[40]
    off = good.copy()
    off[0, 3] += 1.33  # the right place, measured 1.33 m off
    loops = [{"frame": 40, "candidate": 0, "accepted": True, "T_j_i": good.tolist()},
             {"frame": 39, "candidate": 1, "accepted": True, "T_j_i": off.tolist()},
             {"frame": 38, "candidate": 2, "accepted": False, "T_j_i": good.tolist()}]
    (tmp_path / "loops.json").write_text(json.dumps({"loops": loops, "ms_per_query": 1.0}))
    r = loop_truth(tmp_path, gt, min_gap=30)
    assert (r["loops_accepted"], r["loops_true"], r["loops_false"]) == (2, 1, 1)
    errs = {e["frame"]: e for e in r["accepted_errors"]}
    assert errs[40]["true"] and errs[40]["error_m"] < 1e-9
    assert not errs[39]["true"] and errs[39]["error_m"] > 1.0
    # without ground truth (the real clips) every accepted loop is false
    assert loop_truth(tmp_path, None, min_gap=30)["loops_false"] == 2
