"""Network building blocks: ResNet basic block, partial convolution (SLIM), inter-sensor
cross-attention (LeoVR eqs. 5-6) and the uncertainty-driven residual combination (all-day eqs. 3-4)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv_bn_relu(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet-34 basic block: two 3x3 convs with BatchNorm, identity (or 1x1 projection) shortcut."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.short = None
        if stride != 1 or cin != cout:
            self.short = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.short is None else self.short(x)), inplace=True)


def resnet_stage(cin: int, cout: int, blocks: int, stride: int = 2) -> nn.Sequential:
    return nn.Sequential(BasicBlock(cin, cout, stride), *[BasicBlock(cout, cout) for _ in range(blocks - 1)])


class PartialConv2d(nn.Conv2d):
    """Mask-aware convolution (Liu et al. 2018, used by SLIM's sparse encoder).

    Only valid inputs contribute; the sum is rescaled by (window size / valid count) so sparse and dense
    inputs give outputs of the same magnitude; the output mask is 1 wherever the window saw any valid
    input. `forward(x, mask)` returns (features, mask).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.register_buffer("_ones", torch.ones(1, 1, *self.kernel_size), persistent=False)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # type: ignore[override]
        with torch.no_grad():
            count = F.conv2d(mask, self._ones, stride=self.stride, padding=self.padding, dilation=self.dilation)
            new_mask = (count > 0).to(x.dtype)
            ratio = self._ones.numel() / count.clamp(min=1.0) * new_mask
        raw = F.conv2d(x * mask, self.weight, None, self.stride, self.padding, self.dilation, self.groups)
        out = raw * ratio
        if self.bias is not None:
            out = out + self.bias.view(1, -1, 1, 1) * new_mask
        return out, new_mask


class PartialStage(nn.Module):
    """A downsampling stage of the sparse encoder: partial conv (stride 2) + BN + ReLU, then a partial conv."""

    def __init__(self, cin: int, cout: int, stride: int = 2) -> None:
        super().__init__()
        self.pc1 = PartialConv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.pc2 = PartialConv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x, mask = self.pc1(x, mask)
        x = F.relu(self.bn1(x), inplace=True)
        x, mask = self.pc2(x, mask)
        return F.relu(self.bn2(x), inplace=True), mask


class CrossAttention(nn.Module):
    """Inter-sensor cross-attention (LeoVR eqs. 5-6).

    a_I = softmax((W_theta z_I)^T (W_phi z_L)) attends from image positions to LiDAR features;
    a_L = softmax((W_phi z_L)^T (W_delta z_I)) from LiDAR positions to image features; each map weights
    the other modality's features and the two results are concatenated: a_D = (a_I z_L) (+) (a_L z_I).
    """

    def __init__(self, channels: int, dim: int = 64) -> None:
        super().__init__()
        self.theta = nn.Conv2d(channels, dim, 1)
        self.phi = nn.Conv2d(channels, dim, 1)
        self.delta = nn.Conv2d(channels, dim, 1)
        self.scale = dim**-0.5

    def forward(self, z_img: torch.Tensor, z_lidar: torch.Tensor) -> torch.Tensor:
        b, c, h, w = z_img.shape
        q_i = self.theta(z_img).flatten(2).transpose(1, 2)  # B x N x d
        k_l = self.phi(z_lidar).flatten(2)  # B x d x N
        k_i = self.delta(z_img).flatten(2)
        a_img = torch.softmax(q_i @ k_l * self.scale, dim=-1)  # B x N x N
        a_lidar = torch.softmax(k_l.transpose(1, 2) @ k_i * self.scale, dim=-1)
        from_lidar = (a_img @ z_lidar.flatten(2).transpose(1, 2)).transpose(1, 2).reshape(b, c, h, w)
        from_img = (a_lidar @ z_img.flatten(2).transpose(1, 2)).transpose(1, 2).reshape(b, c, h, w)
        return torch.cat([from_lidar, from_img], dim=1)


def uncertainty_weight(log_sigma: torch.Tensor, alpha: float = 0.8, beta: float = 0.0) -> torch.Tensor:
    """lambda(sigma) = 1 / (1 + exp(alpha (sigma - beta))) (all-day eq. 3)."""
    return torch.sigmoid(-alpha * (log_sigma - beta))


def uncertainty_residual(
    prior: torch.Tensor, log_sigma: torch.Tensor, residual: torch.Tensor, alpha: float = 0.8, beta: float = 0.0
) -> torch.Tensor:
    """d = lambda(sigma) z_hat + (1 - lambda(sigma)) d_hat (all-day eq. 4)."""
    lam = uncertainty_weight(log_sigma, alpha, beta)
    return lam * prior + (1.0 - lam) * residual


def gaussian_nll(
    pred: torch.Tensor, log_sigma: torch.Tensor, target: torch.Tensor, valid: torch.Tensor
) -> torch.Tensor:
    """Mean over valid pixels of 1/2 ((pred - target) / e^sigma)^2 + sigma (all-day eq. 2)."""
    r = (pred - target) * torch.exp(-log_sigma)
    loss = 0.5 * r**2 + log_sigma
    return (loss * valid).sum() / valid.sum().clamp(min=1.0)
