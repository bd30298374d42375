"""`leovr adapt`'s loss at the hidden returns: L1 (or log L1) on depth, the uncertainty head's Gaussian NLL on
detached depth (all-day eq. 2), an edge-aware smoothness, and an anchor to the starting network's output on
the whole input; batches and each process's share of them."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from leovr.config import AdaptConfig
from leovr.depth.inference import _pad32
from leovr.depth.layers import gaussian_nll
from leovr.depth.network import DepthGenerator
from leovr.depth.train import edge_aware_smoothness
from selfsup.adapt_data import AdaptFrame, SplitSample


def forward_parts(model: DepthGenerator, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor) -> dict:
    hs, ws = sparse.shape[-2:]
    img_p, sp_p, prior_p = _pad32(image, sparse, prior)
    return {k: v[..., :hs, :ws] for k, v in model.parts(img_p, sp_p, prior_p).items()}


def _log(depth: torch.Tensor) -> torch.Tensor:
    return torch.log(depth.clamp(min=1e-3))


def whole_log_depth(model: DepthGenerator, frames: list[AdaptFrame]) -> torch.Tensor:
    """B x 1 x hs x ws log depth of the frames' whole input (what inference sees)."""
    image = torch.stack([fr.image for fr in frames])
    sparse = torch.stack([fr.sparse for fr in frames])
    prior = torch.stack([fr.prior for fr in frames])
    return _log(model.combine(forward_parts(model, image, sparse, prior), prior, sparse))


def anchor_loss(model: DepthGenerator, frames: list[AdaptFrame]) -> torch.Tensor:
    """Mean |log depth - the starting network's log depth| on the frames' whole input: the masked
    task may teach what the thinner input needs, but not move the inference output without a cost."""
    return (whole_log_depth(model, frames) - torch.stack([fr.teacher for fr in frames])).abs().mean()


@torch.no_grad()
def set_teachers(model: DepthGenerator, frames: list[AdaptFrame]) -> None:
    """The starting network's log depth on each frame's whole input (AdaptFrame.teacher)."""
    model.eval()
    for fr in frames:
        fr.teacher = whole_log_depth(model, [fr])[0]


def at_hidden(
    model: DepthGenerator, parts: dict[str, torch.Tensor], b: int, s: SplitSample
) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """Batch item b's network outputs (1 x 1 x 1 x N each) and final depth (N) at split s's hidden returns."""
    at = {
        k: F.grid_sample(v[b : b + 1], s.grid[None, None], mode="bilinear", align_corners=False)
        for k, v in parts.items()
    }
    return at, model.combine(at, s.prior_at.view(1, 1, 1, -1), s.measured_at.view(1, 1, 1, -1)).view(-1)


def batch_loss(
    model: DepthGenerator,
    batch: list[tuple[AdaptFrame, SplitSample]],
    weight_smooth: float,
    weight_nll: float,
    weight_anchor: float = 0.0,
    log_loss: bool = False,
) -> tuple[torch.Tensor, float, int]:
    """Mean loss of a batch of (frame, split) of one size; also the summed absolute error (metres)
    at the hidden returns and their count."""
    image = torch.stack([fr.image for fr, _ in batch])
    sparse = torch.stack([s.sparse for _, s in batch])
    prior = torch.stack([s.prior for _, s in batch])
    parts = forward_parts(model, image, sparse, prior)
    losses, err_sum, count = [], 0.0, 0
    for b, (_, s) in enumerate(batch):
        if not len(s.target):
            continue
        at, depth = at_hidden(model, parts, b, s)
        err = (depth - s.target).abs()
        loss = (_log(depth) - torch.log(s.target)).abs().mean() if log_loss else err.mean()
        if weight_nll > 0:
            sigma = at["log_sigma"].view(-1)
            loss = loss + weight_nll * gaussian_nll(depth.detach(), sigma, s.target, torch.ones_like(sigma))
        losses.append(loss)
        err_sum, count = err_sum + float(err.detach().sum()), count + len(err)
    total = torch.stack(losses).mean() if losses else sum(v.sum() for v in parts.values()) * 0.0
    if weight_smooth > 0:
        small = model.combine(parts, prior, sparse)
        total = total + weight_smooth * edge_aware_smoothness(small, image)
    if weight_anchor > 0:
        total = total + weight_anchor * anchor_loss(model, [fr for fr, _ in batch])
    return total, err_sum, count


def batches(items: list[tuple[AdaptFrame, SplitSample]], size: int) -> list[list[tuple[AdaptFrame, SplitSample]]]:
    """Consecutive groups of at most `size` items; a group never mixes image sizes."""
    out: list[list] = []
    for it in items:
        if out and len(out[-1]) < size and out[-1][0][0].image.shape == it[0].image.shape:
            out[-1].append(it)
        else:
            out.append([it])
    return out


def share(batch: list, rank: int, world: int) -> tuple[list, float]:
    """This process's part of a batch and its loss weight. DistributedDataParallel averages the
    gradients over the processes, so weighting each part's mean loss by its share of the batch times
    the number of processes gives the gradient of the whole batch's mean: every process takes the same
    steps as one process would. A process left without an item runs the first one at weight 0 (it
    must still join each step's gradient exchange)."""
    part = batch[rank::world]
    if not part:
        return batch[:1], 0.0
    return part, len(part) / len(batch) * world


class StepLoss(torch.nn.Module):
    """`batch_loss` as a module, so that DistributedDataParallel wraps the whole forward of a step
    (the masked task and, with the anchor, a second pass on the whole input)."""

    def __init__(self, model: DepthGenerator, cfg: AdaptConfig) -> None:
        super().__init__()
        self.model, self.cfg = model, cfg

    def forward(self, batch: list[tuple[AdaptFrame, SplitSample]]) -> tuple[torch.Tensor, float, int]:
        c = self.cfg
        return batch_loss(self.model, batch, c.weight_smooth, c.weight_nll, c.weight_anchor, c.depth_loss == "log_l1")
