"""Pieces shared by the two KITTI readers: projection matrices and pose files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.data.io import require_finite_rows
from leovr.errors import DataError

# the KITTI recording platform's cameras sit 1.65 m above the road (Geiger et al., "Vision meets
# robotics: the KITTI dataset", IJRR 2013, sensor setup)
KITTI_CAMERA_HEIGHT_M = 1.65


def split_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a rectified 3x4 projection P = K [I | t] into K and the 4x4 transform [I | t]."""
    K = P[:3, :3].copy()
    T = np.eye(4)
    T[:3, 3] = np.linalg.solve(K, P[:, 3])
    return K, T


def read_kitti_poses(path: Path) -> np.ndarray:
    """Read a KITTI pose file (one 3x4 row-major matrix per line) as F x 4 x 4."""
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataError(path, f"unreadable pose file: {exc}") from exc
    if rows.shape[1] != 12:
        raise DataError(path, f"expected 12 numbers per line (a 3x4 matrix), got {rows.shape[1]}")
    require_finite_rows(rows, path)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :4] = rows.reshape(-1, 3, 4)
    return T


def write_kitti_poses(path: Path, poses: np.ndarray) -> None:
    """Write F x 4 x 4 poses as a KITTI pose file (3x4 row-major per line), atomically."""
    from leovr.data.io import write_text

    lines = [" ".join(f"{v:.9e}" for v in np.asarray(T)[:3, :4].ravel()) for T in poses]
    write_text(path, "\n".join(lines) + ("\n" if lines else ""))
