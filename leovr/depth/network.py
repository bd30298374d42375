"""LeoVR's depth-map generator (Sec. III-B, V-A): RGB and LiDAR ResNet-34-style encoders with stage
channels [16, 32, 64, 128, 128] (stride 2 per stage, so a 448x256 input meets the cross-attention as
14x8x128), inter-sensor cross-attention at the bottleneck, a decoder with skip connections from both
encoders at every scale, positive metric depth out and a log-uncertainty head."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from leovr.depth.layers import (
    BasicBlock,
    CrossAttention,
    PartialStage,
    conv_bn_relu,
    resnet_stage,
)

CHANNELS = (16, 32, 64, 128, 128)
BLOCKS = (3, 4, 6, 3)  # ResNet-34 blocks per stage after the stem
DEPTH_NORM_M = 20.0  # sparse depth enters the network as depth / 20 m


@dataclass
class GeneratorConfig:
    lidar_encoder: str = "partial"  # partial (SLIM partial convolutions) | interp (pre-interpolated input)
    cross_attention: bool = True
    attention_dim: int = 64
    channels: tuple[int, ...] = CHANNELS
    blocks: tuple[int, ...] = BLOCKS
    max_depth: float = 250.0


class RGBEncoder(nn.Module):
    def __init__(self, ch: tuple[int, ...], blocks: tuple[int, ...]) -> None:
        super().__init__()
        self.stem = nn.Sequential(conv_bn_relu(3, ch[0], 2), BasicBlock(ch[0], ch[0]))
        self.stages = nn.ModuleList(resnet_stage(ch[i], ch[i + 1], blocks[i]) for i in range(len(ch) - 1))

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = [self.stem(x)]
        for s in self.stages:
            feats.append(s(feats[-1]))
        return feats


class LidarEncoder(nn.Module):
    """Sparse-depth encoder; `partial` uses mask-aware convolutions in every stage, `interp` a plain
    ResNet on the pre-interpolated (pyramid-filled) depth plus its validity mask."""

    def __init__(self, ch: tuple[int, ...], blocks: tuple[int, ...], kind: str) -> None:
        super().__init__()
        if kind not in ("partial", "interp"):
            raise ValueError(f"lidar_encoder must be 'partial' or 'interp', not '{kind}'")
        self.kind = kind
        if kind == "partial":
            self.stem = PartialStage(1, ch[0])
            self.stages = nn.ModuleList(PartialStage(ch[i], ch[i + 1]) for i in range(len(ch) - 1))
        else:
            self.stem = nn.Sequential(conv_bn_relu(2, ch[0], 2), BasicBlock(ch[0], ch[0]))
            self.stages = nn.ModuleList(resnet_stage(ch[i], ch[i + 1], blocks[i]) for i in range(len(ch) - 1))

    def forward(self, sparse: torch.Tensor, filled: torch.Tensor) -> list[torch.Tensor]:
        mask = (sparse > 0).to(sparse.dtype)
        if self.kind == "interp":
            feats = [self.stem(torch.cat([filled, mask], 1))]
            for s in self.stages:
                feats.append(s(feats[-1]))
            return feats
        x, m = self.stem(sparse, mask)
        feats = [x]
        for s in self.stages:
            x, m = s(x, m)
            feats.append(x)
        return feats


class DepthGenerator(nn.Module):
    """Inputs: image (B x 3 x H x W, 0-1) and sparse depth (B x 1 x H x W, metres, 0 = none), with
    H and W multiples of 32. Outputs: depth (metres, positive) and log-sigma, both B x 1 x H x W."""

    def __init__(self, cfg: GeneratorConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg = cfg or GeneratorConfig()
        ch = cfg.channels
        self.rgb = RGBEncoder(ch, cfg.blocks)
        self.lidar = LidarEncoder(ch, cfg.blocks, cfg.lidar_encoder)
        self.attention = CrossAttention(ch[-1], cfg.attention_dim) if cfg.cross_attention else None
        self.decoders = nn.ModuleList()
        cin = 2 * ch[-1]
        for i in range(len(ch) - 2, -1, -1):  # 1/16 ... 1/2
            self.decoders.append(nn.Sequential(conv_bn_relu(cin + 2 * ch[i], ch[i]), conv_bn_relu(ch[i], ch[i])))
            cin = ch[i]
        self.full = conv_bn_relu(cin + 3 + 2, ch[0])
        self.depth_head = nn.Conv2d(ch[0], 1, 3, 1, 1)  # last layer: no BN / ReLU
        self.sigma_head = nn.Sequential(conv_bn_relu(ch[0], ch[0]), nn.Conv2d(ch[0], 1, 3, 1, 1))

    def depth_parameters(self) -> list[nn.Parameter]:
        """Everything but the uncertainty head (frozen while the head is trained, all-day Sec. III-A)."""
        head = {id(p) for p in self.sigma_head.parameters()}
        return [p for p in self.parameters() if id(p) not in head]

    def forward(self, image: torch.Tensor, sparse: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, w = image.shape[-2:]
        if h % 32 or w % 32:
            raise ValueError(f"image size {w}x{h} must be a multiple of 32 in both directions")
        s = sparse / DEPTH_NORM_M
        filled = pyramid_fill(s)
        f_rgb = self.rgb(image)
        f_lidar = self.lidar(s, filled)
        if self.attention is not None:
            x = self.attention(f_rgb[-1], f_lidar[-1])
        else:
            x = torch.cat([f_rgb[-1], f_lidar[-1]], 1)
        for k, dec in enumerate(self.decoders):
            i = len(f_rgb) - 2 - k
            x = F.interpolate(x, size=f_rgb[i].shape[-2:], mode="bilinear", align_corners=False)
            x = dec(torch.cat([x, f_rgb[i], f_lidar[i]], 1))
        x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)
        x = self.full(torch.cat([x, image, filled, (s > 0).to(s.dtype)], 1))
        log_depth = self.depth_head(x) + math.log(DEPTH_NORM_M)
        depth = torch.exp(log_depth.clamp(max=math.log(self.cfg.max_depth)))
        return depth, self.sigma_head(x)


def pyramid_fill(sparse: torch.Tensor) -> torch.Tensor:
    """Dense prior for the network input: each empty pixel takes the smallest valid depth of the
    smallest aligned 2^k x 2^k block around it that holds one (a few max-pools; no gradient needed).
    Pixels with no valid value anywhere stay 0."""
    out = sparse.clone()
    valid = sparse > 0
    h, w = sparse.shape[-2:]
    scale = 1
    while not bool(valid.all()) and scale < max(h, w):
        scale *= 2
        pooled = F.max_pool2d(torch.where(valid, -out, torch.full_like(out, -1e9)), scale, scale, ceil_mode=True)
        up = -F.interpolate(pooled, scale_factor=scale, mode="nearest")[..., :h, :w]
        fill_here = ~valid & (up > 0) & (up < 1e8)
        out = torch.where(fill_here, up, out)
        valid = valid | fill_here
    return out
