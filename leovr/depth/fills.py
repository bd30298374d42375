"""Every dense fill by name, for the pipelines and benchmarks: the classical fills (leovr.depth.classical) and
the generator's classical prior scored on its own (`interp`, leovr.depth.prior)."""

from __future__ import annotations

import numpy as np

from leovr.depth.classical import ipbasic, nearest_fill
from leovr.depth.prior import interpolated_fill

METHODS = {"nearest": nearest_fill, "ipbasic": ipbasic, "interp": interpolated_fill}


def complete_depth(sparse: np.ndarray, method: str, image: np.ndarray | None = None) -> np.ndarray:
    """Dense depth (metres) from a sparse map with a classical method; `image` (the frame) guides only
    `interp` at depth edges (leovr.depth.prior)."""
    if method not in METHODS:
        raise ValueError(f"unknown method '{method}' (choose {', '.join(METHODS)})")
    return interpolated_fill(sparse, image=image) if method == "interp" else METHODS[method](sparse)
