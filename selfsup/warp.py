"""Differentiable inverse warping (LeoVR eqs. 14-15): back-project frame i's predicted depth, move
the points by T_ji into frame j, project, and sample frame j bilinearly at those pixels."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def pixel_rays(K: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """B x 3 x (h w) rays K^-1 [u v 1]^T of every pixel centre (pixel (0, 0) is at u = v = 0)."""
    v, u = torch.meshgrid(
        torch.arange(h, dtype=K.dtype, device=K.device), torch.arange(w, dtype=K.dtype, device=K.device), indexing="ij"
    )
    pix = torch.stack([u.reshape(-1), v.reshape(-1), torch.ones(h * w, dtype=K.dtype, device=K.device)])
    return torch.linalg.inv(K) @ pix


def project_to(depth: torch.Tensor, T_j_i: torch.Tensor, K: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixels (B x H x W x 2) in frame j of frame i's pixels at `depth` (B x 1 x H x W), and where the
    moved point lies in front of camera j (B x 1 x H x W bool)."""
    b, _, h, w = depth.shape
    P = pixel_rays(K, h, w) * depth.reshape(b, 1, -1)  # B x 3 x HW, camera i
    Q = T_j_i[:, :3, :3] @ P + T_j_i[:, :3, 3:]  # camera j
    z = Q[:, 2:3]
    uv = (K @ Q)[:, :2] / z.clamp(min=1e-3)
    return uv.permute(0, 2, 1).reshape(b, h, w, 2), (z > 1e-3).reshape(b, 1, h, w)


def warp_image(
    image_j: torch.Tensor, depth_i: torch.Tensor, T_j_i: torch.Tensor, K: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """I_{j->i}: frame j sampled at the projections of frame i's pixels (B x C x H x W), and the valid
    mask (projection inside frame j and in front of its camera)."""
    _, _, h, w = image_j.shape
    uv, front = project_to(depth_i, T_j_i, K)
    grid = torch.stack([2 * uv[..., 0] / (w - 1) - 1, 2 * uv[..., 1] / (h - 1) - 1], -1)
    warped = F.grid_sample(image_j, grid, mode="bilinear", padding_mode="border", align_corners=True)
    inside = (grid.abs() <= 1).all(-1, keepdim=True).permute(0, 3, 1, 2)
    return warped, inside & front
