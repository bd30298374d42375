"""Global pose graph over the whole trajectory: odometry between-factors from the sliding window, loop
factors from validated loops, a prior on the first pose; Levenberg-Marquardt."""

from __future__ import annotations

import gtsam
import numpy as np

from leovr.geometry import invert_T


def optimise_pose_graph(poses: np.ndarray, loops: list[tuple[int, int, np.ndarray]], odo_sigma=(0.01, 0.05),
                        loop_sigma=(0.02, 0.1), odo_cauchy: float | None = 1.0) -> np.ndarray:
    """`poses` F x 4 x 4 camera-to-world; `loops` (i, j, T_j_i): camera i seen from camera j.
    Returns the corrected F x 4 x 4 poses.

    `odo_cauchy`: the odometry factors' Cauchy constant (in sigmas; None: Gaussian, as before session 54). A
    front-end step that failed grossly (a tuning lap's fast turn: one step 5 m off) then gives way to the
    validated loops instead of holding them back and spreading its error over the lap; the loops keep their
    Huber kernel, and `consistent_loops` has already asked each of them for a neighbour that agrees."""
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, odo_sigma[0]), np.full(3, odo_sigma[1])])
    if odo_cauchy is not None:
        odo = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(odo_cauchy), odo)
    lc = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                        gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, loop_sigma[0]), np.full(3, loop_sigma[1])]))
    g.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(poses[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for k, T in enumerate(poses):
        v.insert(k, gtsam.Pose3(T))
        if k:
            g.add(gtsam.BetweenFactorPose3(k - 1, k, gtsam.Pose3(invert_T(poses[k - 1]) @ T), odo))
    for i, j, T_j_i in loops:
        g.add(gtsam.BetweenFactorPose3(j, i, gtsam.Pose3(T_j_i), lc))
    res = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
    return np.stack([res.atPose3(k).matrix() for k in range(len(poses))])
