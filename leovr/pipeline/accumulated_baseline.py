"""`nearest_accumulated` and `ipbasic_accumulated`: the classical yardsticks for a refinement that sees
several frames.

With a cone LiDAR (Mid-40), `refine` gives each frame's generator the returns of the earlier frames and
corrects it with the images of the later ones; a single-frame fill sees one scan. These baselines give the
fill the same frames: the cheap returns of the frames up to `reach` before and after (before only, `causal`),
each deskewed and placed in the frame's camera with KISS-ICP's poses on the same cheap input (nothing of
leovr's), the nearest return kept per pixel, then filled as `nearest` and `ipbasic` fill one scan.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig
from leovr.data.sequence import Sequence
from leovr.depth.fills import complete_depth
from leovr.geometry import invert_T
from leovr.lidar.projection import sparse_depth
from leovr.pipeline.refine_input import frame_sample

ACCUMULATED = ("nearest_accumulated", "ipbasic_accumulated")


class Scores(Protocol):
    """A frame's depth scores (`refine_metrics.FrameScore`): one more method's depth added."""

    def add(self, method: str, depth: np.ndarray) -> None: ...


def accumulated_fills(
    seq: Sequence,
    indices: list[int],
    ccfg: CompleteConfig,
    poses: np.ndarray,
    scored: dict[int, Scores],
    frames: list[int],
    reach: int,
    causal: bool = False,
    frame_dt: float = 0.1,
    progress: bool = False,
) -> None:
    """Add both accumulated fills to the scores of `frames` (frames of the run's `indices`, whose camera
    poses `poses` holds in the same order). Each frame's cheap scan is read once, in order."""
    position = {j: n for n, j in enumerate(indices)}
    cache: dict[int, np.ndarray] = {}  # frame -> its cheap returns in its camera (deskewed)
    K, shape = None, None

    def cheap_scan(j: int) -> np.ndarray:
        nonlocal K, shape
        if j not in cache:
            n = position[j]
            # KISS-ICP's motion over the sweep
            step = (
                invert_T(poses[n]) @ poses[n + 1]
                if n + 1 < len(indices)
                else invert_T(poses[n - 1]) @ poses[n]
                if n
                else None
            )
            sample = frame_sample(seq, j, ccfg, step, frame_dt, truth=False)
            K, shape, T_cl = sample.frame.K, sample.frame.shape, sample.frame.T_cam_lidar
            kept = sample.kept_points
            pts = np.zeros((0, 3)) if kept is None else kept[:, :3].astype(np.float64)
            cache[j] = pts @ T_cl[:3, :3].T + T_cl[:3, 3]
        return cache[j]

    for i in tqdm(
        sorted(frames, key=position.get),
        desc="score accumulated fills",
        unit="frame",
        disable=not progress or not frames,
    ):
        n = position[i]
        near = indices[max(0, n - reach) : n + 1 if causal else n + reach + 1]
        for j in [j for j in cache if j not in near]:
            cache.pop(j)
        T_i = invert_T(poses[n])
        moved = []
        for j in near:
            T = T_i @ poses[position[j]]  # camera j in camera i
            moved.append(cheap_scan(j) @ T[:3, :3].T + T[:3, 3])
        sparse = sparse_depth(np.concatenate(moved), K, np.eye(4), shape)
        scored[i].add("nearest_accumulated", complete_depth(sparse, "nearest"))
        scored[i].add("ipbasic_accumulated", complete_depth(sparse, "ipbasic"))
