"""Depth and trajectory metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from leovr.eval.depth_metrics import depth_metrics
from leovr.eval.heldout import parallax_filter
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import make_T


def test_depth_metrics_hand_computed():
    pred = np.array([[1.0, 2.0, 4.0, 10.0, 7.0]])
    gt = np.array([[1.0, 2.5, 5.0, 8.0, 0.0]])  # last pixel has no ground truth
    m = depth_metrics(pred, gt)
    # errors 0, -0.5, -1, 2
    assert m["n"] == 4
    assert m["mae_m"] == pytest.approx(0.875)
    assert m["rmse_m"] == pytest.approx(np.sqrt(5.25 / 4))
    assert m["absrel"] == pytest.approx((0 + 0.2 + 0.2 + 0.25) / 4)
    assert m["imae_per_km"] == pytest.approx(1000 * (0 + 0.1 + 0.05 + 0.025) / 4)
    assert m["irmse_per_km"] == pytest.approx(1000 * np.sqrt((0.01 + 0.0025 + 0.000625) / 4))
    assert m["delta1"] == pytest.approx(0.25)  # ratios 1, 1.25, 1.25, 1.25: strictly below 1.25
    assert m["p95_m"] == pytest.approx(1.85)
    assert m["bins"]["0-20"]["n"] == 4 and m["bins"][">80"] == {"n": 0}


def test_depth_metric_bins_split_by_true_depth():
    gt = np.array([5.0, 25.0, 45.0, 65.0, 85.0, 120.0])
    pred = gt + np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    m = depth_metrics(pred, gt)
    assert [m["bins"][b]["mae_m"] for b in ("0-20", "20-40", "40-60", "60-80")] == [1, 2, 3, 4]
    assert m["bins"][">80"]["mae_m"] == pytest.approx(5.5)
    slim = depth_metrics(pred, gt, bins=(1, 50, 100, 150))
    assert list(slim["bins"]) == ["1-50", "50-100", "100-150"]
    assert slim["bins"]["1-50"]["mae_m"] == pytest.approx(2.0) and slim["bins"]["100-150"]["n"] == 1


def test_missing_prediction_is_an_error_not_skipped():
    m = depth_metrics(np.array([0.0, 10.0]), np.array([10.0, 10.0]))
    assert m["n"] == 2 and m["mae_m"] == pytest.approx((10 - 1e-3) / 2)


def test_parallax_filter_drops_points_hidden_behind_nearer_returns():
    held = np.zeros((20, 20), np.float32)
    held[10, 10] = 30.0  # background seen past an edge
    held[2, 2] = 30.0  # far from the edge: kept
    allr = held.copy()
    allr[10, 13] = 10.0  # a near return 3 px away
    allr[2, 5] = 28.0  # nearer, but by less than 15%
    out = parallax_filter(held, allr)
    assert out[10, 10] == 0 and out[2, 2] == 30.0


def _line(n: int = 20) -> np.ndarray:
    return np.stack([make_T(t=[i * 1.0, 0.1 * i**1.5, 0.05 * i]) for i in range(n)])


def test_ate_alignment_modes():
    ref = _line()
    shifted = ref.copy()
    shifted[:, :3, 3] += [0.0, 1.0, 0.0]
    assert trajectory_metrics(shifted, ref, "none")["ate_m"] == pytest.approx(1.0)
    assert trajectory_metrics(shifted, ref, "se3")["ate_m"] == pytest.approx(0.0, abs=1e-9)
    assert trajectory_metrics(shifted, ref, "none")["rpe_m"] == pytest.approx(0.0, abs=1e-9)
    scaled = ref.copy()
    scaled[:, :3, 3] *= 0.5
    assert trajectory_metrics(scaled, ref, "se3")["ate_m"] > 1.0
    sim = trajectory_metrics(scaled, ref, "sim3")
    assert sim["ate_m"] == pytest.approx(0.0, abs=1e-9) and sim["scale"] == pytest.approx(2.0)
    assert np.allclose(scaled[:, :3, 3], ref[:, :3, 3] * 0.5)  # inputs untouched


def test_ate_split_along_the_reference_cameras_axes():
    """A camera driving forward (its z) with a lateral wobble in its x: the ATE lies in the lateral part;
    the same wobble in a camera turned 90 degrees about y shows in that camera's own x."""
    n = 30
    wobble = 0.1 * np.sin(np.linspace(0, 4 * np.pi, n))
    for yaw in (0.0, np.pi / 2):
        R = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        ref = np.stack([make_T(R, R @ [0, 0, 1.0 * i]) for i in range(n)])
        est = np.stack([make_T(R, R @ [wobble[i], 0, 1.0 * i]) for i in range(n)])
        m = trajectory_metrics(est, ref, "none")
        assert m["ate_lateral_m"] == pytest.approx(m["ate_m"]) and m["ate_lateral_m"] > 0.05
        assert m["ate_vertical_m"] == pytest.approx(0.0, abs=1e-12) and m["ate_forward_m"] == pytest.approx(
            0.0, abs=1e-12
        )


def test_trajectory_metrics_reject_bad_shapes():
    with pytest.raises(ValueError):
        trajectory_metrics(_line(5), _line(6))


def test_kitti_relative_errors_as_the_devkit_computes_them():
    """120 frames 1 m apart on a straight line. Steps 2 % long: KITTI's translation error 2 % of each segment, over
    every length that fits (25 and 50 m from every 10th frame, 100 m from frames 0 and 10), divided as in the devkit
    by the nominal length of a segment that ends at the first frame past it (26 m for 25); a heading that
    turns 0.01 deg per frame against the straight truth: 0.01 deg/m. Stretch ATEs (32 frames each, the last 24
    join none: 120 = 3 x 32 + 24) and the median step ratio say where the error lies."""
    n = 120
    ref = np.stack([make_T(np.eye(3), [0, 0, 1.0 * i]) for i in range(n)])
    long = ref.copy()
    long[:, :3, 3] *= 1.02
    m = trajectory_metrics(long, ref, "none")
    seg = m["kitti_segments"]
    assert seg["25"]["segments"] == 10 and seg["50"]["segments"] == 7 and seg["100"]["segments"] == 2
    for length in (25, 50, 100):
        assert seg[str(length)]["t_err_pct"] == pytest.approx(2.0 * (length + 1) / length)
    assert m["kitti_t_err_pct"] == pytest.approx((10 * 2.08 + 7 * 2.04 + 2 * 2.02) / 19)
    assert m["kitti_r_err_deg_per_m"] == pytest.approx(0.0)
    assert m["step_ratio_median"] == pytest.approx(1.02)
    assert len(m["ate_per_stretch_m"]) == 4
    curved = _line(60)
    half = curved.copy()
    half[:, :3, 3] *= 0.5
    assert trajectory_metrics(half, curved, "none")["kitti_t_err_pct"] == pytest.approx(50.0, rel=0.05)
    # scale taken out
    assert trajectory_metrics(half, curved, "sim3")["kitti_t_err_pct"] == pytest.approx(0.0, abs=1e-6)
    a = np.radians(0.01) * np.arange(n)
    turning = np.stack(
        [
            make_T(np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]]), [0, 0, 1.0 * i])
            for i, t in enumerate(a)
        ]
    )
    assert trajectory_metrics(turning, ref, "none")["kitti_r_err_deg_per_m"] == pytest.approx(0.01, rel=0.05)
    assert trajectory_metrics(_line(20), _line(20), "none")["kitti_t_err_pct"] is None  # no 25 m segment fits
