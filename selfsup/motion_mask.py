"""Movers that eq. 19 cannot see: the rigid-flow test and the depth test.

A car ahead at the ego's speed, or oncoming traffic, moves along the epipolar lines, so its flow
passes the epipolar test of eq. 19 (`selfsup.flow_mask`). The rigid flow, the flow that the graph's
pose and the current depth predict for a static scene, tells them apart: a pixel is dropped when its
measured flow differs from the rigid flow, in magnitude or direction, by more than the depth's
uncertainty allows. Only the translation part of the rigid flow depends on depth (the rotation part
does not), so the tolerance is `abs_px` plus `rel` times that part: `rel` is how far off the depth
may be, relatively.

The dense flow is started from the rigid flow (`rigid_tests`), which eq. 19 then uses too.

The depth test (`depth_disagreement`) needs no flow: frame i's depth, moved by the camera motion into
frame j, must meet frame j's own depth there. A car ahead at the ego's speed stays as far away as
before, so frame j sees it further than a static point would be: the static scene would have to be
seen through. An oncoming car comes nearer than a static point would. Both tests see movers where
the depth is known; a pixel dropped by one of them is dropped when its connected region of dropped
pixels holds a pixel that both drop (`movers`: hysteresis, as in Canny's edges): either test alone
fires on static pixels too (weak texture, occlusions), both together rarely do.

`pair_keep` returns each test apart, so that the trainer can switch them independently and the
benchmark can score each one against the simulator's moving masks (`selfsup.mask_quality`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from leovr.geometry import invert_T
from selfsup.flow_mask import dense_flow, epipolar_keep, flow_inside, gray


@dataclass
class PairKeep:
    """Per test, H x W bools: True = the pixel of frame i may enter the photometric loss against j."""

    inside: np.ndarray  # the flow end point lies inside frame j
    epipolar: np.ndarray  # eq. 19: within lambda px of its epipolar line (True without translation)
    rigid: np.ndarray  # the measured flow agrees with the rigid flow (True where depth is unknown)
    depth: np.ndarray  # frame i's depth moved into frame j meets frame j's depth (True where either is unknown)


def move_pixels(
    depth: np.ndarray, T_j_i: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame i's pixels at `depth` (H x W metres, 0 = unknown), moved as static points by T_j_i into
    frame j: (H x W x 2 pixel in frame j, H x W depth in frame j, H x W x 2 pixel of the rotation alone,
    H x W valid). Invalid pixels hold their own position and depth 0."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T  # z = 1
    R, t = T_j_i[:3, :3], T_j_i[:3, 3]
    rot = rays @ R.T  # a point at infinity: the rotation alone
    X = depth[..., None] * rot + t
    valid = (depth > 0) & (X[..., 2] > 1e-3) & (rot[..., 2] > 1e-6)
    p = X @ K.T
    q = rot @ K.T
    uv = np.stack([u, v], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = p[..., :2] / np.where(valid, p[..., 2], 1.0)[..., None]
        rot_only = q[..., :2] / np.where(valid, q[..., 2], 1.0)[..., None]
    keep = valid[..., None]
    return np.where(keep, moved, uv), np.where(valid, X[..., 2], 0.0), np.where(keep, rot_only, uv), valid


def rigid_flow(depth: np.ndarray, T_j_i: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flow of a static scene with depth `depth` (H x W metres, 0 = unknown) under the motion T_j_i
    (frame i to frame j): (H x W x 2 rigid flow, H x W x 2 flow of the rotation alone, H x W valid)."""
    moved, _, rot_only, valid = move_pixels(depth, T_j_i, K)
    uv = np.stack(np.meshgrid(np.arange(depth.shape[1]), np.arange(depth.shape[0])), -1).astype(np.float64)
    return moved - uv, rot_only - uv, valid


def dis_flow(a: np.ndarray, b: np.ndarray, init: np.ndarray | None) -> np.ndarray:
    """DIS flow (medium preset, down to full resolution) from a to b, started from `init` if given."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(0)
    return dis.calc(gray(a), gray(b), None if init is None else np.ascontiguousarray(init, np.float32))


def _rigid_init(depth: np.ndarray, T_j_i: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    full, rot_only, valid = rigid_flow(depth, T_j_i, K)
    return np.where(valid[..., None], full, rot_only), full - rot_only, valid


def rigid_tests(
    image_i: np.ndarray,
    image_j: np.ndarray,
    depth_i: np.ndarray,
    depth_j: np.ndarray,
    T_j_i: np.ndarray,
    K: np.ndarray,
    abs_px: float,
    rel: float,
    fb_px: float = 2.0,
    open_px: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """(dense flow i -> j, H x W rigid agreement). The flow starts from the rigid flow (DIS then only
    has to find what departs from it: a far better flow on the large, weakly textured motion of
    the near road, where an uninitialised flow fails). A pixel disagrees when its flow departs from
    the rigid flow by more than abs_px + rel |translation part| and the flow is trustworthy there
    (forward-backward consistent within `fb_px`: an occlusion is not a mover); specks thinner than
    `open_px` are removed (a mover is a blob). A pixel without depth cannot be tested and agrees."""
    init, trans, valid = _rigid_init(depth_i, T_j_i, K)
    flow = dis_flow(image_i, image_j, init)
    back = dis_flow(image_j, image_i, _rigid_init(depth_j, invert_T(T_j_i), K)[0])
    h, w = flow.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    back_at = cv2.remap(back, u + flow[..., 0], v + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    consistent = np.linalg.norm(flow + back_at, axis=-1) < fb_px
    gap = np.linalg.norm(flow - init, axis=-1)
    moving = valid & consistent & (gap > abs_px + rel * np.linalg.norm(trans, axis=-1))
    return flow, ~_open(moving, open_px)


def _open(mask: np.ndarray, open_px: int) -> np.ndarray:
    """Specks thinner than `open_px` removed (a mover is a blob)."""
    if open_px <= 1:
        return mask
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8)) > 0


def depth_disagreement(
    depth_i: np.ndarray, depth_j: np.ndarray, T_j_i: np.ndarray, K: np.ndarray, rel: float, open_px: int = 3
) -> np.ndarray:
    """H x W bools of frame i: a static point at frame i's depth, moved by T_j_i, lands in frame j at
    depth z, and frame j's depth there (within its 3 x 3 neighbourhood, so that a depth edge is no
    evidence) is nearer than z / (1 + rel) or further than z / (1 - rel). Further: the static scene
    would be seen through (a mover keeping its distance); nearer: an oncoming mover or an occluder.
    Unknown depth (0) in either frame: no disagreement."""
    moved, z, _, ok = move_pixels(depth_i, T_j_i, K)
    uj = np.where(ok, moved[..., 0], -1.0).astype(np.float32)
    vj = np.where(ok, moved[..., 1], -1.0).astype(np.float32)
    known = depth_j > 0
    box = np.ones((3, 3), np.uint8)
    near = cv2.erode(np.where(known, depth_j, np.inf).astype(np.float32), box)  # nearest known depth around
    far = cv2.dilate(np.where(known, depth_j, 0.0).astype(np.float32), box)  # furthest known depth around
    near_at = cv2.remap(near, uj, vj, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
    far_at = cv2.remap(far, uj, vj, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    tested = ok & np.isfinite(near_at) & (far_at > 0)
    with np.errstate(invalid="ignore"):
        moving = tested & ((z < near_at * (1.0 - rel)) | (z > far_at * (1.0 + rel)))
    return _open(moving, open_px)


def movers(drop_a: np.ndarray, drop_b: np.ndarray) -> np.ndarray:
    """Hysteresis of two mover tests: the connected regions (8-neighbours) of pixels that either test
    drops, kept where they hold a pixel that both drop."""
    weak = (drop_a | drop_b).astype(np.uint8)
    n, labels = cv2.connectedComponents(weak, connectivity=8)
    hit = np.zeros(n, bool)
    hit[np.unique(labels[drop_a & drop_b])] = True
    hit[0] = False  # background
    return hit[labels]


def pair_keep(
    image_i: np.ndarray,
    image_j: np.ndarray,
    T_j_i: np.ndarray,
    K: np.ndarray,
    depth: tuple[np.ndarray, np.ndarray] | None = None,
    lam_px: float = 1.0,
    abs_px: float = 0.5,
    rel: float = 0.3,
    method: str = "dis",
    min_baseline_m: float = 1e-3,
    depth_rel: float = 0.05,
    rigid: bool = True,
    depth_test: bool = True,
) -> PairKeep:
    """Every test of the pair (i, j) that is asked for. `depth`: (depth_i, depth_j) for the rigid test
    (`rigid`; its rigid-initialised flow then serves eq. 19 too) and the depth test (`depth_test`); a
    test not run, or run without depth, keeps everything. Without the rigid test eq. 19 runs on the
    plain flow (`method`)."""
    if depth is not None and rigid:
        flow, rig = rigid_tests(image_i, image_j, depth[0], depth[1], T_j_i, K, abs_px, rel)
    else:
        flow = dense_flow(image_i, image_j, method)
        rig = np.ones(flow.shape[:2], bool)
    if depth is not None and depth_test:
        dep = ~depth_disagreement(depth[0], depth[1], T_j_i, K, depth_rel)
    else:
        dep = np.ones(flow.shape[:2], bool)
    return PairKeep(flow_inside(flow), epipolar_keep(flow, T_j_i, K, lam_px, min_baseline_m), rig, dep)
