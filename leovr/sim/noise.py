"""Hash-based 3-D value noise, vectorized, deterministic across machines (integer hashing only)."""

from __future__ import annotations

import numpy as np

_P1, _P2, _P3 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9)


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Lattice hash to [0, 1)."""
    h = (ix.astype(np.uint64) * _P1) ^ (iy.astype(np.uint64) * _P2) ^ (iz.astype(np.uint64) * _P3)
    h ^= np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x27D4EB2F165667C5)
    h ^= h >> np.uint64(29)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(32)
    return (h >> np.uint64(40)).astype(np.float64) / float(1 << 24)


def value_noise(p: np.ndarray, freq: float, seed: int = 0) -> np.ndarray:
    """Smooth noise in [0, 1) at points p (N x 3), `freq` cycles per metre."""
    q = p * freq
    i = np.floor(q)
    f = q - i
    f = f * f * (3.0 - 2.0 * f)
    i = i.astype(np.int64)
    out = np.zeros(len(p))
    with np.errstate(over="ignore"):
        for dx in (0, 1):
            wx = f[:, 0] if dx else 1.0 - f[:, 0]
            for dy in (0, 1):
                wy = f[:, 1] if dy else 1.0 - f[:, 1]
                for dz in (0, 1):
                    wz = f[:, 2] if dz else 1.0 - f[:, 2]
                    out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fractal_noise(p: np.ndarray, freqs: tuple[float, ...], footprint: np.ndarray, seed: int = 0) -> np.ndarray:
    """Sum of octaves in [-0.5, 0.5] scaled by 1/sqrt(octave); each octave fades out when its period
    shrinks below two pixel footprints (metres per pixel at the hit), which avoids aliasing shimmer."""
    out = np.zeros(len(p))
    for k, fr in enumerate(freqs):
        fade = np.clip(1.0 / (fr * 2.0 * np.maximum(footprint, 1e-6)) - 1.0, 0.0, 1.0)
        live = fade > 0
        if live.any():
            out[live] += fade[live] * (value_noise(p[live], fr, seed + 101 * k) - 0.5) / np.sqrt(k + 1)
    return out
