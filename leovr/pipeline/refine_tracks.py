"""A refine run's corner tracks, for a cone LiDAR: image corners outside its reach triangulated over neighbouring
frames (motion stereo) and the images' motion to the window's earlier frames (pair factors), from one set of tracks
per frame. They need nothing of the frame's generator depth: they run in their own thread beside it, and what of
them needs only the images starts as soon as the frame before has its tracks (`ahead`)."""

from __future__ import annotations

from concurrent.futures import Future
from typing import TYPE_CHECKING

import numpy as np

from leovr.pipeline.refine_input import stereo_image
from leovr.pipeline.refine_setup import RunSetup
from leovr.threads import Worker

if TYPE_CHECKING:
    from odometry.frame_tracks import FrameTracks

Tracked = tuple[np.ndarray | None, dict[int, np.ndarray]]  # motion-stereo corners (or None), pair motions


class CornerTracks:
    """`submit` a frame's tracks; `ahead` queues the next frame's image-only part behind them."""

    def __init__(self, setup: RunSetup, threaded: bool) -> None:
        from odometry.frame_tracks import GrayImages
        from odometry.window_graph import PAIR_OFFSETS

        self.setup, self.stereo = setup, setup.cfg.motion_stereo
        self.following = setup.following
        self.selected = set(setup.indices)
        self.images = GrayImages(
            lambda j: stereo_image(setup.seq, j), keep=2 * max([*self.stereo.offsets, *PAIR_OFFSETS]) + 3
        )
        self.worker = Worker("tracks", threaded)
        self.started: dict[int, Future] = {}  # frame -> its FrameTracks (or None), started ahead

    def submit(
        self, i: int, image: np.ndarray, K: np.ndarray, own: np.ndarray, seen: np.ndarray, stereo: bool, pairs: bool
    ) -> Future:
        """Frame i's corners and pair motions (`tracked`), in the tracks thread or here."""
        args = i, image, K, own, seen, stereo, pairs, self.started.pop(i, None)
        return self.worker.submit(self.tracked, *args)

    def forget(self, i: int) -> None:
        """Frame i's tracks started ahead are not needed (no step that uses them runs for it)."""
        self.started.pop(i, None)

    def neighbours(self, i: int, with_stereo: bool, with_pairs: bool) -> tuple[list[int], list[int]]:
        """Frame i's motion-stereo neighbours and the earlier frames of its pair motions."""
        from odometry.motion_stereo import neighbour_frames
        from odometry.window_graph import PAIR_OFFSETS

        causal = self.setup.cfg.causal
        offsets = self.stereo.causal_offsets if causal else self.stereo.offsets
        neighbours = neighbour_frames(i, self.setup.indices, offsets, causal) if with_stereo else []
        earlier = [i - o for o in PAIR_OFFSETS if i - o in self.selected] if with_pairs else []
        return neighbours, earlier

    def ahead(self, i: int, K: np.ndarray, with_stereo: bool | None, with_pairs: bool | None) -> None:
        """Queue the next frame's tracks (what needs only the images) in the tracks thread behind frame i's,
        when the sensor is known to need them: they then run beside this frame's generator and the main
        thread's front end, off the next frame's path."""
        k = self.following.get(i)
        if not self.worker.threaded or k is None or not (with_stereo or with_pairs):
            return
        self.started[k] = self.worker.submit(
            self.images_tracks, k, K, *self.neighbours(k, bool(with_stereo), bool(with_pairs))
        )

    def images_tracks(self, i: int, K: np.ndarray, neighbours: list[int], earlier: list[int]) -> FrameTracks | None:
        """Frame i's corners tracked into its neighbours with each pair's rotation and direction, or None where its
        image is not read yet: a frame not met as a neighbour before takes its own decoded image (`tracked`),
        as a sequential run does. Runs in the tracks thread, which alone touches `images`."""
        from odometry.frame_tracks import FrameTracks

        if i not in self.images.images:
            return None
        tracks = FrameTracks(i, self.images, K, None, neighbours)
        tracks.track_into([*neighbours, *earlier])
        return tracks

    def tracked(
        self,
        i: int,
        image: np.ndarray,
        K: np.ndarray,
        own: np.ndarray,
        seen: np.ndarray,
        with_stereo: bool,
        with_pairs: bool,
        ahead: Future | None,
    ) -> Tracked:
        """Frame i's motion-stereo corners (a sparse depth map, or None) and its pair motions to the window's
        earlier frames, from one set of corner tracks (`ahead`: started by `ahead`, used when it tracked the same
        neighbours). `own`: the frame's returns (each pair's length); `seen`: with the earlier scans (no corner
        near a return)."""
        from odometry.frame_tracks import FrameTracks, pair_motions
        from odometry.motion_stereo import motion_stereo_depth

        neighbours, earlier = self.neighbours(i, with_stereo, with_pairs)
        tracks = None if ahead is None else ahead.result()
        if tracks is None or tracks.ladder != tuple(neighbours) or not np.array_equal(tracks.K, K):
            if i not in self.images.images:
                self.images.put(i, image)
            tracks = FrameTracks(i, self.images, K, None, neighbours)
        tracks.set_returns(own)
        corners = None
        if with_stereo:
            corners = motion_stereo_depth(i, neighbours, self.images, K, own, seen, tracks)
        pairs = {}
        if with_pairs:  # the images' motion to the window's earlier frames
            pairs = pair_motions(i, earlier, self.images, K, own, tracks)
        return corners, pairs

    def close(self) -> None:
        self.worker.close(cancel=True)
