"""The frames leaving a refine run's window: the generator's depth times the graph's correction, moved by the
photometric step where no return lies, recorded with the pose the frame leaves with."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from leovr.pipeline.refine_photometric import PhotometricStep
from leovr.pipeline.refine_record import RunRecord
from leovr.pipeline.refine_setup import RunSetup

if TYPE_CHECKING:
    from odometry.window_graph import FrameResult, WindowGraph


class LeavingFrames:
    """Each frame's generator depth, held from its front end until it leaves the window (`hold`, `finish`)."""

    def __init__(self, setup: RunSetup, record: RunRecord, graph: WindowGraph) -> None:
        self.record, self.graph = record, graph
        # a leaving frame's depth where no return lies
        self.photometric = PhotometricStep(setup.seq, setup.cfg, setup.indices, setup.first.K)
        # frame -> generator depth, its log uncertainty, and the road's scale for it (camera only)
        self.pending: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}

    def hold(self, i: int, depth: np.ndarray, log_sigma: np.ndarray, scale: float) -> None:
        self.pending[i] = depth, log_sigma, scale

    def finish(self, results: list[FrameResult]) -> None:
        """The frames leaving the window: refined depth (after the photometric step), both depth PNGs and
        the pose saved; a finished frame of a resumed run only has its replayed pose kept."""
        leaving = {r.index: r.T_world_cam for r in results}  # at the end the whole window leaves at once

        def poses_of(near: list[int]) -> dict[int, np.ndarray]:  # the frames leaving with one: as they leave
            return self.latest_poses(near) | {j: leaving[j] for j in near if j in leaving}

        for r in results:
            gen_depth, log_sigma, scale = self.pending.pop(r.index)
            if r.index in self.record.done:
                self.record.replayed[r.index] = r.T_world_cam
                continue
            refined = np.where(gen_depth > 0, gen_depth * scale * np.exp(r.log_offset), 0.0)
            if r.index in self.photometric:  # where no return lies, the depth its neighbours' images agree with
                refined = self.photometric.correct(r.index, r.T_world_cam, refined, poses_of)
            # the generator's predicted spread (metres), carried to the refined depth (the map's filter)
            sigma = np.exp(log_sigma) * np.where(gen_depth > 0, refined / np.maximum(gen_depth, 1e-6), 0.0)
            maps = {"depth_generator": gen_depth, "depth": refined, "sigma": sigma}
            self.record.finished(r.index, r.T_world_cam, maps, r.step_cov)

    def latest_poses(self, indices_kept: list[int]) -> dict[int, np.ndarray]:
        """The graph's current pose of each frame still in the window, else the pose it left with."""
        out = {}
        for j in indices_kept:
            T = self.graph.poses.get(j)
            T = T if T is not None else self.record.pose(j)
            if T is not None:
                out[j] = T
        return out
