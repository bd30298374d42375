"""The passes of `leovr refine` over the whole recording, after the window has run: the camera-only step
lengths solved again over all frames, and loop closure. Each moves the poses, and the landmarks with them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.config import RefineConfig
from leovr.data.sequence import Sequence
from leovr.geometry import invert_T
from leovr.pipeline.refine_outputs import Progress


def smoothed_step_lengths(poses: np.ndarray, indices: list[int], readings: dict, cfg: RefineConfig) -> np.ndarray:
    """Camera only: the window pass's poses with each step's length solved again over the whole recording
    from the road's readings (`odometry.step_length`); rotations and directions of travel are kept."""
    from odometry.step_length import rescale_steps, smooth_log_lengths

    chain = [readings.get(i) for i in indices[1:]]
    return rescale_steps(poses, np.exp(smooth_log_lengths(chain, cfg.camera_only.length_change_sigma_m)))


def move_poses(state: Progress, indices: list[int], before: np.ndarray, after: np.ndarray, landmarks: np.ndarray,
               seen_by: np.ndarray) -> None:
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


def whole_recording_passes(seq: Sequence, cfg: RefineConfig, out: Path, indices: list[int], state: Progress,
                           landmarks: np.ndarray, seen_by: np.ndarray, smooth_lengths: bool,
                           length_readings: dict) -> None:
    """The camera-only step lengths (`smooth_lengths`: a camera-only run with the road's height, not causal)
    and loop closure (`cfg.loop.enabled`), each keeping the poses it started from in `state`."""
    if smooth_lengths and cfg.camera_only.length_smoothing and len(indices) > 2:
        before = state.stacked("poses", indices)
        state.poses_window = {i: T.ravel().tolist() for i, T in zip(indices, before)}
        after = smoothed_step_lengths(before, indices, length_readings, cfg)
        move_poses(state, indices, before, after, landmarks, seen_by)
    if cfg.loop.enabled:
        from leovr.pipeline.loops import loop_pass

        before, loop = state.stacked("poses", indices), cfg.loop
        corrected, _, _ = loop_pass(seq, out, indices, before, loop.min_gap, loop.vocabulary, loop.odometry_cauchy)
        state.poses_no_loop = {i: T.ravel().tolist() for i, T in zip(indices, before)}
        move_poses(state, indices, before, corrected, landmarks, seen_by)
