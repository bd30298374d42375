"""LeoVR's depth-map generator (Sec. III-B, V-A): RGB and LiDAR ResNet-34-style encoders with stage
channels [16, 32, 64, 128, 128] (stride 2 per stage, so a 448x256 input meets the cross-attention as
14x8x128), inter-sensor cross-attention at the bottleneck, a decoder with skip connections from both
encoders at every scale, positive metric depth out and a log-uncertainty head.

Output modes (`GeneratorConfig.output`):
- `absolute`: the decoder predicts log depth (the first shipped generator);
- `residual`: it predicts a log-depth residual r over the classical prior z (leovr.depth.prior):
  d = z exp(r), so a network that has learnt nothing returns the interpolated LiDAR;
- `fusion`: as `residual`, then the all-day paper's uncertainty-driven residual fusion (eqs. 3-4):
  a second head predicts the prior's log uncertainty s (imputed with gamma = -2 at measured pixels,
  all-day Sec. III-A), lambda = 1 / (1 + exp(alpha (s - beta))) and d = lambda z + (1 - lambda) z exp(r).
  Near the measurements the prior dominates, so the network cannot stray far from what was measured.
The prior, residual and fusion weight combine at any resolution (`combine`), so a network run at its
training focal length keeps the full-resolution prior's detail.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from leovr.depth.layers import (
    BasicBlock,
    CrossAttention,
    PartialStage,
    conv_bn_relu,
    resnet_stage,
    uncertainty_residual,
)

CHANNELS = (16, 32, 64, 128, 128)
BLOCKS = (3, 4, 6, 3)  # ResNet-34 blocks per stage after the stem
DEPTH_NORM_M = 20.0  # sparse depth enters the network as depth / 20 m
OUTPUTS = ("absolute", "residual", "fusion")


@dataclass
class GeneratorConfig:
    lidar_encoder: str = "partial"  # partial (SLIM partial convolutions) | interp (pre-interpolated input)
    cross_attention: bool = True
    attention_dim: int = 64
    channels: tuple[int, ...] = CHANNELS
    blocks: tuple[int, ...] = BLOCKS
    max_depth: float = 250.0
    output: str = "absolute"  # absolute | residual | fusion (see the module docstring)
    fusion_alpha: float = 0.8  # all-day eq. 3
    fusion_beta: float = 0.0
    measured_log_sigma: float = -2.0  # gamma: the prior's log uncertainty at measured pixels

    def __post_init__(self) -> None:
        if self.output not in OUTPUTS:
            raise ValueError(f"output must be one of {', '.join(OUTPUTS)}, not '{self.output}'")


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
        self.fusion_head = nn.Conv2d(ch[0], 1, 3, 1, 1) if cfg.output == "fusion" else None
        self.sigma_on_detached = False  # a training switch (not saved): see forward
        if cfg.output != "absolute":  # start as the prior itself: zero residual, lambda = 1/2
            for head in (self.depth_head, self.fusion_head):
                if head is not None:
                    nn.init.zeros_(head.weight)
                    nn.init.zeros_(head.bias)

    def depth_parameters(self) -> list[nn.Parameter]:
        """Everything but the uncertainty head (frozen while the head is trained, all-day Sec. III-A)."""
        head = {id(p) for p in self.sigma_head.parameters()}
        return [p for p in self.parameters() if id(p) not in head]

    @property
    def uses_prior(self) -> bool:
        return self.cfg.output != "absolute"

    def parts(
        self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """The network's outputs before they are combined with the prior, at the input's resolution:
        `log_depth` (absolute) or `log_residual` (+ `prior_log_sigma` for fusion), and `log_sigma`,
        the uncertainty of the final depth (what the graph uses as a prior)."""
        h, w = image.shape[-2:]
        if h % 32 or w % 32:
            raise ValueError(f"image size {w}x{h} must be a multiple of 32 in both directions")
        s = sparse / DEPTH_NORM_M
        if self.uses_prior:
            if prior is None:
                raise ValueError("a residual-mode generator needs the classical prior (prior_for)")
            filled = prior / DEPTH_NORM_M
        else:
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
        # with `sigma_on_detached`, the uncertainty head's loss reaches the head only, never the depth path
        out = {"log_sigma": self.sigma_head(x.detach() if self.sigma_on_detached else x)}
        if not self.uses_prior:
            out["log_depth"] = self.depth_head(x) + math.log(DEPTH_NORM_M)
        else:
            out["log_residual"] = self.depth_head(x)
            if self.fusion_head is not None:
                out["prior_log_sigma"] = self.fusion_head(x)
        return out

    def combine(self, parts: dict[str, torch.Tensor], prior: torch.Tensor | None, sparse: torch.Tensor) -> torch.Tensor:
        """Final depth (metres) from `parts` and, for the residual modes, the prior and the sparse input,
        all at one resolution (parts may have been resized to it)."""
        cap = math.log(self.cfg.max_depth)
        if not self.uses_prior:
            return torch.exp(parts["log_depth"].clamp(max=cap))
        z = prior.clamp(min=1e-3)
        refined = torch.exp((torch.log(z) + parts["log_residual"]).clamp(max=cap))
        if self.cfg.output == "fusion":
            s = torch.where(sparse > 0, torch.full_like(sparse, self.cfg.measured_log_sigma), parts["prior_log_sigma"])
            refined = uncertainty_residual(z, s, refined, self.cfg.fusion_alpha, self.cfg.fusion_beta)
        return refined

    def forward(
        self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Depth (metres) and log-sigma at the input's resolution. `prior` (B x 1 x H x W metres) is the
        classical prior of `sparse`; computed here when a residual mode needs it and none is given."""
        if self.uses_prior and prior is None:
            prior = prior_for(sparse)
        parts = self.parts(image, sparse, prior)
        return self.combine(parts, prior, sparse), parts["log_sigma"]


def prior_for(sparse: torch.Tensor, image: torch.Tensor | None = None) -> torch.Tensor:
    """The classical prior (leovr.depth.prior.interpolated_fill) of a B x 1 x H x W sparse batch; a map
    without any return (a sequence without LiDAR) gets a flat DEPTH_NORM_M, which the residual reshapes.
    `image` (B x 3 x H x W in [0, 1]) picks the side of depth edges; without it, the nearest return."""
    from leovr.depth.prior import interpolated_fill_batch

    images = None
    if image is not None:
        images = (image.detach().cpu().permute(0, 2, 3, 1).numpy() * 255.0).round().clip(0, 255).astype(np.uint8)
    filled = torch.from_numpy(interpolated_fill_batch(sparse.detach().cpu().numpy().astype(np.float32), images))
    filled = filled.to(sparse.device, sparse.dtype)
    empty = ~(sparse > 0).flatten(1).any(1)
    if bool(empty.any()):
        filled[empty] = DEPTH_NORM_M
    return filled


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
