"""`leovr adapt`'s training frames: each frame's cheap input split into a thinner input and hidden returns
(selfsup.masked_lidar), resampled to the network's focal length with the priors built as at inference."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from tqdm import tqdm

from leovr.config import AdaptConfig
from leovr.data.sequence import Sequence
from leovr.depth.inference import _pad32, network_priors, rescale_sparse
from leovr.errors import DataError
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor
from leovr.lidar.projection import sparse_depth
from selfsup.masked_lidar import masked_split


@dataclass
class SplitSample:
    """One masked split of one frame, ready for the network: small input and full-resolution targets."""

    sparse: torch.Tensor  # 1 x hs x ws, metres (the thinner input at the network's focal length)
    prior: torch.Tensor  # 1 x hs x ws, its prior
    grid: torch.Tensor  # N x 2, hidden returns' full-resolution pixel centres in [-1, 1] (x, y)
    target: torch.Tensor  # N, metres
    prior_at: torch.Tensor  # N, full-resolution prior at the hidden returns
    measured_at: torch.Tensor  # N, kept input depth at those pixels (0 = none)


@dataclass
class AdaptFrame:
    image: torch.Tensor  # 3 x hs x ws
    splits: list[SplitSample]
    sparse: torch.Tensor  # 1 x hs x ws, the whole input (what inference sees)
    prior: torch.Tensor  # 1 x hs x ws, its prior
    teacher: torch.Tensor | None = None  # 1 x hs x ws, the starting network's log depth on the whole input


def frame_splits(
    image: np.ndarray,
    points: np.ndarray,
    K: np.ndarray,
    T_cam_lidar: np.ndarray,
    shape: tuple[int, int],
    scale: float,
    n: int,
    rng: np.random.Generator,
    span_rings: bool = False,
) -> AdaptFrame:
    """`n` masked splits of one frame's input scan (`points`) with the resampled image."""
    h, w = shape
    hs, ws = (max(8, int(round(h * scale))), max(8, int(round(w * scale)))) if scale != 1.0 else shape
    small = image if (hs, ws) == shape else cv2.resize(image, (ws, hs), interpolation=cv2.INTER_AREA)
    img = torch.from_numpy(np.ascontiguousarray(small)).permute(2, 0, 1).float() / 255.0
    whole = sparse_depth(points, K, T_cam_lidar, shape).astype(np.float32)
    image_full = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float() / 255.0

    def priors(sparse: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """The network's input map, its prior and the full-resolution prior, built as at inference
        (leovr.depth.inference.network_priors; the side of depth edges taken from the image)."""
        same = (hs, ws) == shape
        small = sparse if same else rescale_sparse(sparse, scale, (hs, ws))
        small_prior, full_prior = network_priors(
            torch.from_numpy(sparse)[None, None], image_full, small, 1.0 if same else scale
        )
        return torch.from_numpy(small)[None], small_prior[0], full_prior[0, 0].numpy()

    whole_small, whole_prior, _ = priors(whole)
    splits = []
    for _ in range(n):
        sp = masked_split(points, K, T_cam_lidar, shape, rng, span_rings=span_rings, every=whole)
        rows, cols = np.nonzero(sp.target > 0)
        s, small_prior, full_prior = priors(sp.sparse.astype(np.float32))
        grid = np.stack([(cols + 0.5) / w * 2 - 1, (rows + 0.5) / h * 2 - 1], 1).astype(np.float32)
        splits.append(
            SplitSample(
                s,
                small_prior,
                torch.from_numpy(grid),
                torch.from_numpy(sp.target[rows, cols]),
                torch.from_numpy(np.ascontiguousarray(full_prior[rows, cols])),
                torch.from_numpy(sp.sparse[rows, cols]),
            )
        )
    return AdaptFrame(img, splits, whole_small, whole_prior)


def input_frames(seqs: list[Sequence], cfg: AdaptConfig, progress: bool = True) -> list[AdaptFrame]:
    """Every selected frame of every sequence with its masked splits (seeded by sequence and frame)."""
    sensor = parse_input(cfg.input)
    out = []
    jobs = [(k, seq, i) for k, seq in enumerate(seqs) for i in range(len(seq))[cfg.start : cfg.end]]
    if not jobs:
        raise DataError("frames", f"no frame selected (start={cfg.start}, end={cfg.end})")
    for k, seq, i in tqdm(jobs, desc="adapt: prepare frames", unit="frame", disable=not progress):
        f = seq[i]
        if f.points is None or not len(f.points):
            raise DataError(seq.path, f"frame {f.index} has no LiDAR scan; adaptation needs the LiDAR input")
        kept = simulate_cheap_sensor(f.points, sensor, f.index, cfg.seed, f.K, f.T_cam_lidar, f.shape).kept
        image = f.image if f.image.ndim == 3 else np.repeat(f.image[..., None], 3, axis=2)
        scale = 1.0 if cfg.generator_focal_px is None else cfg.generator_focal_px / float(f.K[0, 0])
        scale = 1.0 if abs(scale - 1.0) < 0.05 else scale
        rng = np.random.default_rng([cfg.seed, k, f.index])
        out.append(
            frame_splits(image, kept, f.K, f.T_cam_lidar, f.shape, scale, cfg.splits_per_frame, rng, cfg.span_rings)
        )
    return out


def network_feeds(frames: list[AdaptFrame]) -> list[dict[str, np.ndarray]]:
    """Each frame's whole input as the network sees it at inference (padded to 32): int8 calibration."""
    feeds = []
    for fr in frames:
        image, sparse, prior = _pad32(fr.image[None], fr.sparse[None], fr.prior[None])
        feeds.append({"image": image.numpy(), "sparse": sparse.numpy(), "prior": prior.numpy()})
    return feeds
