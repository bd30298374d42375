"""The self-supervised objective on one batch (LeoVR eq. 22): the photometric loss with its masks, the
landmark, refined-depth, smoothness, sparse-depth, masked-LiDAR and anchor terms, and the uncertainty head's
Gaussian NLL."""

from __future__ import annotations

import torch

from leovr.config import SelfSupConfig
from leovr.depth.layers import gaussian_nll
from selfsup.losses import (
    feature_point_loss,
    anchor_loss,
    masked_lidar_loss,
    photometric_error,
    photometric_loss,
    refined_depth_loss,
    sparse_depth_loss,
    second_order_smoothness,
)
from selfsup.warp import warp_image

TERMS = (
    "loss",
    "photometric",
    "feature",
    "refined",
    "smooth",
    "nll",
    "sparse",
    "masked",
    "anchor",
    "mask_kept",
    "refined_used",
)


def photometric_term(
    img: torch.Tensor, depth: torch.Tensor, b: dict, cfg: SelfSupConfig
) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
    """L_p (eq. 16) with the masks of the batch: (loss, warped neighbours, kept pixels per neighbour).
    With `auto_mask` (monodepth2), a pixel also drops out against a neighbour it matches better
    unwarped (a mover at the ego's speed, a standing camera), and the loss takes the per-pixel
    minimum over the neighbours that keep it."""
    warped, masks, errors = [], [], []
    for side in ("prev", "next"):
        w, inside = warp_image(b[side], depth, b[f"T_{side}"], b["K"])
        keep = inside & (b[f"mask_{side}"] > 0.5)
        err = photometric_error(img, w)
        if cfg.auto_mask:
            keep = keep & (err.detach() < photometric_error(img, b[side]))
        warped.append(w)
        masks.append(keep)
        errors.append(err)
    return photometric_loss(errors, masks, per_pixel_min=cfg.auto_mask), warped, masks


def batch_terms(
    depth: torch.Tensor,
    b: dict,
    cfg: SelfSupConfig,
    refine_stage: bool,
    log_sigma: torch.Tensor | None = None,
    masked_depth: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, float], dict[str, torch.Tensor]]:
    """Eq. 22 on one batch, plus the uncertainty head's Gaussian NLL at the LiDAR-backed landmarks
    (on detached depth, and the head sees detached features: it trains the head only) and the masked-LiDAR
    term on `masked_depth`, the network's depth from the batch's thinner input: (total loss, detached terms,
    images)."""
    img = b["image"]
    lp, warped, masks = photometric_term(img, depth, b, cfg)
    lf = (
        feature_point_loss(depth, b["feature_depth"], cfg.target_loss)
        if cfg.weight_feature > 0
        else depth.new_zeros(())
    )
    use_r = refine_stage and cfg.weight_refined > 0 and bool(b["use_refined"].any())
    lr = refined_depth_loss(depth, b["refined"], b["use_refined"], cfg.target_loss) if use_r else depth.new_zeros(())
    ls = second_order_smoothness(depth, img) if cfg.weight_smooth > 0 else depth.new_zeros(())
    lz = sparse_depth_loss(depth, b["sparse"], cfg.target_loss) if cfg.weight_sparse > 0 else depth.new_zeros(())
    lm = masked_lidar_loss(masked_depth, b["masked_target"]) if masked_depth is not None else depth.new_zeros(())
    la = anchor_loss(depth, b["anchor"]) if cfg.weight_anchor > 0 and "anchor" in b else depth.new_zeros(())
    nll = depth.new_zeros(())
    if cfg.weight_nll > 0 and log_sigma is not None:
        nll = gaussian_nll(depth.detach(), log_sigma, b["feature_depth"], (b["feature_depth"] > 0).to(depth.dtype))
    loss = (
        lp
        + cfg.weight_feature * lf
        + cfg.weight_refined * lr
        + cfg.weight_smooth * ls
        + cfg.weight_nll * nll
        + cfg.weight_sparse * lz
        + cfg.weight_masked * lm
        + cfg.weight_anchor * la
    )
    terms = {
        "loss": loss.item(),
        "photometric": lp.item(),
        "feature": lf.item(),
        "refined": lr.item(),
        "smooth": ls.item(),
        "nll": nll.item(),
        "sparse": lz.item(),
        "masked": lm.item(),
        "anchor": la.item(),
        "mask_kept": float(torch.cat(masks).float().mean()),
        "refined_used": float(b["use_refined"].float().mean()) if refine_stage else 0.0,
    }
    return loss, terms, {"warped_prev": warped[0], "mask_prev": masks[0]}
