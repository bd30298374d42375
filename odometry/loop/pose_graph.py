"""Global pose graph over the whole trajectory: odometry between-factors from the sliding window, loop
factors from validated loops, a prior on the first pose; Levenberg-Marquardt."""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np

from leovr.geometry import invert_T


def diagonal(rot: float, trans: float) -> gtsam.noiseModel.Base:
    """Pose3 noise: `rot` rad on the rotation, `trans` m on the translation (gtsam's tangent order)."""
    return gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, rot), np.full(3, trans)])


def robust(kernel, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    """`base` under an m-estimator (`gtsam.noiseModel.mEstimator.X.Create(c)`); None keeps it Gaussian."""
    return base if kernel is None else gtsam.noiseModel.Robust.Create(kernel, base)


def build_pose_graph(
    poses: np.ndarray,
    loops: list[tuple[int, int, np.ndarray]],
    odo_noise: Callable[[int], gtsam.noiseModel.Base],
    loop_noise: gtsam.noiseModel.Base,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The graph and its initial values: a prior on the first pose, one between-factor per odometry step
    (`odo_noise(k)` for the step into pose k) and one per loop."""
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(poses[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for k, T in enumerate(poses):
        v.insert(k, gtsam.Pose3(T))
        if k:
            g.add(gtsam.BetweenFactorPose3(k - 1, k, gtsam.Pose3(invert_T(poses[k - 1]) @ T), odo_noise(k)))
    for i, j, T_j_i in loops:
        g.add(gtsam.BetweenFactorPose3(j, i, gtsam.Pose3(T_j_i), loop_noise))
    return g, v


def solve_pose_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n: int) -> np.ndarray:
    """Levenberg-Marquardt from `values`; the n poses (keys 0..n-1) as n x 4 x 4 camera-to-world."""
    res = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return np.stack([res.atPose3(k).matrix() for k in range(n)])


def optimise_pose_graph(
    poses: np.ndarray,
    loops: list[tuple[int, int, np.ndarray]],
    odo_sigma=(0.01, 0.05),
    loop_sigma=(0.02, 0.1),
    odo_cauchy: float = 1.0,
) -> np.ndarray:
    """`poses` F x 4 x 4 camera-to-world; `loops` (i, j, T_j_i): camera i seen from camera j.
    Returns the corrected F x 4 x 4 poses.

    `odo_cauchy`: the odometry factors' Cauchy constant (in sigmas). A
    front-end step that failed grossly (a tuning lap's fast turn: one step 5 m off) then gives way to the
    validated loops instead of holding them back and spreading its error over the lap; the loops keep their
    Huber kernel, and `consistent_loops` has already asked each of them for a neighbour that agrees."""
    M = gtsam.noiseModel.mEstimator
    odo = robust(M.Cauchy.Create(odo_cauchy), diagonal(*odo_sigma))
    lc = robust(M.Huber.Create(1.345), diagonal(*loop_sigma))
    return solve_pose_graph(*build_pose_graph(poses, loops, lambda k: odo, lc), len(poses))
