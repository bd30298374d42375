"""The generator stage of `leovr refine`: a frame's input (read, its sweep's motion, deskewed: `refine_sweep`) and
the depth the graph starts from (earlier scans joined, motion stereo, the generator), with the images' motion to the
window's earlier frames (`refine_tracks`). It runs in the lookahead's worker thread while the main thread processes
the previous frame (from its front end on without earlier scans, else from its graph update, once the front end
has placed the earlier scans); its inputs are known when it starts, so the results are those of a sequential
run."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from leovr.data.records import Frame
from leovr.lidar.accumulate import ScanHistory, with_history
from leovr.pipeline.completion import EvalSample
from leovr.pipeline.lookahead import Lookahead
from leovr.pipeline.refine_setup import RunSetup
from leovr.pipeline.refine_sweep import SweepDeskew
from leovr.pipeline.refine_tracks import CornerTracks
from leovr.threads import done_future


@dataclass
class PreparedFrame:
    """What the generator stage hands to the main thread for one frame."""

    sample: EvalSample  # the frame with its cheap input, deskewed; no held-out truth (the run's scoring builds it)
    depth: np.ndarray  # the generator's depth, moved towards the motion-stereo corners when they ran
    log_sigma: np.ndarray
    generator_ms: float  # the stage's time: the generator, with the sweep's motion when it is read
    pairs: dict[int, np.ndarray]  # the images' motion to the window's earlier frames (pair factors)
    corners: np.ndarray | None  # motion-stereo depth at image corners (0 elsewhere), when it ran
    motion: np.ndarray | None  # the camera motion over the sweep the input was deskewed with (None: not deskewed)
    # a causal run's second frame: the first frame's scan deskewed with the first step, KISS-ICP's map to restart from
    first_scan: np.ndarray | None = None


@dataclass
class ConeSteps:
    """Whether a step that needs a LiDAR and is `auto` with a cone one (motion stereo, pair factors, the
    photometric field) runs. Read by both threads; `spinning` is set by the main thread, once, before the
    frames that follow are prepared."""

    has_lidar: bool
    spinning: bool | None = None  # once judged on the first scan with returns

    def known(self, setting: bool | str) -> bool | None:
        """Whether the step runs for every frame from now on, None while the sensor is not judged yet."""
        if not self.has_lidar or setting is False:
            return False
        if setting is True:
            return True
        return None if self.spinning is None else not self.spinning

    def runs(self, setting: bool | str, sample: EvalSample) -> bool:
        """Whether the step runs for this frame: before the sensor is judged, on this frame's own scan."""
        known = self.known(setting)
        if known is not None:
            return known
        kept = sample.kept_points
        if kept is None or len(kept) < 100:
            return False
        from odometry.initial_pose import is_spinning

        return not is_spinning(kept[:, :3])


class PrepareStage:
    """`prepare` a frame: its input, then its generator depth; its sweep's motion (`sweep`) and corner tracks
    (`tracks`) each in a thread of their own."""

    def __init__(self, setup: RunSetup, history: ScanHistory, cone: ConeSteps, frames: Lookahead) -> None:
        self.setup, self.history, self.cone, self.frames = setup, history, cone, frames
        self.sweep = SweepDeskew(setup, frames)
        self.tracks = CornerTracks(setup, frames.threaded)

    def read_sweep_ahead(self, i: int) -> None:
        """Frame i's sweep's images' motion started in the sweep thread (main thread, before i is prepared)."""
        self.sweep.read_ahead(i)

    def close(self) -> None:
        self.sweep.close()
        self.tracks.close()

    def read_input(
        self, i: int, motion: np.ndarray | None
    ) -> tuple[Frame, EvalSample, np.ndarray | None, float, np.ndarray | None]:
        """Frame i as read, its sample (deskewed over the sweep's motion), that motion, the seconds it took, and in
        a causal run's second frame the first scan deskewed (`SweepDeskew.causal_start`). `motion`: the last step
        (deskew on), else None."""
        frame = self.frames.take(i)
        t_sweep = time.perf_counter()
        motion, first_scan = self.sweep.motion(i, frame, motion)
        sweep_s = time.perf_counter() - t_sweep  # counted with the generator: the same thread's per-frame work
        return frame, self.setup.sample(frame, motion), motion, sweep_s, first_scan

    def prepare(self, i: int, motion: np.ndarray | None, earlier: np.ndarray | None) -> PreparedFrame:
        """Frame i's input and generator depth; runs beside the previous frame's front end or graph update.
        `motion`: the last step (deskew on), else None; `earlier`: returns of the frames before, in frame i's
        predicted camera (the generator's input only)."""
        frame, sample, motion, sweep_s, first_scan = self.read_input(i, motion)
        t0 = time.perf_counter() - sweep_s
        depth, log_sigma, pairs, corners = self.generate(i, frame, sample, earlier)
        ms = 1000.0 * (time.perf_counter() - t0)
        return PreparedFrame(sample, depth, log_sigma, ms, pairs, corners, motion, first_scan)

    def generate(
        self, i: int, frame: Frame, sample: EvalSample, earlier: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray], np.ndarray | None]:
        """The generator's depth and log sigma on the sample (with the earlier scans that agree with it),
        moved towards the motion-stereo corners, the pair motions, and the corners."""
        from odometry.corner_correction import EDGE_PX, RANGE_LOG, SPREAD, SUPPORT, corrected_depth

        cfg, K = self.setup.cfg, sample.frame.K
        if earlier is not None:
            earlier = self.history.keep_consistent(earlier, sample.kept_points)
        seen = sample if earlier is None else replace(sample, sparse=with_history(sample.sparse, earlier, K))
        stereo, pair_factors = cfg.motion_stereo.enabled, cfg.graph.pair_factors
        with_stereo, with_pairs = self.cone.runs(stereo, sample), self.cone.runs(pair_factors, sample)
        tracked = done_future((None, {}))  # the corners and pair motions, beside the generator or here
        if with_stereo or with_pairs:
            tracked = self.tracks.submit(i, frame.image, K, sample.sparse, seen.sparse, with_stereo, with_pairs)
            self.tracks.ahead(i, K, self.cone.known(stereo), self.cone.known(pair_factors))
        else:
            self.tracks.forget(i)
        depth, log_sigma = self.setup.generator(seen)
        corners, pairs = tracked.result()
        if corners is not None:  # the generator's depth moved towards the corners around them
            depth = corrected_depth(depth, corners, SPREAD * float(K[0, 0]), SUPPORT, RANGE_LOG, EDGE_PX)
        return depth, log_sigma, pairs, corners
