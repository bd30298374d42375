"""The pass of `leovr refine` over the whole recording, after the window has run: loop closure. It moves the
poses, and the landmarks with them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.config import RefineConfig
from leovr.data.sequence import Sequence
from leovr.geometry import invert_T
from leovr.pipeline.refine_outputs import Progress


def move_poses(
    state: Progress,
    indices: list[int],
    before: np.ndarray,
    after: np.ndarray,
    landmarks: np.ndarray,
    seen_by: np.ndarray,
) -> None:
    """A whole-recording pass moved the poses: keep them, and move each landmark (in place) with the frame
    that last observed it."""
    state.poses = {i: T.ravel().tolist() for i, T in zip(indices, after)}
    moves = after @ np.stack([invert_T(T) for T in before])  # per frame: its old pose to its new one
    order = np.argsort(indices)
    at = np.searchsorted(np.asarray(indices)[order], seen_by).clip(0, len(indices) - 1)
    n = order[at]
    mine = np.asarray(indices)[n] == seen_by  # landmarks whose frame is one of the poses
    D = moves[n[mine]]
    landmarks[mine] = np.einsum("nij,nj->ni", D[:, :3, :3], landmarks[mine]) + D[:, :3, 3]


def whole_recording_passes(
    seq: Sequence,
    cfg: RefineConfig,
    out: Path,
    indices: list[int],
    state: Progress,
    landmarks: np.ndarray,
    seen_by: np.ndarray,
) -> None:
    """Loop closure (`cfg.loop.enabled`), keeping the poses it started from in `state`."""
    if cfg.loop.enabled:
        from leovr.pipeline.loops import loop_pass

        before, loop = state.stacked("poses", indices), cfg.loop
        step_cov = state.covariances(indices)
        corrected, _, _ = loop_pass(seq, out, indices, before, loop.min_gap, loop.vocabulary, step_cov)
        state.poses_no_loop = {i: T.ravel().tolist() for i, T in zip(indices, before)}
        move_poses(state, indices, before, corrected, landmarks, seen_by)
