"""Ground truth from held-out LiDAR points, with the parallax filter the shared data README asks for."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

# a held-out point is dropped when a return within this window (px, side) is nearer by more than this fraction
PARALLAX_WINDOW = 7
PARALLAX_REL = 0.15


def parallax_filter(
    heldout: np.ndarray,
    all_returns: np.ndarray,
    window: int | tuple[int, int] = PARALLAX_WINDOW,
    rel: float = PARALLAX_REL,
) -> np.ndarray:
    """Drop held-out depths that have a clearly nearer return nearby.

    The LiDAR sits behind and above the camera, so near object edges it sees background the camera
    cannot. A held-out pixel is dropped when some return (kept or held out) within a `window` x
    `window` (or rows x cols) neighbourhood is nearer by more than `rel` (fraction of its depth). Maps use 0 = none.
    """
    near = np.where(all_returns > 0, all_returns, np.inf)
    nearest = minimum_filter(near, size=window, mode="constant", cval=np.inf)
    out = heldout.copy()
    out[(heldout > 0) & (nearest < heldout * (1.0 - rel))] = 0
    return out


FILTER_DESCRIPTION = (
    f"held-out points with a return nearer by more than {PARALLAX_REL:.0%} within a "
    f"{PARALLAX_WINDOW}x{PARALLAX_WINDOW} window were dropped (LiDAR-camera parallax)"
)
