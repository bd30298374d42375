"""What a refine run scores beside its outputs: each frame against its held-out truth, the classical fills on the
very same input, and after the last frame the single-frame generator, the pose baselines (the textbook monocular
VO with `--compare`, KISS-ICP with and without its deskew) and the accumulated fills of a cone LiDAR."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.config import CompleteConfig, RefineConfig
from leovr.data.io import write_depth_png
from leovr.data.kitti_common import write_kitti_poses
from leovr.data.records import Frame
from leovr.data.run_info import png_name
from leovr.data.sequence import Sequence
from leovr.depth.fills import complete_depth
from leovr.pipeline.accumulated_baseline import accumulated_fills
from leovr.pipeline.completion import EvalSample, with_truth
from leovr.pipeline.frame_writer import FrameWriter
from leovr.pipeline.kiss_baseline import kiss_icp_trajectories
from leovr.pipeline.refine_outputs import FrameScore, single_frame_generator


class RunScoring:
    """The frames' scores (`scored`, frames of this process only) and the textbook VO's poses, kept while the run
    goes; `conclude` adds what needs the whole run."""

    def __init__(
        self, seq: Sequence, cfg: RefineConfig, ccfg: CompleteConfig, out: Path, score: bool, first: Frame
    ) -> None:
        from odometry.mono_vo import MonoVO

        self.seq, self.cfg, self.ccfg, self.out, self.score, self.first = seq, cfg, ccfg, out, score, first
        self.names = seq.frame_numbers()
        self.scored: dict[int, FrameScore] = {}
        self.textbook = MonoVO(first.K) if cfg.compare else None  # the `mono_vo` baseline on the same images

    def frame(
        self, i: int, sample: EvalSample, finished: bool, has_lidar: bool, several: bool, writer: FrameWriter
    ) -> None:
        """Frame i's score (its held-out truth built here) and the classical fills on the very same input: IP-Basic
        written beside the run's depth, both scored; nothing for a frame `finished` before a resume. `several`:
        earlier scans join the generator's input (its own input kept, for the single-frame generator)."""
        fs = FrameScore.of(with_truth(sample, self.ccfg)) if self.score and not finished else None
        if fs is not None:
            self.scored[i] = fs
        if fs is not None and several:
            fs.own_input = (*np.nonzero(sample.sparse), sample.sparse[sample.sparse > 0])
        if has_lidar and not finished:
            ipb = complete_depth(sample.sparse, "ipbasic")
            writer.submit(write_depth_png, self.out / "depth_ipbasic" / png_name(self.names, i), ipb)
            if fs is not None:
                fs.add("ipbasic", ipb)
                fs.add("nearest", complete_depth(sample.sparse, "nearest"))

    def image(self, image: np.ndarray) -> None:
        """The textbook VO's step on the frame's image (--compare)."""
        if self.textbook is not None:
            self.textbook.add(image)

    def depth(self, i: int, generator: np.ndarray, refined: np.ndarray) -> None:
        """A leaving frame's generator and refined depth, scored where the frame is."""
        if i in self.scored:
            self.scored[i].add("generator", generator)
            self.scored[i].add("refined", refined)

    def conclude(
        self,
        indices: list[int],
        has_lidar: bool,
        generator,
        frame_dt: float,
        progress: bool,
    ) -> dict[str, tuple[np.ndarray, str]]:
        """After the last frame: the single-frame generator's scores, the pose baselines (their files written) and,
        where earlier scans joined the generator's input, the accumulated fills; the baselines (name -> poses,
        alignment)."""
        several = [i for i, fs in self.scored.items() if fs.own_input is not None]
        single_frame_generator(self.seq, self.scored, generator, progress)
        baselines, icp = self.pose_baselines(indices, has_lidar, bool(several), progress)
        if several and icp is not None:  # the fills given the same frames: the yardstick for a cone's several scans
            accumulated_fills(
                self.seq,
                indices,
                self.ccfg,
                icp,
                self.scored,
                several,
                self.cfg.accumulation.frames,
                causal=self.cfg.causal,
                frame_dt=frame_dt,
                progress=progress,
            )
        return baselines

    def pose_baselines(
        self, indices: list[int], has_lidar: bool, several: bool, progress: bool
    ) -> tuple[dict[str, tuple[np.ndarray, str]], np.ndarray | None]:
        """The trajectories scored beside leovr's (name -> poses, alignment), their pose files written, and
        KISS-ICP's poses (None when it did not run): the textbook monocular VO (`--compare`), KISS-ICP with
        and without its deskew (with a LiDAR, when compared, scored, or the accumulated fills need it)."""
        seq, cfg, out = self.seq, self.cfg, self.out
        baselines: dict[str, tuple[np.ndarray, str]] = {}
        if self.textbook is not None:
            baselines["mono_vo"] = np.stack(self.textbook.poses), "sim3"
            write_kitti_poses(out / "poses_mono_vo_kitti.txt", baselines["mono_vo"][0])
        icp = None
        first = self.first
        if has_lidar and (cfg.compare or several or self.score and first.T_world_cam is not None):
            # without its deskew too where scans carry point times: the other way to run it
            runs = kiss_icp_trajectories(
                seq, indices, self.ccfg, (True, False) if first.point_times is not None else (True,), progress
            )
            for deskew, name in ((True, "kiss_icp"), (False, "kiss_icp_no_deskew")):
                if runs is not None and deskew in runs:
                    baselines[name] = runs[deskew], "se3"
                    write_kitti_poses(out / f"poses_{name}_kitti.txt", runs[deskew])
            icp = None if runs is None else runs[True]
        return baselines, icp
