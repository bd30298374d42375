"""Directions of travel from a rigid vehicle model (odometry/vehicle_motion.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from odometry.vehicle_motion import VehicleModel, fit_vehicle, redirect_steps

# camera axes (x right, y down, z forward) in the vehicle frame (x forward, y left, z up)
R_VC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
P_CAM = np.array([1.5, 0.3, 1.6])  # the camera 1.5 m ahead of the rear axle, 0.3 m left, 1.6 m up


def _drive(n: int = 120, turning: bool = True) -> np.ndarray:
    """Camera-to-world poses of a car whose rear axle drives arcs of 1 m a frame, turning up to 6 degrees a frame."""
    T_vc = np.eye(4)
    T_vc[:3, :3], T_vc[:3, 3] = R_VC, P_CAM
    yaw_rate = np.radians(6.0) * np.sin(np.linspace(0, 3 * np.pi, n)) if turning else np.zeros(n)
    V, out = np.eye(4), []
    for k in range(n):
        out.append(V @ T_vc)
        th = yaw_rate[k]
        chord = 2.0 * np.sin(th / 2) / th if abs(th) > 1e-9 else 1.0
        step = np.eye(4)
        step[:3, :3] = Rotation.from_euler("z", th).as_matrix()
        step[:3, 3] = chord * np.array([np.cos(th / 2), np.sin(th / 2), 0.0])
        V = V @ step
    return np.stack(out)


def _noisy_directions(poses: np.ndarray, deg: float, seed: int = 0, vertical_deg: float = 0.0) -> np.ndarray:
    """The same rotations and lengths, each step's direction of travel turned sideways by about `deg` degrees
    (about the camera's y axis) and up or down by about `vertical_deg`."""
    rng = np.random.default_rng(seed)
    out = [poses[0]]
    for a, b in zip(poses[:-1], poses[1:]):
        s = invert_T(a) @ b
        turn = np.radians([vertical_deg, deg, 0.0]) * rng.standard_normal(3)
        s[:3, 3] = Rotation.from_rotvec(turn).as_matrix() @ s[:3, 3]
        out.append(out[-1] @ s)
    return np.stack(out)


def _error(poses: np.ndarray, truth: np.ndarray) -> float:
    """ATE after SE(3) alignment, as the product scores trajectories (a constant heading offset of every step, all
    that the noise leaves in the fitted forward axis, turns the whole planar track and aligns away)."""
    return trajectory_metrics(poses, truth, "se3")["ate_m"]


def _steps(poses: np.ndarray) -> np.ndarray:
    return invert_T(poses[:-1]) @ poses[1:]


def test_a_turning_car_gets_its_directions_back_with_the_camera_offset():
    truth = _drive()
    noisy = _noisy_directions(truth, 1.0)
    model = fit_vehicle(_steps(noisy))
    assert model is not None
    m_true = -R_VC.T @ P_CAM  # the rear axle in camera coordinates
    assert abs(model.forward @ np.array([0.0, 0.0, 1.0])) > 0.999
    # the offset along the car, which swings the camera sideways in a turn (the sideways offset only changes a
    # step's length, to first order, and the lengths are the measured ones)
    assert abs(model.offset[2] - m_true[2]) < 0.15
    assert model.up @ np.array([0.0, -1.0, 0.0]) > 0.999
    fixed = redirect_steps(noisy, model)
    assert _error(fixed, truth) < 0.3 * _error(noisy, truth)
    # rotations and lengths stay as they were
    for s0, s1 in zip(_steps(noisy), _steps(fixed)):
        assert np.allclose(s0[:3, :3], s1[:3, :3])
        assert np.isclose(np.linalg.norm(s0[:3, 3]), np.linalg.norm(s1[:3, 3]))
    # the camera is not over the axle: the same model without the offset (session 51's) is far worse
    axle = redirect_steps(noisy, VehicleModel(model.forward, np.zeros(3), model.up, model.steps_used))
    assert _error(axle, truth) > 3 * _error(fixed, truth)


def test_a_straight_drive_keeps_its_pitch_and_loses_its_sideways_noise():
    truth = _drive(turning=False)
    noisy = _noisy_directions(truth, 1.0, seed=1, vertical_deg=0.5)
    model = fit_vehicle(_steps(noisy))
    fixed = redirect_steps(noisy, model)
    assert np.abs(model.offset).max() < 0.5  # nothing observes it: the prior keeps it small
    side = np.array([1.0, 0.0, 0.0])  # camera x: across the car
    err_noisy = np.abs(np.array([s[:3, 3] @ side for s in _steps(noisy)]))
    err_fixed = np.abs(np.array([s[:3, 3] @ side for s in _steps(fixed)]))
    assert err_fixed.mean() < 0.2 * err_noisy.mean()
    up = np.array([0.0, -1.0, 0.0])
    assert np.allclose([s[:3, 3] @ up for s in _steps(fixed)], [s[:3, 3] @ up for s in _steps(noisy)], atol=1e-3)


def test_too_few_moving_steps_give_no_model():
    truth = _drive(4)
    assert fit_vehicle(_steps(truth)) is None
    standing = np.tile(np.eye(4), (10, 1, 1))
    assert fit_vehicle(_steps(standing)) is None
