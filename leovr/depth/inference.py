"""Run a trained depth generator on numpy inputs: image + sparse depth -> depth and log-sigma."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from leovr.depth.network import DepthGenerator, GeneratorConfig, prior_for
from leovr.errors import DataError


def load_generator(path: str | Path) -> DepthGenerator:
    """Load weights saved by a trainer (`best.pt`, `generator.pt` or `checkpoint_last.pt`); clear errors when the
    file is missing, is not a leovr checkpoint, or does not match the network it describes."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "depth-generator checkpoint not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for corrupt files
        raise DataError(path, f"unreadable checkpoint: {exc}") from exc
    if not isinstance(state, dict) or "model" not in state or "network" not in state:
        raise DataError(path, "not a leovr depth-generator checkpoint (needs 'model' and 'network')")
    try:
        net = dict(state["network"])
        net["channels"], net["blocks"] = tuple(net["channels"]), tuple(net["blocks"])
        model = DepthGenerator(GeneratorConfig(**net))
    except (TypeError, ValueError, KeyError) as exc:  # unknown or missing fields, values out of range
        raise DataError(path, f"invalid network description in the checkpoint: {exc}") from exc
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise DataError(path, f"checkpoint does not match the network it describes: {str(exc)[:300]}") from exc
    bad = [
        k
        for k, v in state["model"].items()
        if torch.is_tensor(v) and v.is_floating_point() and not torch.isfinite(v).all()
    ]
    if bad:
        raise DataError(
            path,
            f"{len(bad)} weight tensors hold NaN or infinite values (first: {bad[0]}); "
            "the training that wrote it diverged",
        )
    ranges = state.get("int8_ranges")
    if ranges is not None and not (isinstance(ranges, dict) and isinstance(ranges.get("data"), dict)):
        raise DataError(path, "its int8 calibration table ('int8_ranges') is not one; re-run tools/calibrate_int8.py")
    model.int8_ranges = ranges  # the activations' ranges for `generator_runtime: onnxruntime_int8` (or None)
    return model.eval()


def _pad32(image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None):
    """Edge-pad image (and prior) and zero-pad sparse depth to a multiple of 32 (the encoder's stride)."""
    h, w = sparse.shape[-2:]
    ph, pw = (-h) % 32, (-w) % 32
    if ph or pw:
        image = F.pad(image, (0, pw, 0, ph), mode="replicate")
        sparse = F.pad(sparse, (0, pw, 0, ph))
        if prior is not None:
            prior = F.pad(prior, (0, pw, 0, ph), mode="replicate")
    return image, sparse, prior


def forward_padded(
    model: torch.nn.Module,
    image: torch.Tensor,
    sparse: torch.Tensor,
    prior: torch.Tensor | None = None,
    image_edges: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Run the network on B x 3 x H x W images and B x 1 x H x W sparse depth of any size: edge-pad to
    a multiple of 32 (the encoder's total stride), crop the outputs back. A residual-mode network gets
    the classical prior of the unpadded input (computed when not given; `image_edges`: the image picks
    the side of its depth edges, as the shipped pipeline does; the trainers build it without)."""
    h, w = sparse.shape[-2:]
    if getattr(model, "uses_prior", False) and prior is None:
        prior = prior_for(sparse, image if image_edges else None)
    image, sparse_p, prior_p = _pad32(image, sparse, prior)
    depth, log_sigma = model(image, sparse_p, prior_p)
    return depth[..., :h, :w], log_sigma[..., :h, :w]


@torch.no_grad()
def predict(
    model: DepthGenerator, images: np.ndarray, sparse: np.ndarray, image_edges: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Depth (metres) and log-sigma for a batch (B x H x W x 3 uint8 or H x W x 3; sparse B x H x W or
    H x W, metres, 0 = none). Any size: inputs are edge-padded to a multiple of 32 and cropped back.
    `image_edges`: the prior takes the side of each depth edge from the image (leovr.depth.prior)."""
    single = images.ndim == 3
    if single:
        images, sparse = images[None], sparse[None]
    if images.shape[:3] != sparse.shape:
        raise ValueError(f"images {images.shape} and sparse depth {sparse.shape} disagree")
    if images.shape[-1] != 3:
        raise ValueError("images must be B x H x W x 3 (RGB)")
    img = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float() / 255.0
    sp = torch.from_numpy(np.ascontiguousarray(sparse, np.float32))[:, None]
    depth, log_sigma = forward_padded(model, img, sp, image_edges=image_edges)
    d, s = depth[:, 0].numpy(), log_sigma[:, 0].numpy()
    return (d[0], s[0]) if single else (d, s)


def rescale_sparse(sparse: np.ndarray, scale: float, shape: tuple[int, int]) -> np.ndarray:
    """Move each return of an H x W sparse depth map to pixel round(scale * (u, v)) of a map of `shape`;
    when several land on one pixel the nearest wins (as in projection)."""
    v, u = np.nonzero(sparse > 0)
    d = sparse[v, u]
    uu = np.clip(np.floor(u * scale + 0.5).astype(np.int64), 0, shape[1] - 1)
    vv = np.clip(np.floor(v * scale + 0.5).astype(np.int64), 0, shape[0] - 1)
    out = np.full(shape, np.inf, np.float32)
    np.minimum.at(out, (vv, uu), d)
    out[np.isinf(out)] = 0.0
    return out


def predict_at_focal(
    model: DepthGenerator,
    image: np.ndarray,
    sparse: np.ndarray,
    focal_px: float,
    model_focal_px: float | None,
    image_edges: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth and log-sigma of one frame, run at the focal length the model was trained with.

    A network trained on one camera learns object sizes in pixels; resampling a frame from `focal_px`
    to `model_focal_px` (e.g. KITTI's 721 px to the simulator's 260 px) removes that gap. The outputs
    are resized back to the frame's size. `model_focal_px=None` runs at the native resolution.
    """
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    scale = 1.0 if model_focal_px is None else model_focal_px / focal_px
    if abs(scale - 1.0) < 0.05:
        return predict(model, image, sparse, image_edges)
    import cv2

    h, w = sparse.shape
    shape = (max(8, int(round(h * scale))), max(8, int(round(w * scale))))
    small = cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    small_sparse = rescale_sparse(sparse, scale, shape)
    if not model.uses_prior:
        depth, log_sigma = predict(model, small, small_sparse, image_edges)
        back = [cv2.resize(x, (w, h), interpolation=cv2.INTER_LINEAR) for x in (depth, log_sigma)]
        return back[0], back[1]
    return predict_parts_full(model, small, small_sparse, sparse, scale, image if image_edges else None)


def sampled_prior(prior_full: np.ndarray, small_sparse: np.ndarray, scale: float) -> np.ndarray:
    """The network's input prior on a resampled frame: the full-resolution prior read at the full pixel
    each small pixel maps to (the inverse of `rescale_sparse`), the small map's returns kept exactly.
    Building the prior once at full resolution, not again on the small map, saves a KITTI frame's
    generator about a quarter of its time (239 against 326 ms) at equal MAE."""
    hs, ws = small_sparse.shape
    h, w = prior_full.shape
    rows = np.clip(np.floor(np.arange(hs) / scale + 0.5).astype(np.int64), 0, h - 1)
    cols = np.clip(np.floor(np.arange(ws) / scale + 0.5).astype(np.int64), 0, w - 1)
    out = np.ascontiguousarray(prior_full[np.ix_(rows, cols)], np.float32)
    measured = small_sparse > 0
    out[measured] = small_sparse[measured]
    return out


def network_priors(
    sparse: torch.Tensor, image: torch.Tensor | None, small_sparse: np.ndarray, scale: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The priors of a frame run at another focal length: the network's input prior (1 x 1 x hs x ws,
    `sampled_prior`) and the full-resolution one it is read from and combined with (1 x 1 x H x W), both
    from one `prior_for` of the full-resolution `sparse` (1 x 1 x H x W) and `image` (or None)."""
    full = prior_for(sparse, image)
    small = sampled_prior(full[0, 0].numpy(), np.asarray(small_sparse, np.float32), scale)
    return torch.from_numpy(small)[None, None], full


@torch.no_grad()
def predict_parts_full(
    model: DepthGenerator,
    small_image: np.ndarray,
    small_sparse: np.ndarray,
    sparse: np.ndarray,
    scale: float,
    image: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A residual-mode network run on the resampled frame, its residual, fusion uncertainty and sigma
    resized to the full frame and combined there with the full-resolution prior: the prior keeps every
    measured return and its pixel-exact interpolation; the network adds its correction. With the
    full-resolution `image`, both priors take the side of depth edges from the image."""
    img = torch.from_numpy(np.ascontiguousarray(small_image)).permute(2, 0, 1)[None].float() / 255.0
    sp = torch.from_numpy(np.ascontiguousarray(small_sparse, np.float32))[None, None]
    sp_full = torch.from_numpy(np.ascontiguousarray(sparse, np.float32))[None, None]
    img_full = (
        None if image is None else torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float() / 255.0
    )
    small_prior, prior_full = network_priors(sp_full, img_full, small_sparse, scale)
    h, w = sparse.shape
    image_p, sparse_p, prior_p = _pad32(img, sp, small_prior)
    hs, ws = small_sparse.shape
    parts = {k: v[..., :hs, :ws] for k, v in model.parts(image_p, sparse_p, prior_p).items()}
    full = {k: F.interpolate(v, size=(h, w), mode="bilinear", align_corners=False) for k, v in parts.items()}
    depth = model.combine(full, prior_full, sp_full)
    return depth[0, 0].numpy(), full["log_sigma"][0, 0].numpy()
