"""OXTS reference poses: GPS fixes smoothed with the unit's velocities by their stated accuracies."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import KITTI_RAW_POSES, needs_posed_drive

from leovr.data.oxts import smoothed_positions


def test_smoothed_positions_follow_the_velocities_where_the_fixes_wander():
    """A car at 12 m/s for 10 s; the fixes swing +-0.5 m sideways over seconds (as a differential fix does),
    the velocities hold to 3 cm/s. The smoothed track stays within a few cm of the truth, the fixes do not."""
    rng = np.random.default_rng(0)
    t = np.arange(100) * 0.1
    truth = np.stack([12.0 * t, 0.02 * t**2, np.zeros_like(t)], 1)
    velocity = np.stack([np.full_like(t, 12.0), 0.04 * t, np.zeros_like(t)], 1) + rng.normal(0, 0.03, (100, 3))
    fixes = truth + np.stack([0.05 * np.sin(t), 0.5 * np.sin(2 * np.pi * t / 8), np.zeros_like(t)], 1)
    fixes += rng.normal(0, 0.05, fixes.shape)
    track = smoothed_positions(fixes, velocity, t, np.full(100, 0.2), np.full(100, 0.03))

    def err(p: np.ndarray) -> float:  # RMS after taking out the mean offset
        return float(np.sqrt((((p - p.mean(0)) - (truth - truth.mean(0))) ** 2).sum(1).mean()))

    assert err(fixes) > 0.3 and err(track) < 0.3 * err(fixes)


def test_smoothed_positions_stay_on_the_fixes_when_the_velocities_are_biased():
    """Over a long drive a velocity bias would make the integrated track drift without bound: the fixes hold the
    smoothed one to their accuracy."""
    t = np.arange(3000) * 0.1  # five minutes
    truth = np.stack([12.0 * t, np.zeros_like(t), np.zeros_like(t)], 1)
    velocity = np.stack([np.full_like(t, 12.05), np.zeros_like(t), np.zeros_like(t)], 1)  # 15 m over the drive
    track = smoothed_positions(truth, velocity, t, np.full(3000, 0.2), np.full(3000, 0.03))
    assert np.abs(track - truth).max() < 1.0


@pytest.mark.slow
@needs_posed_drive
def test_kitti_raw_reference_agrees_with_the_lidar_where_the_gps_fixes_do_not():
    """On drive 0013 the GPS fixes alone (differential mode, 0.15-0.21 m stated) swing sideways against the
    unit's own velocities; KISS-ICP on the LiDAR, which shares nothing with the GPS/IMU, follows the smoothed
    reference: its ATE against it is well under half its ATE against the fixes."""
    from leovr.config import CompleteConfig
    from leovr.data import open_sequence
    from leovr.eval.trajectory import trajectory_metrics
    from leovr.pipeline.kiss_baseline import kiss_icp_trajectory

    seq = open_sequence(KITTI_RAW_POSES)
    ref = np.stack([seq.pose(i) for i in range(len(seq))])
    assert 0.1 < trajectory_metrics(ref, seq.gps_poses)["ate_m"] < 0.6  # they differ, within the fixes' accuracy
    est = kiss_icp_trajectory(seq, list(range(len(seq))), CompleteConfig(input="vlp16"), deskew=False)
    assert trajectory_metrics(est, ref)["ate_m"] < 0.5 * trajectory_metrics(est, seq.gps_poses)["ate_m"]
