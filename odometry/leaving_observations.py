"""The observations, by a frame leaving the window, of landmarks that stay in it: conditioned on the leaving pose
instead of marginalised. Marginalised, they tied every such landmark to every other in one dense factor (about 300
keys, 1000 dimensions on a KITTI frame) that each later update linearised and eliminated again; conditioned, each
landmark keeps the anchor the old frame gave it and the graph stays sparse. The leaving pose's own uncertainty is
what this leaves out.
"""

from __future__ import annotations

import gtsam
import numpy as np


def conditioned_observations(
    factors: gtsam.NonlinearFactorGraph,
    leaving: dict[int, np.ndarray],
    staying: set[int],
    landmarks: dict[int, np.ndarray],
    graph: gtsam.NonlinearFactorGraph,
) -> list[int]:
    """The factors of the smoother's graph (`factors`) keyed (leaving pose, staying landmark): returns their indices
    in it (to remove) and adds to `graph` each one conditioned on the leaving pose (a linear factor on the landmark
    alone, taken at the current estimate). `leaving`: each leaving pose's key and its estimate (camera to world);
    `staying`: the staying landmarks' keys; `landmarks`: the landmarks' estimates by index."""
    drop = []
    for n in range(factors.size()):
        fac = factors.at(n)
        if fac is None:
            continue
        keys = fac.keys()
        if len(keys) != 2 or keys[0] not in leaving or keys[1] not in staying:
            continue  # projection and LiDAR point factors are keyed (pose, landmark)
        values = gtsam.Values()
        values.insert(keys[0], gtsam.Pose3(leaving[keys[0]]))
        values.insert(keys[1], landmarks[gtsam.Symbol(keys[1]).index()])
        A, b = fac.linearize(values).jacobian()  # whitened, columns [pose 6 | landmark 3]
        point = gtsam.Values()
        point.insert(keys[1], values.atPoint3(keys[1]))
        graph.add(
            gtsam.LinearContainerFactor(
                gtsam.JacobianFactor(keys[1], A[:, 6:], b, gtsam.noiseModel.Unit.Create(len(b))), point
            )
        )
        drop.append(n)
    return drop
