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
    orb = cv2.ORB_create(
        nfeatures=n_features, scaleFactor=SCALE_FACTOR, fastThreshold=12, edgeThreshold=15, patchSize=15
    )
    kps, desc = orb.detectAndCompute(gray, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), np.zeros(0, np.int32))
    return Features(np.array([k.pt for k in kps], np.float32), desc, np.array([k.octave for k in kps], np.int32))


def match(a: Features, b: Features, ratio: float = 0.8, max_distance: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of mutual best matches that pass Lowe's ratio test, in the order of `a`.

    OpenCV's brute-force Hamming distances (`batchDistance`, what its BFMatcher runs): each of a's two nearest in b,
    then, for the b's that some a chose, their nearest in a (the mutual check needs no other b's)."""
    if len(a) < 2 or len(b) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dist, nearest = cv2.batchDistance(a.desc, b.desc, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
    ia = np.nonzero((dist[:, 0] < ratio * dist[:, 1]) & (dist[:, 0] <= max_distance))[0]
    ib = nearest[ia, 0].astype(np.int64)
    if not len(ia):
        return ia.astype(np.int64), ib
    chosen = np.unique(ib)
    _, back = cv2.batchDistance(b.desc[chosen], a.desc, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=1)
    mutual = back[np.searchsorted(chosen, ib), 0] == ia
    return ia[mutual].astype(np.int64), ib[mutual]
