"""Training samples for the depth generator from simulator sequences (dense ground truth)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from leovr.data import open_sequence
from leovr.depth.network import prior_for
from leovr.errors import DataError
from leovr.lidar.projection import sparse_depth


# density-agnostic input (SLIM): the share of samples that use the sequence's own LiDAR pattern; the others draw a
# uniform share of the ground-truth pixels in this range
NATIVE_PROB = 0.5
DENSITY_RATIO = (0.005, 0.30)


def split_entries(root: Path, split: str) -> list[dict]:
    """Manifest records (scenario, lidar, light, seed, ...) of one split, with `path` made absolute."""
    manifest = root / "manifest.json"
    if not manifest.is_file():
        raise DataError(manifest, "missing dataset manifest (run tools/make_dataset.py)")
    try:
        entries = json.loads(manifest.read_text())["sequences"]
    except (ValueError, KeyError) as exc:
        raise DataError(manifest, f"not a dataset manifest: {exc}") from exc
    out = [{**e, "path": root / e["path"]} for e in entries if e.get("split") == split]
    if not out:
        raise DataError(manifest, f"no sequences in split '{split}'")
    return out


def split_sequences(root: Path, split: str) -> list[Path]:
    """Sequence folders of one split listed in `root/manifest.json`."""
    return [e["path"] for e in split_entries(root, split)]


class DepthSamples(Dataset):
    """(image, sparse depth, dense ground truth) tensors.

    Density-agnostic input (SLIM): with probability `native_prob` the sequence's own LiDAR scan is
    projected; otherwise a uniform fraction r ~ U[ratio_min, ratio_max] of the ground-truth pixels is
    kept. Sampling is seeded by (seed, epoch, index), so runs repeat.
    """

    def __init__(
        self,
        sequences: list[Path],
        ratio: tuple[float, float] = (0.005, 0.30),
        native_prob: float = 0.5,
        max_frames: int | None = None,
        seed: int = 0,
        random_input: bool = True,
        with_prior: bool = False,
        image_edges: bool = True,
    ) -> None:
        self.seqs = [open_sequence(p) for p in sequences]
        self.index = [(k, i) for k, s in enumerate(self.seqs) for i in range(len(s))]
        if max_frames is not None and len(self.index) > max_frames:
            pick = np.random.default_rng(seed).choice(len(self.index), max_frames, replace=False)
            self.index = [self.index[j] for j in sorted(pick)]
        self.ratio, self.native_prob, self.seed = ratio, native_prob, seed
        self.random_input = random_input
        self.with_prior = with_prior  # add the classical prior (residual-mode networks)
        self.image_edges = image_edges  # the prior takes the image's side of depth edges (leovr.depth.prior)
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, j: int) -> dict[str, torch.Tensor]:
        k, i = self.index[j]
        f = self.seqs[k][i]
        if f.depth is None:
            raise DataError(self.seqs[k].path, "training needs dense ground-truth depth")
        gt = f.depth.astype(np.float32)
        rng = np.random.default_rng([self.seed, self.epoch, j])
        if not self.random_input or rng.random() < self.native_prob:
            sparse = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
        else:
            r = rng.uniform(*self.ratio)
            sparse = np.where(rng.random(gt.shape) < r, gt, 0.0).astype(np.float32)
        img = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, axis=2)
        out = {
            "image": torch.from_numpy(img).permute(2, 0, 1).float() / 255.0,
            "sparse": torch.from_numpy(sparse)[None],
            "gt": torch.from_numpy(gt)[None],
        }
        if self.with_prior:
            out["prior"] = prior_for(out["sparse"][None], out["image"][None] if self.image_edges else None)[0]
        return out
