"""Global pose graph over the whole trajectory: odometry between-factors from the sliding window, loop
factors from validated loops, a prior on the first pose; Levenberg-Marquardt."""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np

from leovr.geometry import invert_T

ODOMETRY_SIGMA_M = 0.05  # the median odometry step's translation sigma (m)
ODOMETRY_SIGMA_RAD = 0.01  # without the window's covariances: every step's rotation sigma (rad)


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


def odometry_noises(step_cov: list[np.ndarray | None] | None, n: int) -> list[gtsam.noiseModel.Base]:
    """The noise of each of the n - 1 odometry steps (step k into pose k at index k - 1): the sliding window's
    covariance of that step, scaled by one factor per run so that the median translation sigma is
    ODOMETRY_SIGMA_M. The window treats its factors as independent, so its covariances come out several times too
    small (on the rendered laps 2.5-5x); what the graph takes from them is their size along the run (a loop's
    correction goes where the window was least sure) and their shape (the rotation known far better than the
    translation). A step without one gets the median per-axis variance; a run without any, ODOMETRY_SIGMA_RAD
    and ODOMETRY_SIGMA_M."""
    steps = (list(step_cov or []) + [None] * n)[1:n]
    steps = [None if c is None else np.asarray(c, float).reshape(6, 6) for c in steps]
    given = [c for c in steps if c is not None]
    if not given:
        return [diagonal(ODOMETRY_SIGMA_RAD, ODOMETRY_SIGMA_M)] * (n - 1)
    median = np.diag(np.median([np.diag(c) for c in given], axis=0))
    scale = ODOMETRY_SIGMA_M**2 / np.median([np.trace(c[3:, 3:]) / 3 for c in given])
    covs = [median if c is None else (c + c.T) / 2 for c in steps]
    return [gtsam.noiseModel.Gaussian.Covariance(scale * c) for c in covs]


def optimise_pose_graph(
    poses: np.ndarray,
    loops: list[tuple[int, int, np.ndarray]],
    step_cov: list[np.ndarray | None] | None = None,
    loop_sigma=(0.02, 0.1),
) -> np.ndarray:
    """`poses` F x 4 x 4 camera-to-world; `loops` (i, j, T_j_i): camera i seen from camera j; `step_cov` the
    window's covariance of the step into each pose (None where it has none; `odometry_noises`). Returns the
    corrected F x 4 x 4 poses.

    The odometry factors are Gaussian: a robust kernel over them, at the scale the window's covariances give,
    let steps give way that were right and bent the lap where the loops pulled hardest. The loops keep their
    Huber kernel, and `consistent_loops` has already asked each of them for a neighbour that agrees."""
    noises = odometry_noises(step_cov, len(poses))
    lc = robust(gtsam.noiseModel.mEstimator.Huber.Create(1.345), diagonal(*loop_sigma))
    return solve_pose_graph(*build_pose_graph(poses, loops, lambda k: noises[k - 1], lc), len(poses))
