"""How sure the sliding window is of each step: the covariance of the relative pose between consecutive frames,
from the window's joint marginal over its poses. The global pose graph of loop closure weighs each odometry step by
it, so a loop's correction goes where the window was least sure (odometry.loop.pose_graph)."""

from __future__ import annotations

import gtsam
import numpy as np

from leovr.geometry import invert_T


def relative_covariance(T_a: np.ndarray, T_b: np.ndarray, joint: np.ndarray) -> np.ndarray:
    """The 6 x 6 covariance of T_a^-1 T_b in gtsam's tangent order (rotation, translation; perturbation on the
    right, in frame b), from the 12 x 12 joint covariance of poses a and b: for T_ab = T_a^-1 T_b the perturbations
    compose as xi_ab = -Ad(T_ab^-1) xi_a + xi_b."""
    rel = gtsam.Pose3(invert_T(T_a) @ T_b)
    A = np.hstack([-rel.inverse().AdjointMap(), np.eye(6)])
    return A @ joint @ A.T


def window_step_covariances(
    factors: gtsam.NonlinearFactorGraph, estimate: gtsam.Values, keys: dict[int, int], poses: dict[int, np.ndarray]
) -> dict[int, np.ndarray]:
    """Frame index -> covariance of the step into it from the frame before it in the window, for every pair of
    consecutive frames in `keys` (frame index -> its pose's key in `factors`). Empty when the window's system
    cannot be inverted (a gauge left free): the caller keeps what it had."""
    frames = sorted(keys)
    if len(frames) < 2:
        return {}
    graph = gtsam.NonlinearFactorGraph()
    for k in range(factors.size()):  # a smoother's graph keeps an empty slot for every factor it removed
        if (f := factors.at(k)) is not None:
            graph.add(f)
    try:
        marginals = gtsam.Marginals(graph, estimate)
        joint = marginals.jointMarginalCovariance(gtsam.KeyVector([keys[i] for i in frames]))
    except RuntimeError:  # an indeterminant system
        return {}
    out = {}
    for a, b in zip(frames, frames[1:]):
        ka, kb = keys[a], keys[b]
        pair = np.block([[joint.at(ka, ka), joint.at(ka, kb)], [joint.at(kb, ka), joint.at(kb, kb)]])
        out[b] = relative_covariance(poses[a], poses[b], pair)
    return out
