"""How well the photometric masks find movers: each test the trainer can switch on, scored against the
simulator's moving mask as "dropped" vs "moving" (precision and recall).

The masks are built as the trainer builds them (`selfsup.supervision.pair_tests`): frames resampled to
the training focal length, both neighbours of every frame, poses and depth from a graph pass on the
blind sequence. Initialisation stage (no checkpoint): IP-Basic depth and point factors, the depth tests
only near LiDAR returns. Refinement stage (a checkpoint): the generator's depth in the full graph,
trusted everywhere. The auto-mask compares the
photometric error of the neighbour warped with a network's depth against the unwarped neighbour; it
is scored with the network given (the trained one in `leovr bench selfsup`), else with the graph's
depth. Scored pixels: those with ground-truth depth (not sky) whose flow stays inside the neighbour;
the ground truth is read here only, never by the trainer.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from leovr.config import SelfSupConfig
from leovr.data.sequence import Sequence
from leovr.depth.inference import forward_padded
from leovr.geometry import invert_T
from selfsup.blind import BlindSequence
from selfsup.dataset import image_tensor
from selfsup.losses import photometric_error
from selfsup.supervision import (
    PosePass,
    TrainFrame,
    at_training_size,
    graph_depth_at,
    graph_pass,
    keep_mask,
    mover_keep,
    pair_tests,
    RIGID_SUPPORT_PX,
    rigid_support,
    train_frames,
)
from selfsup.warp import warp_image

# full: what the config switches on
VARIANTS = (
    "eq19",
    "rigid",
    "depth",
    "movers",
    "auto",
    "eq19_rigid",
    "eq19_movers",
    "full",
)


@torch.no_grad()
def auto_keep(frame: TrainFrame, neighbour: TrainFrame, T_j_i: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """monodepth2's auto-mask of one pair: True where the neighbour warped with `depth` matches the
    frame better than the unwarped neighbour."""
    img, nb = image_tensor(frame.image)[None], image_tensor(neighbour.image)[None]
    d = torch.from_numpy(depth.astype(np.float32))[None, None]
    warped, _ = warp_image(nb, d, torch.from_numpy(T_j_i).float()[None], torch.from_numpy(frame.K).float()[None])
    return (photometric_error(img, warped) < photometric_error(img, nb))[0, 0].numpy()


def score_masks(
    seq: Sequence,
    cfg: SelfSupConfig,
    work: Path,
    pose_pass: PosePass,
    model: torch.nn.Module | None = None,
    progress: bool = False,
    checkpoint: Path | None = None,
) -> dict:
    """{"variants": {variant: precision, recall, dropped_share}, "moving_share", "pixels",
    "moving_with_depth"} over the sequence ("dropped" vs "moving" on the scored pixels);
    `moving_with_depth` is the share of moving pixels with depth in frame i: an upper bound on what the
    depth-based tests can reach. `work` holds the graph pass (reused when done with the same generator).
    `checkpoint`: the refinement stage's masks, with the graph over this generator."""
    blind = BlindSequence(seq)
    frames = train_frames(blind, cfg)
    graph = graph_pass(blind, cfg, Path(work), checkpoint, len(frames), pose_pass, progress)
    filled = [graph_depth_at(graph, f) for f in frames]
    if checkpoint is None:  # as the trainer's first stage: the classical fill only near returns
        depth = [rigid_support(d, f.sparse, RIGID_SUPPORT_PX) for d, f in zip(filled, frames)]
    else:
        depth = filled
    rigid_cfg = cfg.model_copy(update={"rigid_mask": True, "depth_mask": True})
    eq19_cfg = cfg.model_copy(update={"rigid_mask": False, "depth_mask": False})
    counts = {v: np.zeros(3) for v in VARIANTS}  # true positives, dropped, moving
    scored = moving_total = moving_tested = 0
    for k, f in enumerate(frames):
        gt = seq[f.index]
        size = (f.sparse.shape[1], f.sparse.shape[0])
        moving = at_training_size(gt.moving_mask, f)
        has_depth = cv2.resize(gt.depth, size, interpolation=cv2.INTER_NEAREST) > 0
        net_depth = filled[k]
        if model is not None:
            model.eval()
            with torch.no_grad():
                net_depth = forward_padded(model, image_tensor(f.image)[None], torch.from_numpy(f.sparse)[None, None])[
                    0
                ][0, 0].numpy()
        for j in (k - 1, k + 1):
            if not 0 <= j < len(frames):
                continue
            plain = pair_tests(frames, graph.poses, depth, eq19_cfg, k, j)  # eq. 19 alone: the plain flow
            # with the depth-based tests: the initialised flow
            t = pair_tests(frames, graph.poses, depth, rigid_cfg, k, j)
            auto = auto_keep(f, frames[j], invert_T(graph.poses[j]) @ graph.poses[k], net_depth)
            region = t.inside & has_depth
            both = mover_keep(t, True, True)
            # the tests as the trainer runs them: the rigid test's flow, else the plain flow (and then its own depth
            # test)
            own = (
                t
                if cfg.rigid_mask
                else plain
                if not cfg.depth_mask
                else pair_tests(frames, graph.poses, depth, cfg, k, j)
            )
            full = keep_mask(own, cfg) & (auto if cfg.auto_mask else True)
            dropped = {
                "eq19": ~plain.epipolar,
                "rigid": ~t.rigid,
                "depth": ~t.depth,
                "movers": ~both,
                "auto": ~auto,
                "eq19_rigid": ~(t.epipolar & t.rigid),
                "eq19_movers": ~(t.epipolar & both),
                "full": ~full,
            }
            mv = moving & region
            for v, d in dropped.items():
                d = d & region
                counts[v] += (np.sum(d & mv), np.sum(d), np.sum(mv))
            scored += int(region.sum())
            moving_total += int(mv.sum())
            moving_tested += int((mv & (depth[k] > 0)).sum())
    variants = {
        v: {
            "precision": float(tp / max(dr, 1)),
            "recall": float(tp / max(mv, 1)),
            "dropped_share": float(dr / max(scored, 1)),
        }
        for v, (tp, dr, mv) in counts.items()
    }
    # the depth-based tests' reach
    return {
        "variants": variants,
        "moving_share": moving_total / max(scored, 1),
        "pixels": scored,
        "moving_with_depth": moving_tested / max(moving_total, 1),
    }
