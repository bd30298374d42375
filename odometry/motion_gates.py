"""Gates on the motions the window graph takes from other estimators: an image pair motion or a KISS-ICP motion
enters the window only where it agrees with another estimate of the same motion, and a new pose starts from a
candidate that turns as the images' pair motion does. A pair's tracks can fail together in a fast turn, and a cone
LiDAR's registration can slip or slide there, each while sure of itself; a tight between factor from either pulls
the poses however robust its kernel.
"""

from __future__ import annotations

import cv2
import numpy as np

from leovr.geometry import invert_T, rotation_angle_deg
from odometry.mono_vo import relative_motion

# a pair motion whose rotation is this far (deg) from both the initial pose's and the front end's essential matrix
# is left out (docs/decisions/0006-pair-factors-cone-only.md); 0: no gate
PAIR_GATE_DEG = 3.0
# a KISS-ICP motion whose rotation is this far (deg) from the images' is left out of the window (`icp_agrees`):
# on a cone KISS-ICP can slip by tens of degrees in a fast turn while sure of itself
# (docs/decisions/0011-tuned-settings.md)
ICP_GATE_DEG = 3.0
# ... and one whose direction of travel is this far (deg) from the images' (the pair motion's essential matrix),
# where both travel at least ICP_DIRECTION_MIN_M: a cone's registration slides sideways while sure of itself, and
# over a shorter baseline the images' direction is the less sure (docs/decisions/0013-icp-direction-gate.md)
ICP_DIRECTION_GATE_DEG = 3.0
ICP_DIRECTION_MIN_M = 1.0


# an initial pose candidate (KISS-ICP's step, PnP) whose rotation is this far (deg) from the images' pair motion from
# the previous frame is passed over (`turning_as_the_images`): from a wrong start the window's robust kernels take the
# images' tight pair factors for outliers and keep the pose where it started
# (docs/decisions/0020-initial-pose-turns-as-the-images.md)
INIT_GATE_DEG = 1.0


def turning_as_the_images(
    cands: dict[str, np.ndarray | None], T_prev: np.ndarray, images_step: np.ndarray | None
) -> dict[str, np.ndarray | None]:
    """The candidates (world poses) whose step from `T_prev` turns within INIT_GATE_DEG of `images_step`; all of
    them when there is no images' step or none does."""
    if images_step is None:
        return cands
    kept = {
        name: T
        for name, T in cands.items()
        if T is not None and rotation_angle_deg(images_step[:3, :3].T @ (invert_T(T_prev) @ T)[:3, :3]) <= INIT_GATE_DEG
    }
    return kept or cands


def direction_agrees(t_images: np.ndarray, t_icp: np.ndarray) -> bool:
    """Whether two motions' translations point within ICP_DIRECTION_GATE_DEG of each other; true when either is
    shorter than ICP_DIRECTION_MIN_M (a direction read over a short baseline says little)."""
    la, lb = float(np.linalg.norm(t_images)), float(np.linalg.norm(t_icp))
    if min(la, lb) < ICP_DIRECTION_MIN_M:
        return True
    cos = float(t_images @ t_icp) / (la * lb)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))) <= ICP_DIRECTION_GATE_DEG


def pair_agrees(
    T: np.ndarray,
    j: int,
    T_init: np.ndarray,
    matches_prev: tuple[int, np.ndarray, np.ndarray] | None,
    poses: dict[int, np.ndarray],
    K: np.ndarray,
    second: list[np.ndarray | None],
) -> bool:
    """Whether the pair motion T (this frame to window frame j) may enter the window: its rotation lies within
    PAIR_GATE_DEG of the initial pose's (`T_init`, chained to j through the window's `poses`), or else of the
    rotation of the essential matrix of the front end's matches with the previous frame (`matches_prev`, chained to
    j likewise). `second` caches that rotation across one frame's pairs: computed once and only when needed."""
    gate = PAIR_GATE_DEG
    if gate <= 0:
        return True
    R_pair = T[:3, :3]
    if rotation_angle_deg(R_pair.T @ (invert_T(poses[j]) @ T_init)[:3, :3]) <= gate:
        return True
    if matches_prev is None or matches_prev[0] not in poses:
        return False
    if not second:
        motion, _ = relative_motion(matches_prev[1], matches_prev[2], K, method=cv2.USAC_ACCURATE)
        second.append(None if motion is None else motion[:3, :3])
    if second[0] is None:
        return False
    R_ref = (invert_T(poses[j]) @ poses[matches_prev[0]])[:3, :3] @ second[0]
    return rotation_angle_deg(R_pair.T @ R_ref) <= gate


def icp_agrees(
    motion: np.ndarray,
    j: int,
    pair: np.ndarray | None,
    T_init: np.ndarray,
    T_prev_rel: np.ndarray | None,
    poses: dict[int, np.ndarray],
    last: int | None,
) -> bool:
    """Whether KISS-ICP's motion from window frame j to this frame may enter the window: its rotation lies within
    ICP_GATE_DEG of the images' (the pair motion to j, else the front end's motion `T_prev_rel` from the window's
    newest frame `last`, chained back to j through the window's `poses`, else the initial pose's) and, where there is
    a pair motion, its direction of travel agrees with the pair's (`direction_agrees`)."""
    ref = pair
    if ref is None:
        ref = (
            invert_T(poses[j]) @ poses[last] @ T_prev_rel
            if T_prev_rel is not None and last in poses
            else invert_T(poses[j]) @ T_init
        )
    return not (
        rotation_angle_deg(ref[:3, :3].T @ motion[:3, :3]) > ICP_GATE_DEG
        or (pair is not None and not direction_agrees(pair[:3, 3], motion[:3, 3]))
    )
