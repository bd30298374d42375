"""A view of a sequence with its ground truth removed: frames come without depth, pose or moving-object
mask, so nothing in the self-supervised trainer can read them, whatever the reader found on disk."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from leovr.data.records import Frame
from leovr.data.sequence import Sequence


class BlindSequence(Sequence):
    def __init__(self, base: Sequence) -> None:
        self.base = base
        self.name = base.name
        self.path = base.path
        self.has_lidar = base.has_lidar
        self.has_poses = False
        self.has_depth = False
        self.rate_hz = getattr(base, "rate_hz", 10.0)

    def _num_frames(self) -> int:
        return len(self.base)

    def _load(self, i: int) -> Frame:
        return replace(self.base[i], depth=None, T_world_cam=None, moving_mask=None)

    def timestamps(self) -> np.ndarray:
        return self.base.timestamps()
