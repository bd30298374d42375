"""Training samples for the self-supervised trainer: frame i with its previous and next frames, the
relative poses, the flow masks and the graph's targets. Frames at the ends of a sequence (one
neighbour only) are left out so every sample has both photometric terms."""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from leovr.geometry import invert_T
from selfsup.supervision import Supervision, TrainFrame


def image_tensor(x: np.ndarray) -> torch.Tensor:
    """H x W x 3 uint8 -> 3 x H x W float in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1).float() / 255.0


def _plane(x: np.ndarray | None, like: np.ndarray, fill: float = 0.0) -> torch.Tensor:
    if x is None:
        return torch.full((1, *like.shape), fill, dtype=torch.float32)
    return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None]


class SelfSupSamples(Dataset):
    """`frames[k]` and `supervision[k]` describe sequence k; `set_supervision` swaps in a new graph pass."""

    def __init__(self, frames: list[list[TrainFrame]], supervision: list[Supervision]) -> None:
        shapes = {f.sparse.shape for seq in frames for f in seq}
        if len(shapes) != 1:
            raise ValueError(f"training frames must share one size after resampling, got {sorted(shapes)}")
        self.frames = frames
        self.index = [(k, i) for k, seq in enumerate(frames) for i in range(1, len(seq) - 1)]
        self.set_supervision(supervision)

    def set_supervision(self, supervision: list[Supervision]) -> None:
        self.sup = supervision

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, j: int) -> dict[str, torch.Tensor]:
        k, i = self.index[j]
        fr, sup = self.frames[k], self.sup[k]
        f = fr[i]
        split = f.masked[int(torch.randint(len(f.masked), (1,)))] if f.masked else (f.sparse * 0, f.sparse * 0)
        return {
            "image": image_tensor(f.image),
            "prev": image_tensor(fr[i - 1].image),
            "next": image_tensor(fr[i + 1].image),
            "sparse": _plane(f.sparse, f.sparse),
            "K": torch.from_numpy(f.K).float(),
            "T_prev": torch.from_numpy(invert_T(sup.poses[i - 1]) @ sup.poses[i]).float(),
            "T_next": torch.from_numpy(invert_T(sup.poses[i + 1]) @ sup.poses[i]).float(),
            "mask_prev": _plane(sup.mask_prev[i], f.sparse, 1.0),
            "mask_next": _plane(sup.mask_next[i], f.sparse, 1.0),
            "feature_depth": _plane(sup.feature_depth[i], f.sparse),
            "refined": _plane(sup.refined[i], f.sparse),
            "use_refined": torch.tensor(bool(sup.use_refined[i])),
            "masked_sparse": _plane(split[0], f.sparse),
            "masked_target": _plane(split[1], f.sparse),
            "anchor": _plane(f.anchor, f.sparse),
            "key": torch.tensor([k, i]),
        }
