"""The self-supervised objective (LeoVR eqs. 16-17 and 20-22): masked photometric error against the
warped neighbours, feature-point depth, refined-depth guidance and edge-aware second-order
smoothness. All terms are means over their valid pixels, so batch and image size do not rescale them."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


ALPHA = 0.8  # eq. 17: alpha/2 (1 - SSIM) + (1 - alpha) L1


def ssim_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(1 - SSIM) / 2 per pixel over 3 x 3 windows (reflection padded), in [0, 1]."""
    c1, c2 = 0.01**2, 0.03**2
    a, b = F.pad(a, (1, 1, 1, 1), mode="reflect"), F.pad(b, (1, 1, 1, 1), mode="reflect")
    mu_a, mu_b = F.avg_pool2d(a, 3, 1), F.avg_pool2d(b, 3, 1)
    var_a = F.avg_pool2d(a * a, 3, 1) - mu_a**2
    var_b = F.avg_pool2d(b * b, 3, 1) - mu_b**2
    cov = F.avg_pool2d(a * b, 3, 1) - mu_a * mu_b
    ssim = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return ((1 - ssim) / 2).clamp(0, 1)


def photometric_error(a: torch.Tensor, b: torch.Tensor, alpha: float = ALPHA) -> torch.Tensor:
    """Eq. 17: alpha/2 (1 - SSIM) + (1 - alpha) |a - b|_1, averaged over channels: B x 1 x H x W."""
    return (alpha * ssim_distance(a, b) + (1 - alpha) * (a - b).abs()).mean(1, keepdim=True)


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    m = mask.to(x.dtype)
    return (x * m).sum() / m.sum().clamp(min=1.0)


def photometric_loss(
    errors: list[torch.Tensor], masks: list[torch.Tensor], per_pixel_min: bool = False
) -> torch.Tensor:
    """Eq. 16: the masked photometric errors (`photometric_error` against each warped neighbour)
    summed over the neighbours; with `per_pixel_min` (monodepth2), the per-pixel minimum over the
    neighbours that keep the pixel, times their number so the weights of eq. 22 keep their balance."""
    if not per_pixel_min:
        return sum(masked_mean(e, m) for e, m in zip(errors, masks))
    stacked = torch.stack([torch.where(m, e, torch.full_like(e, float("inf"))) for e, m in zip(errors, masks)])
    best = stacked.min(0).values
    valid = torch.isfinite(best)
    return len(errors) * masked_mean(torch.where(valid, best, torch.zeros_like(best)), valid)


def depth_target_error(depth: torch.Tensor, target: torch.Tensor, kind: str = "log_l1") -> torch.Tensor:
    """Per-pixel error against a graph depth target: 'l2' is the paper's squared error in metres
    (eqs. 20-21); 'log_l1' is |log D - log D*|, a relative error, so the few far targets (tens of
    metres, metres off) do not outweigh the many near ones and the photometric term."""
    if kind == "l2":
        return (depth - target) ** 2
    if kind == "log_l1":
        return (depth.clamp(min=1e-3).log() - target.clamp(min=1e-3).log()).abs()
    raise ValueError(f"target loss must be 'log_l1' or 'l2', not '{kind}'")


def feature_point_loss(depth: torch.Tensor, feature_depth: torch.Tensor, kind: str = "log_l1") -> torch.Tensor:
    """Eq. 20: error at the pixels where the graph's landmarks project (feature_depth > 0)."""
    return masked_mean(depth_target_error(depth, feature_depth, kind), feature_depth > 0)


def sparse_depth_loss(depth: torch.Tensor, sparse: torch.Tensor, kind: str = "log_l1") -> torch.Tensor:
    """Sparse depth reconstruction (unsupervised depth completion, e.g. all-day-depth-completion Sec. II):
    error to the LiDAR input itself at its returns (sparse > 0). It also holds the pixels that no
    photometric mask keeps, such as a mover's, where the LiDAR sees them."""
    return masked_mean(depth_target_error(depth, sparse, kind), sparse > 0)


def refined_depth_loss(
    depth: torch.Tensor, refined: torch.Tensor, use: torch.Tensor, kind: str = "log_l1"
) -> torch.Tensor:
    """Eq. 21: error to the graph's refined depth, only on frames whose refined depth agreed
    with the landmarks (`use`, B bools)."""
    return masked_mean(depth_target_error(depth, refined, kind), (refined > 0) & use.view(-1, 1, 1, 1))


def second_order_smoothness(depth: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Edge-aware L1 of the second derivatives of mean-normalised inverse depth, damped where the image
    has strong gradients (object boundaries may bend)."""
    disp = 1.0 / depth.clamp(min=1e-3)
    disp = disp / disp.mean(dim=(2, 3), keepdim=True)
    dxx = (disp[..., :, 2:] - 2 * disp[..., :, 1:-1] + disp[..., :, :-2]).abs()
    dyy = (disp[..., 2:, :] - 2 * disp[..., 1:-1, :] + disp[..., :-2, :]).abs()
    gx = (image[..., :, 2:] - image[..., :, :-2]).abs().mean(1, keepdim=True) / 2
    gy = (image[..., 2:, :] - image[..., :-2, :]).abs().mean(1, keepdim=True) / 2
    return (dxx * torch.exp(-gx)).mean() + (dyy * torch.exp(-gy)).mean()


@dataclass
class LossWeights:
    """Eq. 22 weights (LeoVR Sec. V-A): L = L_p + lambda_f L_f + lambda_r L_r + lambda_s L_s."""

    photometric: float = 1.0
    feature: float = 0.4
    refined: float = 0.1
    smooth: float = 0.2


def masked_lidar_loss(depth: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean |log D - log z| at the returns hidden from the network's input (target > 0): the masked-LiDAR task
    (selfsup.masked_lidar), metric supervision from the user's own LiDAR where the input has no return."""
    return masked_mean(depth_target_error(depth, target, "log_l1"), target > 0)


def anchor_loss(depth: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    """Mean |log D - log D0| over the pixels where the starting network gave a depth (D0 > 0): fine-tuning's
    anchor to the checkpoint it starts from."""
    return masked_mean(depth_target_error(depth, start, "log_l1"), start > 0)
