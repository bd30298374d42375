"""Trajectory metrics: ATE and RPE through evo, with SE(3) or Sim(3) alignment, and KITTI's relative errors
(translation % and rotation deg / m over segments of 25, 50 and 100 m, as the KITTI odometry devkit computes them)."""

from __future__ import annotations

import numpy as np
from evo.core import metrics
from evo.core.trajectory import PosePath3D


def _path(poses: np.ndarray) -> PosePath3D:
    return PosePath3D(poses_se3=[np.array(T, float) for T in poses])


KITTI_LENGTHS_M = (25.0, 50.0, 100.0)  # segment lengths: KITTI's 100-800 m do not fit a 100 m clip
KITTI_STEP_FRAMES = 10  # the devkit's spacing of segment starts
STRETCH_FRAMES = 32  # the ATE of each stretch of this many frames too, each aligned alone: where drift builds up


def kitti_relative_errors(
    estimate: np.ndarray,
    reference: np.ndarray,
    lengths: tuple[float, ...] = KITTI_LENGTHS_M,
    step: int = KITTI_STEP_FRAMES,
) -> dict:
    """KITTI odometry's drift measure (devkit `evaluate_odometry.cpp`): from every `step`-th frame, the segment
    to the first frame whose distance along the reference path exceeds each length; the error of the estimated
    relative pose over the segment, translation (% of the length) and rotation (deg / m), averaged over every
    segment of every length that fits. Per length too (`segments`); None where no segment of that length fits.
    Alignment does not change it (relative poses)."""
    dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(reference[:, :3, 3], axis=0), axis=1))]
    t_err, r_err, per = [], [], {}
    for length in lengths:
        t_len, r_len = [], []
        for first in range(0, len(reference), step):
            last = int(np.searchsorted(dist, dist[first] + length, side="right"))
            if last >= len(reference):
                break
            d_ref = np.linalg.inv(reference[first]) @ reference[last]
            d_est = np.linalg.inv(estimate[first]) @ estimate[last]
            err = np.linalg.inv(d_est) @ d_ref
            cos = np.clip((np.trace(err[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
            t_len.append(float(np.linalg.norm(err[:3, 3])) / length)
            r_len.append(float(np.degrees(np.arccos(cos))) / length)
        per[f"{length:g}"] = (
            {
                "t_err_pct": 100.0 * float(np.mean(t_len)),
                "r_err_deg_per_m": float(np.mean(r_len)),
                "segments": len(t_len),
            }
            if t_len
            else None
        )
        t_err += t_len
        r_err += r_len
    return {
        "kitti_t_err_pct": 100.0 * float(np.mean(t_err)) if t_err else None,
        "kitti_r_err_deg_per_m": float(np.mean(r_err)) if r_err else None,
        "kitti_segments": per,
    }


def trajectory_metrics(estimate: np.ndarray, reference: np.ndarray, align: str = "se3", rpe_delta: int = 1) -> dict:
    """ATE (RMSE of translation after alignment) and RPE (translation, `rpe_delta` frames apart).

    `estimate` and `reference` are F x 4 x 4 camera-to-world poses of the same frames. `align` is
    'se3' (rigid), 'sim3' (rigid + scale, for monocular estimates) or 'none'. The ATE is also split along
    the reference camera's axes (`ate_lateral_m`: x, right; `ate_vertical_m`: y, down; `ate_forward_m`: z,
    the view direction): where the error lies, e.g. a step length wrong (forward) or a heading drift (lateral).
    KITTI's relative errors (`kitti_relative_errors`) are computed after the alignment's scale (Sim(3));
    `ate_per_stretch_m`: the ATE of frames 0-31, 32-63, ... each aligned alone (a last stretch of fewer than half
    as many frames joins the one before). `step_ratio_median`: the median of the estimated step lengths over the
    reference's (after the scale), steps under 5 cm left out.
    """
    if estimate.shape != reference.shape or estimate.ndim != 3 or estimate.shape[1:] != (4, 4):
        raise ValueError(f"estimate {estimate.shape} and reference {reference.shape} must both be F x 4 x 4")
    if len(estimate) < 2:
        raise ValueError("need at least two poses")
    if align not in ("se3", "sim3", "none"):
        raise ValueError(f"align must be se3, sim3 or none, not {align}")
    ref, est = _path(reference), _path(estimate)
    scale = 1.0
    if align != "none" and len(estimate) >= 3:
        _, _, scale = est.align(ref, correct_scale=align == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(
        metrics.PoseRelation.translation_part, delta=rpe_delta, delta_unit=metrics.Unit.frames, all_pairs=False
    )
    rpe.process_data((ref, est))
    scaled = np.array(estimate, float)
    scaled[:, :3, 3] *= scale
    # the aligned error of each frame in its reference camera's axes
    err = np.einsum("fji,fj->fi", reference[:, :3, :3], est.positions_xyz - ref.positions_xyz)
    axes = np.sqrt(np.mean(err**2, axis=0))
    return {
        "ate_m": float(ape.get_statistic(metrics.StatisticsType.rmse)),
        "ate_lateral_m": float(axes[0]),
        "ate_vertical_m": float(axes[1]),
        "ate_forward_m": float(axes[2]),
        "ate_mean_m": float(ape.get_statistic(metrics.StatisticsType.mean)),
        "ate_max_m": float(ape.get_statistic(metrics.StatisticsType.max)),
        "rpe_m": float(rpe.get_statistic(metrics.StatisticsType.rmse)),
        "scale": float(scale),
        "align": align,
        "frames": int(len(estimate)),
        "ate_per_stretch_m": stretch_ates(estimate, reference, align),
        "step_ratio_median": float(np.nanmedian(step_ratios(scaled, reference))),
    } | kitti_relative_errors(scaled, reference)


def stretch_ates(estimate: np.ndarray, reference: np.ndarray, align: str, frames: int = STRETCH_FRAMES) -> list[float]:
    """The ATE of each stretch of `frames` frames, each aligned alone; a short last stretch joins the one before."""
    starts = list(range(0, len(estimate), frames))
    if len(starts) > 1 and len(estimate) - starts[-1] < frames // 2:
        starts.pop()
    ends = starts[1:] + [len(estimate)]
    if len(starts) < 2:
        return []
    return [_ate(estimate[a:b], reference[a:b], align) for a, b in zip(starts, ends)]


def step_ratios(estimate: np.ndarray, reference: np.ndarray, min_step_m: float = 0.05) -> np.ndarray:
    """Each step's length over the reference's (NaN where the reference moved under `min_step_m`)."""
    ref = np.linalg.norm(np.diff(reference[:, :3, 3], axis=0), axis=1)
    est = np.linalg.norm(np.diff(estimate[:, :3, 3], axis=0), axis=1)
    return np.where(ref >= min_step_m, est / np.maximum(ref, 1e-9), np.nan)


def _ate(estimate: np.ndarray, reference: np.ndarray, align: str) -> float:
    """The ATE alone (m, RMSE after alignment)."""
    ref, est = _path(reference), _path(estimate)
    if align != "none" and len(estimate) >= 3:
        est.align(ref, correct_scale=align == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))
