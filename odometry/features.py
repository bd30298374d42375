"""ORB features (OpenCV) and descriptor matching between frames."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

SCALE_FACTOR = 1.2  # ORB's pyramid: each level 1.2x coarser (OpenCV's default)


@dataclass
class Features:
    """Keypoints of one frame: pixel coordinates (N x 2, float), ORB descriptors (N x 32 uint8) and the
    pyramid level each was found at (None: all at full resolution)."""

    uv: np.ndarray
    desc: np.ndarray
    octave: np.ndarray | None = None

    def pixel_scale(self, idx: np.ndarray) -> np.ndarray:
        """How much coarser than a full-resolution pixel the position of each keypoint `idx` is: a keypoint
        found on pyramid level n is located to about SCALE_FACTOR**n pixels (as ORB-SLAM weights it)."""
        if self.octave is None:
            return np.ones(len(idx))
        return SCALE_FACTOR ** self.octave[idx].astype(float)

    def __len__(self) -> int:
        return len(self.uv)


def detect(image: np.ndarray, n_features: int = 1000) -> Features:
    """ORB keypoints spread over the image (FAST threshold lowered where texture is weak)."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    orb = cv2.ORB_create(nfeatures=n_features, scaleFactor=SCALE_FACTOR, fastThreshold=12, edgeThreshold=15,
                         patchSize=15)
    kps, desc = orb.detectAndCompute(gray, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), np.zeros(0, np.int32))
    return Features(np.array([k.pt for k in kps], np.float32), desc, np.array([k.octave for k in kps], np.int32))


def match(a: Features, b: Features, ratio: float = 0.8, max_distance: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of mutual best matches that pass Lowe's ratio test."""
    if len(a) < 2 or len(b) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    fwd = bf.knnMatch(a.desc, b.desc, k=2)
    back = {m.queryIdx: m.trainIdx for m in bf.match(b.desc, a.desc)}
    ia, ib = [], []
    for pair in fwd:
        if len(pair) < 2:
            continue
        m, n = pair
        if m.distance < ratio * n.distance and m.distance <= max_distance and back.get(m.trainIdx) == m.queryIdx:
            ia.append(m.queryIdx)
            ib.append(m.trainIdx)
    return np.array(ia, np.int64), np.array(ib, np.int64)
