"""The step-length ratio to the ground truth along a drive, one line per trajectory: where a trajectory's
scale drifts (steps too short or too long) shows as a line leaving 1, long before it dominates the ATE."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.data.io import atomic_write
from leovr.eval.trajectory import step_ratios


def plot_step_ratios(tracks: dict[str, np.ndarray], reference: np.ndarray, path: Path, smooth: int = 5) -> None:
    """`tracks`: name -> F x 4 x 4 poses of the frames of `reference` (camera to world, each at the scale
    it is scored at); each step's length over the reference's, as a running median of `smooth` steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.ndimage import median_filter

    fig, ax = plt.subplots(figsize=(8, 3.4))
    styles = {
        "leovr": ("tab:orange", "-"),
        "kiss_icp": ("tab:blue", "--"),
        "kiss_icp_no_deskew": ("tab:cyan", ":"),
        "mono_vo": ("tab:green", "-."),
        "leovr_no_loop": ("tab:red", ":"),
    }
    for name, poses in tracks.items():
        r = step_ratios(poses, reference)
        filled = np.where(np.isfinite(r), r, 1.0)
        c, ls = styles.get(name, ("gray", ":"))
        ax.plot(
            np.arange(1, len(poses)),
            np.where(np.isfinite(r), median_filter(filled, smooth, mode="nearest"), np.nan),
            color=c,
            linestyle=ls,
            label=name,
        )
    ax.axhline(1.0, color="k", linewidth=0.8)
    ax.set_xlabel("frame")
    ax.set_ylabel("step length / true step")
    ax.set_title(f"Step length against the ground truth (running median of {smooth} steps)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)
