"""Camera-only step lengths smoothed over the whole recording (`odometry.step_length`)."""

from __future__ import annotations

import numpy as np
import pytest

from leovr.geometry import invert_T
from odometry.step_length import LengthReading, rescale_steps, smooth_log_lengths


def _braking(n: int = 60) -> np.ndarray:
    """Log step lengths of a car braking gently from 0.25 m to 0.1 m a frame over 6 s (10 Hz)."""
    return np.log(0.1 + 0.15 * 0.5 * (1 + np.cos(np.pi * np.linspace(0, 1, n))))


def test_smoothing_follows_a_braking_car_far_closer_than_its_readings():
    truth = _braking()
    rng = np.random.default_rng(0)
    meas = truth + rng.normal(0, 0.08, truth.size)  # the road's reading: about 8 % a frame
    est = smooth_log_lengths([LengthReading(float(m), 0.08) for m in meas])
    err_raw = np.sqrt(np.mean((meas - truth) ** 2))
    err = np.sqrt(np.mean((est - truth) ** 2))
    print(err_raw, err)
    assert err < 0.6 * err_raw
    # a prior of near-constant speed (0.5 mm a frame) cannot follow the braking: the car's 0.5 m/s^2 is what does
    flat = smooth_log_lengths([LengthReading(float(m), 0.08) for m in meas], change_sigma_m=0.0005)
    assert err < 0.5 * np.sqrt(np.mean((flat - truth) ** 2))


def test_a_restart_or_a_step_without_the_filter_breaks_the_chain():
    # the car stands between frame 19 and 20 and sets off at a third of its speed: no smoothing across
    truth = np.r_[np.full(20, np.log(0.3)), np.full(20, np.log(0.1))]
    readings: list[LengthReading | None] = [LengthReading(float(x), 0.05) for x in truth]
    readings[20] = LengthReading(float(truth[20]), 0.05, restart=True)
    est = smooth_log_lengths(readings)
    assert np.abs(est - truth).max() < 1e-6
    joined = smooth_log_lengths([LengthReading(float(x), 0.05) for x in truth])
    assert np.abs(joined - truth).max() > 0.1  # without the break the jump is smeared
    readings[20] = None  # a standing step: no length, and the chain breaks there too
    est = smooth_log_lengths(readings)
    assert np.isnan(est[20]) and np.abs(np.delete(est, 20) - np.delete(truth, 20)).max() < 1e-6


def test_a_step_in_the_chain_without_a_reading_is_bridged():
    truth = np.log(np.linspace(0.2, 0.3, 30))
    readings = [LengthReading(float(x), 0.02) for x in truth]
    readings[10] = LengthReading(None)
    est = smooth_log_lengths(readings)
    assert est[10] == pytest.approx(truth[10], abs=0.005)


def _pose(yaw: float, t) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = t
    return T


def test_rescaled_steps_keep_rotation_and_direction():
    poses = np.stack([_pose(0.0, [0, 0, 0]), _pose(0.1, [0.1, 0, 1.0]), _pose(0.25, [0.3, 0.02, 2.1])])
    out = rescale_steps(poses, np.array([2.0, np.nan]))
    for k in (1, 2):
        a, b = invert_T(poses[k - 1]) @ poses[k], invert_T(out[k - 1]) @ out[k]
        assert np.allclose(a[:3, :3], b[:3, :3])
        assert np.allclose(a[:3, 3] / np.linalg.norm(a[:3, 3]), b[:3, 3] / np.linalg.norm(b[:3, 3]))
    assert np.linalg.norm(out[1][:3, 3]) == pytest.approx(2.0)
    # NaN keeps the step's length
    assert np.linalg.norm((invert_T(out[1]) @ out[2])[:3, 3]) == pytest.approx(
        np.linalg.norm((invert_T(poses[1]) @ poses[2])[:3, 3]))


def test_a_broken_reading_is_ignored_and_a_chain_without_any_keeps_its_steps():
    truth = np.log(np.full(10, 0.5))
    readings = [LengthReading(float(x), 0.05) for x in truth]
    readings[4] = LengthReading(float("nan"), 0.05)
    assert np.abs(smooth_log_lengths(readings) - truth).max() < 1e-6
    assert np.isnan(smooth_log_lengths([LengthReading(None)] * 5)).all()
