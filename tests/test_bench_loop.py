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
    loops = [
        {"frame": 40, "candidate": 0, "accepted": True, "T_j_i": good.tolist()},
        {"frame": 39, "candidate": 1, "accepted": True, "T_j_i": off.tolist()},
        {"frame": 38, "candidate": 2, "accepted": False, "T_j_i": good.tolist()},
    ]
    (tmp_path / "loops.json").write_text(json.dumps({"loops": loops, "ms_per_query": 1.0}))
    r = loop_truth(tmp_path, gt, min_gap=30)
    assert (r["loops_accepted"], r["loops_true"], r["loops_false"]) == (2, 1, 1)
    errs = {e["frame"]: e for e in r["accepted_errors"]}
    assert errs[40]["true"] and errs[40]["error_m"] < 1e-9
    assert not errs[39]["true"] and errs[39]["error_m"] > 1.0
    # without ground truth (the real clips) every accepted loop is false
    assert loop_truth(tmp_path, None, min_gap=30)["loops_false"] == 2


def test_the_ideal_loops_close_a_drifted_lap_with_the_runs_own_pose_graph(tmp_path):
    """A circular lap whose poses drifted in heading: given the true relative pose at the accepted loop's frame pair,
    the run's pose graph brings the ATE well below the drifted lap's; no accepted loop, no figure."""
    from scipy.spatial.transform import Rotation

    from leovr.bench.loop import ideal_loop_ate
    from leovr.pipeline.refine_outputs import Progress
    from leovr.eval.trajectory import trajectory_metrics

    n = 40
    gt = []
    for k in range(n):
        a = 2 * np.pi * k / n
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec([0, -a, 0]).as_matrix()
        T[0, 3], T[2, 3] = 20 * (1 - np.cos(a)), 20 * np.sin(a)
        gt.append(T)
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_rotvec([0, 0.002, 0]).as_matrix()  # each step turned 0.002 rad too far
    drifted = [gt[0]]
    for k in range(1, n):
        drifted.append(drifted[-1] @ np.linalg.inv(gt[k - 1]) @ gt[k] @ turn)
    Progress(poses_no_loop={k: T.ravel().tolist() for k, T in enumerate(drifted)}).save(tmp_path / "progress.json")
    loops = [{"frame": 39, "candidate": 0, "accepted": True}, {"frame": 38, "candidate": 1, "accepted": False}]
    (tmp_path / "loops.json").write_text(json.dumps({"loops": loops, "ms_per_query": 1.0}))
    before = trajectory_metrics(np.stack(drifted), np.stack(gt))["ate_m"]
    ideal = ideal_loop_ate(tmp_path, gt)
    assert before > 0.4 and ideal < 0.1 * before, (before, ideal)
    (tmp_path / "loops.json").write_text(json.dumps({"loops": loops[1:], "ms_per_query": 1.0}))
    assert ideal_loop_ate(tmp_path, gt) is None
