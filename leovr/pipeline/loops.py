"""The loop-closure pass over a refined run (LeoVR Sec. IV-B): bag-of-words detection with the
co-visibility rule, geometric validation (PnP both ways, then agreement with a neighbouring loop
through the odometry), and a global pose graph that corrects the poses.

Runs after `run_refine` on its outputs (images from the sequence, refined depth from `depth/`), so it
also works on resumed runs. Writes `loops.json`; returns the corrected poses and the loop records."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from leovr.data.io import write_text
from leovr.data.run_info import read_run_depth
from leovr.data.sequence import Sequence
from leovr.geometry import back_project
from leovr.paths import shipped_vocabulary
from odometry.features import detect
from odometry.loop.detector import LoopDetector
from odometry.loop.pose_graph import optimise_pose_graph
from odometry.loop.validate import consistent_loops, validate_loop
from odometry.loop.vocabulary import Vocabulary


def feature_points(feats, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """3D camera points of the features from a depth map (NaN where the depth is 0)."""
    h, w = depth.shape
    u = np.clip(np.rint(feats.uv[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(feats.uv[:, 1]).astype(int), 0, h - 1)
    z = depth[v, u].astype(np.float64)
    z[z <= 0] = np.nan
    return back_project(feats.uv, z, K)


def loop_pass(
    seq: Sequence,
    run: Path,
    indices: list[int],
    poses: np.ndarray,
    min_gap: int = 30,
    vocabulary: str | Path | None = None,
    step_cov: list[np.ndarray | None] | None = None,
) -> tuple[np.ndarray, list[dict], float]:
    """Detect, validate and close loops; returns (corrected poses, loop records, ms per query). `step_cov`: the
    window's covariance of the step into each of `poses` (None where it has none), the odometry's weights."""
    voc = Vocabulary.load(vocabulary or shipped_vocabulary())
    det = LoopDetector(min_gap=min_gap)
    feats, pts, records, loops, t_query = {}, {}, [], [], []
    validated: list[dict] = []  # records of geometrically validated loops, in the order of `loops`
    for n, i in enumerate(indices):
        f = seq[i]
        feats[n] = detect(f.image)
        pts[n] = feature_points(feats[n], read_run_depth(run, "depth", i, f.shape), f.K)
        t0 = time.perf_counter()
        cand = det.add(n, voc.bow(feats[n].desc))
        t_query.append(time.perf_counter() - t0)
        if cand is None:
            continue
        j, s = cand
        check = validate_loop(feats[n], pts[n], feats[j], pts[j], f.K)
        records.append(
            {
                "frame": i,
                "candidate": indices[j],
                "score": round(float(s), 4),
                "inliers": check.inliers,
                "reprojection_px": round(float(check.reprojection_px), 3),
                "pnp_disagreement_m": round(check.disagree_m, 3),
                "pnp_disagreement_deg": round(check.disagree_deg, 3),
                "accepted": check.accepted,
                "T_j_i": None if check.T_j_i is None else np.round(check.T_j_i, 6).tolist(),
            }
        )
        records[-1]["consistent"] = None
        if check.accepted:
            loops.append((n, j, check.T_j_i))
            validated.append(records[-1])
    keep = consistent_loops(loops, poses)
    for r, ok in zip(validated, keep):
        r["consistent"] = r["accepted"] = ok
    loops = [lp for lp, ok in zip(loops, keep) if ok]
    corrected = optimise_pose_graph(poses, loops, step_cov) if loops else poses
    ms = 1000.0 * float(np.mean(t_query)) if t_query else 0.0
    write_text(
        run / "loops.json",
        json.dumps({"ms_per_query": ms, "vocabulary_words": voc.words, "loops": records}, indent=2) + "\n",
    )
    return corrected, records, ms
