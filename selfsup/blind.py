"""A view of a sequence with its ground truth removed: frames come without depth, pose or moving-object
mask, so nothing in the self-supervised trainer can read them, whatever the reader found on disk."""

from __future__ import annotations

from dataclasses import replace

from leovr.data.records import Frame
from leovr.data.sequence import Sequence, SequenceView


class BlindSequence(SequenceView):
    def __init__(self, base: Sequence) -> None:
        super().__init__(base, list(range(len(base))))
        self.has_poses = self.has_depth = False

    def _load(self, i: int) -> Frame:
        return replace(super()._load(i), depth=None, T_world_cam=None, moving_mask=None)
