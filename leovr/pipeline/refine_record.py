"""What a refine run has finished, as `--resume` finds it: the progress record (poses, the front end's choices,
times), the frames already done, the poses their replay found, and the finished frames' files, each written
before the record that names it.

A resumed run replays its finished frames through the front end and the window (their outputs are kept, not
rewritten) so that the window, the landmarks and KISS-ICP's map are the uninterrupted run's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.data.run_info import png_name
from leovr.pipeline.frame_writer import FrameWriter
from leovr.pipeline.refine_outputs import Progress, check_replay, write_frame_files


class RunRecord:
    """The run folder's progress record and the finished frames waiting to be written."""

    def __init__(self, out: Path, names: list[int], indices: list[int], resume: bool) -> None:
        self.out, self.names = out, names
        self.path = out / "progress.json"
        self.state = Progress.load(self.path) if resume and self.path.is_file() else Progress()
        self.done = {i for i in indices if i in self.state.poses and (out / "depth" / png_name(names, i)).is_file()}
        self.replayed: dict[int, np.ndarray] = {}  # finished frames' poses as the replay found them
        self.unwritten: list[tuple[str, dict[str, np.ndarray]]] = []  # finished frames' depth maps, to write
        self.empty: list[int] = []  # frames whose LiDAR input has no return inside the image

    def frame_done(
        self, i: int, source: str, T_icp: np.ndarray | None, times: list[float], deskew: np.ndarray | None
    ) -> None:
        """Frame i's turn: the front end's choice of initial pose, KISS-ICP's pose, the stages' times and the motion
        its input was deskewed with (the scoring pass rebuilds that input). A resumed frame's record is completed
        by its replay."""
        state = self.state
        if deskew is not None and i not in state.deskew:  # a record that lacks it: the replay's (the same motion)
            state.deskew[i] = deskew.ravel().tolist()
        if i in self.done and i in state.times:
            return
        state.sources[i] = source
        if T_icp is not None:
            state.icp_poses[i] = T_icp.ravel().tolist()
        state.times[i] = times

    def finished(
        self, i: int, T_world_cam: np.ndarray, maps: dict[str, np.ndarray], step_cov: np.ndarray | None = None
    ) -> None:
        """Frame i left the window: its pose (and how sure the window was of the step into it) recorded, its
        depth maps (folder -> array) queued for writing."""
        self.state.poses[i] = T_world_cam.ravel().tolist()
        if step_cov is not None:
            self.state.step_covariances[i] = step_cov.ravel().tolist()
        self.unwritten.append((png_name(self.names, i), maps))

    def write(self, writer: FrameWriter) -> None:
        """The finished frames' files, each followed by the progress record as it stands now (a resume never
        finds a pose without its files, nor a finished frame without its record)."""
        for name, maps in self.unwritten:
            writer.submit(write_frame_files, self.out, name, maps, self.path, self.state.text())
        self.unwritten.clear()

    def pose(self, j: int) -> np.ndarray | None:
        """The pose frame j left the window with (this run's, or its replay's when it finished before a resume)."""
        if j in self.replayed:
            return self.replayed[j]
        if j in self.state.poses:
            return np.array(self.state.poses[j]).reshape(4, 4)
        return None

    def check_replay(self) -> None:
        """A resumed run's replayed poses against the record it resumed from (refine_outputs.check_replay)."""
        if self.replayed:
            check_replay(self.out, self.state, self.replayed)

    def save(self) -> None:
        self.state.save(self.path)
