"""The camera's motion over each LiDAR sweep in a refine run, to deskew the sweep, from the frame's image and the
next one (odometry.sweep_motion): with a spinning LiDAR their rotation along the last step's arc, with a cone the
last step unless clearly more matches agree with the images' essential matrix; the last step where the images give
no motion; before any step, the first two scans' own motion. The images' motion is read in its own thread,
started as soon as both images are read (`read_ahead`)."""

from __future__ import annotations

from concurrent.futures import Future
from typing import TYPE_CHECKING

import numpy as np

from leovr.data.records import Frame
from leovr.pipeline.lookahead import Lookahead
from leovr.pipeline.refine_setup import RunSetup
from leovr.threads import Worker, done_future

if TYPE_CHECKING:
    from odometry.sweep_motion import ImagesMotion


class SweepDeskew:
    """`motion(i, frame, last_step)`: the motion frame i's sweep is deskewed with. The main thread reads back
    `start` (the first step's motion) and `motion_of` (a sweep's motion read from the images: KISS-ICP's
    prediction) once the frame is prepared."""

    def __init__(self, setup: RunSetup, frames: Lookahead) -> None:
        from odometry.sweep_motion import SweepMotion

        self.setup, self.frames = setup, frames
        self.following = setup.following
        self.images = SweepMotion()
        # a sweep's images' motion (ORB matching, essential matrix) needs only the two images: it runs in its own
        # thread while the main thread's front end runs and the generator stage's thread would wait
        self.worker = Worker("sweep", frames.threaded)
        self.ahead: dict[int, Future] = {}  # frame -> its sweep's images' motion, started ahead
        self.motion_of: dict[int, np.ndarray | None] = {}  # frame -> its sweep's motion (to the next frame)
        self.start: np.ndarray | None = None  # the first step's motion, for the first two sweeps
        self.first: Frame | None = None  # a causal run's first frame, until the second one gives the first step
        # a spinning LiDAR's sweep motion follows the last step's arc; a cone's keeps the last step (decision 0018)
        self._spinning: bool | None = None

    @property
    def runs(self) -> bool:
        return self.setup.cfg.deskew and self.setup.has_lidar

    def motion(self, i: int, frame: Frame, last: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The motion frame i's sweep is deskewed with (None: not deskewed), and in a causal run's second frame the
        first scan deskewed (`causal_start`). `last`: the last step (deskew on), else None."""
        s, first_scan = self.setup, None
        if self.runs and i == s.indices[0] and frame.point_times is not None:
            if s.cfg.causal:
                self.first = frame
            else:
                last = self.start_motion(i, frame)
        elif self.first is not None and i == self.following.get(self.first.index):
            start, first_scan = self.causal_start(frame)
            last = start if start is not None else last
        # camera only: no scan to deskew (a recording's scan is only scored against), so no sweep motion to read
        motion = self.sweep(i, frame, last) if self.runs else None
        # KISS-ICP's prediction for the next frame: the sweep's motion where the images gave one (it follows the
        # start and end of turns, which KISS-ICP's constant velocity misses); elsewhere its own constant velocity
        self.motion_of[i] = motion if motion is not last and last is not None else None
        return motion, first_scan

    def next_frame(self, i: int, frame: Frame) -> Frame | None:
        """Frame i + 1 when it is the next selected one and frame i's scan has point times (its sweep ends
        there), else None; read once: frame i + 1's own preparation then takes it from the lookahead."""
        j = i + 1
        if frame.point_times is None or self.following.get(i) != j:
            return None
        return self.frames.peek(j)

    def read_ahead(self, i: int) -> None:
        """Start frame i's sweep's images' motion (images i and i + 1, read ahead) in the sweep thread, when
        frame i's scan will be deskewed with it. Called by the main thread before frame i is prepared."""
        if (
            not self.worker.threaded
            or i in self.ahead
            or not self.runs
            or self.setup.cfg.causal
            or self.following.get(i) != i + 1
        ):
            return
        self.ahead[i] = self.worker.submit(self._images_motion, i, self.frames.future(i), self.frames.future(i + 1))

    def _images_motion(self, i: int, this: Future, nxt: Future) -> ImagesMotion | None:
        frame = this.result()
        if frame.point_times is None:  # no point times: the scan is not deskewed over its sweep
            return None
        return self.images(i, frame.image, i + 1, nxt.result().image, frame.K)

    def sweep(self, i: int, frame: Frame, motion: np.ndarray | None) -> np.ndarray | None:
        """The camera motion over frame i's sweep from this image and the next one and the last step (`motion`,
        None before the second frame; `sweep_motion`), or that step itself where there is no next image (a causal
        run, the next frame not selected or its scan without point times) or the images give no motion."""
        ahead = self.ahead.pop(i, None)
        nxt_frame = None if self.setup.cfg.causal else self.next_frame(i, frame)
        if nxt_frame is None:
            return motion
        from odometry.sweep_motion import sweep_motion

        # not started ahead (the first frame, before any sweep thread work; or no sweep thread): read here
        seen = (
            ahead.result() if ahead is not None else self._images_motion(i, done_future(frame), done_future(nxt_frame))
        )
        return sweep_motion(seen, frame.K, motion, along_arc=self.spinning(frame))

    def spinning(self, frame: Frame) -> bool:
        """Whether the cheap input comes from a spinning LiDAR: judged once, on the first scan with returns enough
        (until then: not, the cone's sweep motion)."""
        if self._spinning is None:
            self._judge(self.setup.sample(frame, None).kept_points)
        return bool(self._spinning)

    def _judge(self, kept: np.ndarray | None) -> None:
        from odometry.initial_pose import MIN_JUDGED_RETURNS, is_spinning

        if kept is not None and len(kept) >= MIN_JUDGED_RETURNS:
            self._spinning = is_spinning(kept[:, :3])

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

        scans = [self.setup.sample(f, None).kept_points for f in (first, second)]
        if self._spinning is None:
            self._judge(scans[0])
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
        return motion, self.setup.sample(first, motion).kept_points

    def close(self) -> None:
        self.worker.close(cancel=True)
