"""Depth-completion metrics (KITTI / LeoVR / SLIM conventions), overall and per distance bin.

Errors are pooled over all valid pixels of all frames (LeoVR reports the average over all pixels).
Units: metres for MAE/RMSE/p95; 1/km for iMAE/iRMSE (KITTI depth-completion benchmark).
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass, field

import numpy as np

LEOVR_BINS = (0.0, 20.0, 40.0, 60.0, 80.0, float("inf"))
SLIM_BINS = (1.0, 50.0, 100.0, 150.0)


def bin_label(lo: float, hi: float) -> str:
    return f">{lo:g}" if np.isinf(hi) else f"{lo:g}-{hi:g}"


def metrics_from_arrays(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Metrics over matched 1-D arrays of predicted and true depth (metres, all > 0)."""
    n = int(len(gt))
    if n == 0:
        return {"n": 0}
    err = pred - gt
    ae = np.abs(err)
    inv_err = np.abs(1.0 / pred - 1.0 / gt) * 1000.0
    ratio = np.maximum(pred / gt, gt / pred)
    return {
        "n": n,
        "mae_m": float(ae.mean()),
        "rmse_m": float(np.sqrt((err**2).mean())),
        "absrel": float((ae / gt).mean()),
        "imae_per_km": float(inv_err.mean()),
        "irmse_per_km": float(np.sqrt((inv_err**2).mean())),
        "delta1": float((ratio < 1.25).mean()),
        "p95_m": float(np.percentile(ae, 95)),
    }


def depth_metrics(pred: np.ndarray, gt: np.ndarray, bins: Seq[float] = LEOVR_BINS, min_pred: float = 1e-3) -> dict:
    """Metrics of a predicted depth map against ground truth (0 = unknown) with per-bin breakdown.

    Predictions at or below `min_pred` where ground truth exists are clamped to `min_pred` (a
    missing prediction counts as an error, never silently skipped).
    """
    acc = DepthMetricAccumulator(bins)
    acc.add(pred, gt, min_pred)
    return acc.result()


@dataclass
class DepthMetricAccumulator:
    """Collects matched (pred, gt) pairs over frames; `result()` gives overall and per-bin metrics."""

    bins: Seq[float] = LEOVR_BINS
    _pred: list[np.ndarray] = field(default_factory=list)
    _gt: list[np.ndarray] = field(default_factory=list)

    def add(self, pred: np.ndarray, gt: np.ndarray, min_pred: float = 1e-3) -> None:
        if pred.shape != gt.shape:
            raise ValueError(f"prediction shape {pred.shape} differs from ground truth {gt.shape}")
        valid = np.isfinite(gt) & (gt > 0)
        p = np.nan_to_num(pred[valid].astype(np.float64), nan=min_pred, posinf=min_pred, neginf=min_pred)
        self._pred.append(np.maximum(p, min_pred))
        self._gt.append(gt[valid].astype(np.float64))

    @property
    def empty(self) -> bool:
        """Whether no frame was added (a method a run did not score)."""
        return not self._gt

    def result(self) -> dict:
        pred = np.concatenate(self._pred) if self._pred else np.zeros(0)
        gt = np.concatenate(self._gt) if self._gt else np.zeros(0)
        out = metrics_from_arrays(pred, gt)
        edges = list(self.bins)
        out["bins"] = {
            bin_label(lo, hi): metrics_from_arrays(pred[(gt >= lo) & (gt < hi)], gt[(gt >= lo) & (gt < hi)])
            for lo, hi in zip(edges[:-1], edges[1:])
        }
        return out
