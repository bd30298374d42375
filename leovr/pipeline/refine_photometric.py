"""The photometric step of a refine run: where no LiDAR return lies, a leaving frame's refined depth moved to what
its neighbours' images agree with (odometry.photo_field), with the poses the neighbours have when it leaves."""

from __future__ import annotations

from typing import Callable

import numpy as np

from leovr.config import RefineConfig
from leovr.data.sequence import Sequence
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample
from leovr.pipeline.refine_input import stereo_image


class PhotometricStep:
    """The images and free nodes of the frames it runs on, kept from their turn in the front end until they
    leave the window."""

    def __init__(self, seq: Sequence, cfg: RefineConfig, indices: list[int], K: np.ndarray) -> None:
        from odometry.frame_tracks import GrayImages

        self.cfg, self.indices, self.K = cfg, indices, K
        self.position = {j: n for n, j in enumerate(indices)}
        self.images = GrayImages(
            lambda j: stereo_image(seq, j), keep=cfg.window + 2 * max(cfg.photometric.offsets, default=0) + 3
        )
        self.free: dict[int, np.ndarray] = {}  # frame -> its grid's nodes without a return

    def keep(self, i: int, sample: EvalSample) -> None:
        """Frame i's image and the nodes its returns leave free, for when it leaves the window."""
        from odometry.photo_field import free_nodes

        self.images.put(i, sample.frame.image)
        self.free[i] = free_nodes(sample.sparse)

    def __contains__(self, i: int) -> bool:
        return i in self.free

    def correct(
        self, i: int, T_i: np.ndarray, depth: np.ndarray, poses_of: Callable[[list[int]], dict[int, np.ndarray]]
    ) -> np.ndarray:
        """Frame i's refined depth after the plane sweep against the selected frames `photometric.offsets` before
        and after it, at the poses `poses_of` gives them now (final before i, the window's after it)."""
        from odometry.photo_field import photometric_correction, photometric_offsets

        cfg, indices, at = self.cfg, self.indices, self.position[i]
        free = self.free.pop(i)
        offsets = [-o for o in cfg.photometric.offsets] + ([] if cfg.causal else cfg.photometric.offsets)
        near = [indices[at + o] for o in offsets if 0 <= at + o < len(indices)]
        poses = poses_of(near)
        gray = self.images[i]
        pairs = [(self.images[j], invert_T(poses[j]) @ T_i) for j in near if j in poses]
        pairs = [(im, T) for im, T in pairs if im is not None and im.shape == depth.shape]
        if gray is None or not pairs:
            return depth
        return photometric_correction(depth, photometric_offsets(depth, gray, pairs, self.K, free))
