"""The generator stage of `leovr refine`: a frame's input (read, its sweep's motion, deskewed) and the depth
the graph starts from (earlier scans joined, motion stereo, the generator), with the images' motion to the
window's earlier frames. It runs in the lookahead's worker thread while the main thread processes the
previous frame (from its front end on without earlier scans, else from its graph update, once the front end
has placed the earlier scans); its inputs are known when it starts, so the results are those of a sequential
run."""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from leovr.config import CompleteConfig, RefineConfig
from leovr.data.records import Frame
from leovr.data.sequence import Sequence
from leovr.lidar.accumulate import ScanHistory, with_history
from leovr.pipeline.completion import EvalSample
from leovr.pipeline.lookahead import Lookahead, done_future
from leovr.pipeline.refine_input import frame_sample, stereo_image

if TYPE_CHECKING:
    from odometry.frame_tracks import FrameTracks
    from odometry.sweep_motion import ImagesMotion

Generator = Callable[[EvalSample], tuple[np.ndarray, np.ndarray]]  # sample -> depth, log sigma


@dataclass
class PreparedFrame:
    """What the generator stage hands to the main thread for one frame."""

    sample: EvalSample  # the frame with its cheap input, deskewed; its held-out truth not built yet
    depth: np.ndarray  # the generator's depth, moved towards the motion-stereo corners when they ran
    log_sigma: np.ndarray
    generator_ms: float  # the stage's time: the generator, with the sweep's motion when it is read
    pairs: dict[int, np.ndarray]  # the images' motion to the window's earlier frames (pair factors)
    corners: np.ndarray | None  # motion-stereo depth at image corners (0 elsewhere), when it ran
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
    """`prepare` a frame: its input, then its generator depth. The main thread reads back `start` (the first
    step's motion) and `sweep_of` (a sweep's motion read from the images) once the frame is prepared."""

    def __init__(
        self,
        seq: Sequence,
        cfg: RefineConfig,
        ccfg: CompleteConfig,
        indices: list[int],
        has_lidar: bool,
        frame_dt: float,
        generator: Generator,
        history: ScanHistory,
        cone: ConeSteps,
        frames: Lookahead,
    ) -> None:
        from odometry.frame_tracks import GrayImages
        from odometry.window_graph import PAIR_OFFSETS
        from odometry.sweep_motion import SweepMotion

        self.seq, self.cfg, self.ccfg, self.indices = seq, cfg, ccfg, indices
        self.has_lidar, self.camera_only = has_lidar, cfg.input == "none"
        self.frame_dt, self.generator, self.history, self.cone, self.frames = frame_dt, generator, history, cone, frames
        self.following = dict(zip(indices[:-1], indices[1:]))
        self.selected = set(indices)
        # motion stereo: image corners outside a cone LiDAR's reach, triangulated over neighbouring frames
        self.stereo = cfg.motion_stereo
        self.stereo_images = GrayImages(
            lambda j: stereo_image(seq, j), keep=2 * max([*self.stereo.offsets, *PAIR_OFFSETS]) + 3
        )
        self.sweep_images = SweepMotion()
        # a sweep's images' motion (ORB matching, essential matrix) needs only the two images: it runs in its own
        # thread while the main thread's front end runs and this stage's thread would wait
        self.sweeper = ThreadPoolExecutor(1, thread_name_prefix="leovr-sweep") if frames.threaded else None
        # a frame's corner tracks (motion stereo, pair motions) need nothing of its generator: they run in their own
        # thread beside it; and what of them needs only the images starts there as soon as the frame before has
        # its tracks (`track_ahead`), before the frame's input is read
        self.tracker = ThreadPoolExecutor(1, thread_name_prefix="leovr-tracks") if frames.threaded else None
        self.tracks_ahead: dict[int, Future] = {}  # frame -> its FrameTracks (or None), started ahead
        self.images_ahead: dict[int, Future] = {}  # frame -> its sweep's images' motion, started ahead
        self.sweep_of: dict[int, np.ndarray | None] = {}  # frame -> its sweep's motion (to the next frame)
        self.start: np.ndarray | None = None  # the first step's motion, for the first two sweeps
        self.first: Frame | None = None  # a causal run's first frame, until the second one gives the first step

    def next_frame(self, i: int, frame: Frame) -> Frame | None:
        """Frame i + 1 when it is the next selected one and frame i's scan has point times (its sweep ends
        there), else None; read once: frame i + 1's own preparation then takes it from the lookahead."""
        j = i + 1
        if frame.point_times is None or self.following.get(i) != j:
            return None
        return self.frames.peek(j)

    def read_sweep_ahead(self, i: int) -> None:
        """Start frame i's sweep's images' motion (images i and i + 1, read ahead) in the sweep thread, when
        frame i's scan will be deskewed with it. Called by the main thread before frame i is prepared."""
        cfg = self.cfg
        if (
            self.sweeper is None
            or i in self.images_ahead
            or not (cfg.deskew and self.has_lidar)
            or cfg.causal
            or self.following.get(i) != i + 1
        ):
            return
        self.images_ahead[i] = self.sweeper.submit(
            self._images_motion, i, self.frames.future(i), self.frames.future(i + 1)
        )

    def _images_motion(self, i: int, this: Future, nxt: Future) -> ImagesMotion | None:
        frame = this.result()
        if frame.point_times is None:  # no point times: the scan is not deskewed over its sweep
            return None
        return self.sweep_images(i, frame.image, i + 1, nxt.result().image, frame.K)

    def sweep(self, i: int, frame: Frame, motion: np.ndarray | None) -> np.ndarray | None:
        """The camera motion over frame i's sweep, to deskew it: the last step (`motion`, None before the
        second frame), or the motion read from this image and the next one (not in a causal run)."""
        ahead = self.images_ahead.pop(i, None)
        nxt_frame = None if self.cfg.causal else self.next_frame(i, frame)
        if nxt_frame is None:
            return motion
        from odometry.sweep_motion import sweep_motion

        # not started ahead (the first frame, before any sweep thread work; or no sweep thread): read here
        seen = (
            ahead.result() if ahead is not None else self._images_motion(i, done_future(frame), done_future(nxt_frame))
        )
        return sweep_motion(seen, frame.K, motion)

    def close(self) -> None:
        for pool in (self.sweeper, self.tracker):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)

    def start_motion(self, i: int, frame: Frame) -> np.ndarray | None:
        """The first step's motion from the first two cheap scans as they are (no step is known yet)."""
        nxt_frame = self.next_frame(i, frame)
        if nxt_frame is None:
            return None
        self.start = self._first_step(frame, nxt_frame)
        return self.start

    def _first_step(self, first: Frame, second: Frame) -> np.ndarray | None:
        """The motion between two frames from their cheap scans as they are (KISS-ICP)."""
        from odometry.initial_pose import first_step

        scans = [
            frame_sample(
                self.seq, f.index, self.ccfg, None, self.frame_dt, self.camera_only, truth=False, frame=f
            ).kept_points
            for f in (first, second)
        ]
        return first_step(*scans, first.T_cam_lidar)

    def causal_start(self, frame: Frame) -> tuple[np.ndarray | None, np.ndarray | None]:
        """A causal run's second frame: the first step's motion from the first two scans as they are, and the
        first scan deskewed with it. The first scan went into KISS-ICP's map as it was (its motion unknown then),
        and a skewed scan in the map biases every later registration that matches it: the front end restarts
        KISS-ICP from the deskewed one."""
        first, self.first = self.first, None
        motion = self.start = self._first_step(first, frame)
        if motion is None:
            return None, None
        scan = frame_sample(
            self.seq, first.index, self.ccfg, motion, self.frame_dt, self.camera_only, truth=False, frame=first
        ).kept_points
        return motion, scan

    def read_input(self, i: int, motion: np.ndarray | None) -> tuple[Frame, EvalSample, float, np.ndarray | None]:
        """Frame i as read, its sample (deskewed over the sweep's motion), the seconds the motion took, and in
        a causal run's second frame the first scan deskewed (`causal_start`). `motion`: the last step (deskew
        on), else None."""
        cfg = self.cfg
        frame = self.frames.take(i)
        t_sweep = time.perf_counter()
        first_scan = None
        if cfg.deskew and self.has_lidar and i == self.indices[0] and frame.point_times is not None:
            if cfg.causal:
                self.first = frame
            else:
                motion = self.start_motion(i, frame)
        elif self.first is not None and i == self.following.get(self.first.index):
            start, first_scan = self.causal_start(frame)
            motion = start if start is not None else motion
        given = motion
        # camera only: no scan to deskew (a recording's scan is only scored against), so no sweep motion to read
        motion = self.sweep(i, frame, motion) if cfg.deskew and self.has_lidar else None
        # KISS-ICP's prediction for the next frame: the images' motion only where it overruled the last step
        # (the start and end of turns); elsewhere KISS-ICP keeps its own constant velocity
        self.sweep_of[i] = motion if motion is not given and given is not None else None
        sweep_s = time.perf_counter() - t_sweep  # counted with the generator: the same thread's per-frame work
        # the held-out truth is scoring, not refinement: built in the main thread's scoring step
        sample = frame_sample(self.seq, i, self.ccfg, motion, self.frame_dt, self.camera_only, truth=False, frame=frame)
        return frame, sample, sweep_s, first_scan

    def prepare(self, i: int, motion: np.ndarray | None, earlier: np.ndarray | None) -> PreparedFrame:
        """Frame i's input and generator depth; runs beside the previous frame's front end or graph update.
        `motion`: the last step (deskew on), else None; `earlier`: returns of the frames before, in frame i's
        predicted camera (the generator's input only)."""
        frame, sample, sweep_s, first_scan = self.read_input(i, motion)
        t0 = time.perf_counter() - sweep_s
        depth, log_sigma, pairs, corners = self.generate(i, frame, sample, earlier)
        return PreparedFrame(sample, depth, log_sigma, 1000.0 * (time.perf_counter() - t0), pairs, corners, first_scan)

    def generate(
        self, i: int, frame: Frame, sample: EvalSample, earlier: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray], np.ndarray | None]:
        """The generator's depth and log sigma on the sample (with the earlier scans that agree with it),
        moved towards the motion-stereo corners, the pair motions, and the corners."""
        from odometry.corner_correction import EDGE_PX, RANGE_LOG, SPREAD, SUPPORT, corrected_depth

        cfg, stereo, K = self.cfg, self.stereo, sample.frame.K
        if earlier is not None:
            earlier = self.history.keep_consistent(earlier, sample.kept_points)
        seen = sample if earlier is None else replace(sample, sparse=with_history(sample.sparse, earlier, K))
        with_stereo, with_pairs = self.cone.runs(stereo.enabled, sample), self.cone.runs(cfg.graph.pair_factors, sample)
        tracked = done_future((None, {}))  # the corners and pair motions, beside the generator (`tracker`) or here
        ahead = self.tracks_ahead.pop(i, None)
        if with_stereo or with_pairs:
            args = i, frame.image, K, sample.sparse, seen.sparse, with_stereo, with_pairs, ahead
            tracked = (
                self.tracker.submit(self._tracked, *args)
                if self.tracker is not None
                else done_future(self._tracked(*args))
            )
            self.track_ahead(i, K)
        depth, log_sigma = self.generator(seen)
        corners, pairs = tracked.result()
        if corners is not None:  # the generator's depth moved towards the corners around them
            depth = corrected_depth(depth, corners, SPREAD * float(K[0, 0]), SUPPORT, RANGE_LOG, EDGE_PX)
        return depth, log_sigma, pairs, corners

    def _neighbours(self, i: int, with_stereo: bool, with_pairs: bool) -> tuple[list[int], list[int]]:
        """Frame i's motion-stereo neighbours and the earlier frames of its pair motions."""
        from odometry.motion_stereo import neighbour_frames
        from odometry.window_graph import PAIR_OFFSETS

        cfg, stereo = self.cfg, self.stereo
        offsets = stereo.causal_offsets if cfg.causal else stereo.offsets
        neighbours = neighbour_frames(i, self.indices, offsets, cfg.causal) if with_stereo else []
        earlier = [i - o for o in PAIR_OFFSETS if i - o in self.selected] if with_pairs else []
        return neighbours, earlier

    def track_ahead(self, i: int, K: np.ndarray) -> None:
        """Queue the next frame's tracks (what needs only the images) in the tracks thread behind frame i's,
        when the sensor is known to need them: they then run beside this frame's generator and the main
        thread's front end, off the next frame's path."""
        k = self.following.get(i)
        with_stereo, with_pairs = self.cone.known(self.stereo.enabled), self.cone.known(self.cfg.graph.pair_factors)
        if self.tracker is None or k is None or not (with_stereo or with_pairs):
            return
        self.tracks_ahead[k] = self.tracker.submit(
            self._images_tracks, k, K, *self._neighbours(k, bool(with_stereo), bool(with_pairs))
        )

    def _images_tracks(self, i: int, K: np.ndarray, neighbours: list[int], earlier: list[int]) -> FrameTracks | None:
        """Frame i's corners tracked into its neighbours with each pair's rotation and direction, or None where its
        image is not read yet: a frame not met as a neighbour before takes its own decoded image (`_tracked`),
        as a sequential run does. Runs in the tracks thread, which alone touches `stereo_images`."""
        from odometry.frame_tracks import FrameTracks

        if i not in self.stereo_images.images:
            return None
        tracks = FrameTracks(i, self.stereo_images, K, None, neighbours)
        tracks.track_into([*neighbours, *earlier])
        return tracks

    def _tracked(
        self,
        i: int,
        image: np.ndarray,
        K: np.ndarray,
        own: np.ndarray,
        seen: np.ndarray,
        with_stereo: bool,
        with_pairs: bool,
        ahead: Future | None,
    ) -> tuple[np.ndarray | None, dict[int, np.ndarray]]:
        """Frame i's motion-stereo corners (a sparse depth map, or None) and its pair motions to the window's
        earlier frames, from one set of corner tracks (`ahead`: started by `track_ahead`, used when it tracked
        the same neighbours). `own`: the frame's returns (each pair's length); `seen`: with the earlier scans
        (no corner near a return)."""
        from odometry.frame_tracks import FrameTracks, pair_motions
        from odometry.motion_stereo import motion_stereo_depth

        neighbours, earlier = self._neighbours(i, with_stereo, with_pairs)
        tracks = None if ahead is None else ahead.result()
        if tracks is None or tracks.ladder != tuple(neighbours) or not np.array_equal(tracks.K, K):
            if i not in self.stereo_images.images:
                self.stereo_images.put(i, image)
            tracks = FrameTracks(i, self.stereo_images, K, None, neighbours)
        tracks.set_returns(own)
        corners = None
        if with_stereo:
            corners = motion_stereo_depth(i, neighbours, self.stereo_images, K, own, seen, tracks)
        pairs = {}
        if with_pairs:  # the images' motion to the window's earlier frames
            pairs = pair_motions(i, earlier, self.stereo_images, K, own, tracks)
        return corners, pairs
