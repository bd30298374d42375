"""Trajectory metrics (ATE, RPE) through evo, with SE(3) or Sim(3) alignment."""

from __future__ import annotations

import numpy as np
from evo.core import metrics
from evo.core.trajectory import PosePath3D


def _path(poses: np.ndarray) -> PosePath3D:
    return PosePath3D(poses_se3=[np.array(T, float) for T in poses])


def trajectory_metrics(
    estimate: np.ndarray, reference: np.ndarray, align: str = "se3", rpe_delta: int = 1
) -> dict[str, float]:
    """ATE (RMSE of translation after alignment) and RPE (translation, `rpe_delta` frames apart).

    `estimate` and `reference` are F x 4 x 4 camera-to-world poses of the same frames. `align` is
    'se3' (rigid), 'sim3' (rigid + scale, for monocular estimates) or 'none'. The ATE is also split along
    the reference camera's axes (`ate_lateral_m`: x, right; `ate_vertical_m`: y, down; `ate_forward_m`: z,
    the view direction): where the error lies, e.g. a step length wrong (forward) or a heading drift (lateral).
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
    }
