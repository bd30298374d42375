"""What a refine run fixes before its first frame: the sequence and settings, the frames it refines, the sensor it
reads, the depth source; the front end and the window graph it starts with; the run folder's identity (`run.json`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from leovr.config import CompleteConfig, RefineConfig
from leovr.data.records import Frame
from leovr.data.run_info import run_identity, start_run
from leovr.data.sequence import Sequence
from leovr.pipeline.completion import EvalSample, frame_indices, generator_checkpoint, generator_method
from leovr.pipeline.refine_input import (
    camera_only_config,
    classical_source,
    completion_config,
    frame_sample,
    road_height,
)

if TYPE_CHECKING:
    from odometry.frontend import FrontEnd
    from odometry.window_graph import WindowGraph

Generator = Callable[[EvalSample], tuple[np.ndarray, np.ndarray]]  # sample -> depth, log sigma


@dataclass(frozen=True)
class RunSetup:
    """A refine run's fixed inputs, read by every stage."""

    seq: Sequence
    cfg: RefineConfig
    ccfg: CompleteConfig  # the cheap input's settings (refine_input.completion_config)
    out: Path
    indices: list[int]  # the selected frames, in order
    has_lidar: bool  # a LiDAR input (not camera only)
    frame_dt: float  # the median time between frames (s)
    generator: Generator  # the depth the graph starts from: the network, or IP-Basic
    first: Frame  # the first selected frame (camera, image size, LiDAR mounting)
    progress: bool  # progress bars

    @classmethod
    def of(cls, seq: Sequence, cfg: RefineConfig, out: Path, progress: bool) -> "RunSetup":
        ccfg = completion_config(cfg)
        indices = frame_indices(len(seq), ccfg)
        stamps = seq.timestamps()
        return cls(
            seq,
            cfg,
            ccfg,
            Path(out),
            indices,
            seq.has_lidar and cfg.input != "none",
            float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.1,
            generator_method(ccfg) if cfg.depth_source == "generator" else classical_source,
            seq[indices[0]],
            progress,
        )

    @cached_property
    def following(self) -> dict[int, int]:
        """Each selected frame's next selected frame."""
        return dict(zip(self.indices[:-1], self.indices[1:]))

    def sample(self, frame: Frame, motion: np.ndarray | None) -> EvalSample:
        """The frame's cheap input, its scan deskewed with `motion` (None: as it is); the held-out truth is
        scoring's, not built here."""
        camera_only = self.cfg.input == "none"
        return frame_sample(
            self.seq, frame.index, self.ccfg, motion, self.frame_dt, camera_only, truth=False, frame=frame
        )

    def odometry(self) -> tuple[FrontEnd, WindowGraph]:
        """The front end and the window graph, with the camera-only profile's settings without a LiDAR."""
        from odometry.frontend import FrontEnd
        from odometry.window_graph import WindowGraph

        cfg, first, has_lidar = self.cfg, self.first, self.has_lidar
        ocfg = cfg if has_lidar else camera_only_config(cfg)
        front = FrontEnd(
            ocfg,
            first.K,
            first.shape,
            first.T_cam_lidar,
            use_lidar=has_lidar,
            camera_height=None if has_lidar else road_height(self.seq, cfg),
        )
        # the loop pass weighs each step by the window's covariance of it; camera only they come out alike (the road
        # plane sets every step's length), so the marginals that would double the graph's time are left out
        graph = WindowGraph(
            ocfg,
            first.K,
            first.shape,
            rng=np.random.default_rng(cfg.seed),
            condition_leaving=has_lidar,
            step_covariances=cfg.loop.enabled and has_lidar,
        )
        return front, graph

    def start(self, resume: bool, camera_height: float | None) -> None:
        """The run folder's `run.json`: what ran on what (a resume checks it against the folder's)."""
        cfg, seq = self.cfg, self.seq
        checkpoint = generator_checkpoint(self.ccfg) if cfg.depth_source == "generator" else None
        start_run(
            self.out,
            "refine",
            run_identity("refine", cfg.model_dump(), [seq.path], checkpoint),
            resume,
            input=cfg.input if self.has_lidar else "none",
            sequence=str(Path(seq.path).resolve()),
            frame_numbers=seq.frame_numbers(),
            **({} if self.has_lidar else {"camera_height_m": camera_height}),
        )
