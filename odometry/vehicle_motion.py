"""Camera-only directions of travel from a rigid vehicle's motion, fitted over the whole recording.

A car's reference point (the rear axle's centre) moves along the chord of its arc, at half the step's rotation
from the car's forward axis; a camera mounted at an offset m from that point moves by

    t_k = s_k Rhalf_k f + (I - R_k) m        (camera frame; f the car's forward axis, R_k the step's rotation,
                                              Rhalf_k its half, s_k the step's length)

so with f and m fitted once, each step's direction of travel follows from its rotation, which the essential
matrix gives far better than the direction itself (the epipole of forward motion is poorly conditioned: on the
development drives the direction is off by about 1 degree a step, and with the reference's directions the
trajectory error falls 1.5-4x). Only the component across the car's up axis is taken from the model; the one
along it stays measured, because the body pitches on its suspension and the road's slope changes, which a rigid
model does not see. Session 51 tried m = 0 (the camera over the axle): the city loop lost 5x.

Off by default (`refine.mono_vehicle_directions`): better or level on all six development clips, but on the real
KITTI odometry clip the ATE rose 0.059 -> 0.068 m while the RPE fell (docs/benchmarks.md, session 56)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from leovr.geometry import invert_T


@dataclass(frozen=True)
class VehicleModel:
    """The car's forward axis `f` and up axis `up` (unit, camera frame) and the camera's offset `m` (metres,
    camera frame, from the reference point; only its part across the rotation axes is observable)."""

    forward: np.ndarray
    offset: np.ndarray
    up: np.ndarray
    steps_used: int


def _half(R: np.ndarray) -> np.ndarray:
    """Half of each rotation of a stack (N x 3 x 3)."""
    return Rotation.from_rotvec(0.5 * Rotation.from_matrix(R).as_rotvec()).as_matrix()


def vehicle_directions(poses: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (F x 4 x 4) with each step's direction across the car's up axis from the vehicle
    model fitted to their own steps; the poses as they are where too few steps move (`fit_vehicle`)."""
    steps = invert_T(poses[:-1]) @ poses[1:]
    model = fit_vehicle(steps)
    return poses if model is None else _redirect(poses[0], steps, model)


def fit_vehicle(steps: np.ndarray, min_step_m: float = 0.05, huber_m: float = 0.02, offset_sigma_m: float = 2.0,
                iterations: int = 5) -> VehicleModel | None:
    """Fit f and m to the steps (F x 4 x 4, camera motion from one frame to the next, metric) by least squares on
    the translations with Huber weights (`huber_m` metres), m held near 0 by a weak prior (`offset_sigma_m` metres
    against the translations' `huber_m`) where the recording does not turn; steps shorter than `min_step_m` are
    left out. Each pass takes the reference point's step lengths s_k from the last pass's f and m so that the
    model's step is as long as the camera's. None with fewer than 5 such steps."""
    L = np.linalg.norm(steps[:, :3, 3], axis=1)
    use = np.nonzero(L > min_step_m)[0]
    if len(use) < 5:
        return None
    R = steps[use, :3, :3]
    half = _half(R)
    b = steps[use, :3, 3].reshape(-1)
    prior = np.hstack([np.zeros((3, 3)), np.eye(3) * huber_m / offset_sigma_m])
    s, w = L[use], np.ones(len(b))
    for _ in range(iterations):
        A = np.concatenate([s[:, None, None] * half, np.eye(3) - R], axis=2).reshape(-1, 6)
        sw = np.sqrt(w)
        x = np.linalg.lstsq(np.vstack([A * sw[:, None], prior]), np.r_[b * sw, np.zeros(3)], rcond=None)[0]
        r = np.abs(A @ x - b)
        w = np.where(r < huber_m, 1.0, huber_m / np.maximum(r, 1e-12))
        f = x[:3] / np.linalg.norm(x[:3])
        s = _axle_lengths(half @ f, np.eye(3)[None] - R, x[3:], L[use])
    return VehicleModel(f, x[3:], _up_axis(R, f), len(use))


def _axle_lengths(a: np.ndarray, I_minus_R: np.ndarray, m: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The reference point's step lengths s_k with |s_k a_k + (I - R_k) m| = L_k (a_k unit)."""
    c = I_minus_R @ m
    ac = np.einsum("ni,ni->n", a, c)
    return np.maximum(-ac + np.sqrt(np.maximum(ac**2 - np.einsum("ni,ni->n", c, c) + L**2, 0.0)), 0.0)


def _up_axis(R: np.ndarray, f: np.ndarray, min_turn_deg: float = 0.5) -> np.ndarray:
    """The car's up axis: the summed rotation axes of the turning steps (sign: towards the camera's -y, image
    up), made orthogonal to f; the camera's -y where the recording does not turn."""
    rv = Rotation.from_matrix(R).as_rotvec()
    rv = rv[np.linalg.norm(rv, axis=1) > np.radians(min_turn_deg)]
    rv = rv * np.where(rv[:, 1] <= 0, 1.0, -1.0)[:, None]
    u = rv.sum(0) if len(rv) >= 3 else np.array([0.0, -1.0, 0.0])
    u = u - (u @ f) * f
    return u / np.linalg.norm(u)


def redirect_steps(poses: np.ndarray, model: VehicleModel) -> np.ndarray:
    """Camera-to-world poses (F x 4 x 4) whose steps keep their rotation, length and the component of their
    direction along the car's up axis, and take the component across it from the vehicle model."""
    return _redirect(poses[0], invert_T(poses[:-1]) @ poses[1:], model)


def _redirect(first: np.ndarray, steps: np.ndarray, model: VehicleModel) -> np.ndarray:
    """The poses chained from `first` through `steps` (F-1 x 4 x 4), each step redirected as `redirect_steps` says."""
    steps = steps.copy()
    L = np.linalg.norm(steps[:, :3, 3], axis=1)
    a = _half(steps[:, :3, :3]) @ model.forward
    I_minus_R = np.eye(3)[None] - steps[:, :3, :3]
    t_model = _axle_lengths(a, I_minus_R, model.offset, L)[:, None] * a + I_minus_R @ model.offset
    u = model.up
    d = steps[:, :3, 3] / np.maximum(L, 1e-12)[:, None]
    dm = t_model / np.maximum(np.linalg.norm(t_model, axis=1), 1e-12)[:, None]
    v = dm - np.outer(dm @ u, u) + np.outer(d @ u, u)
    v /= np.maximum(np.linalg.norm(v, axis=1), 1e-12)[:, None]
    moving = L > 1e-9
    steps[moving, :3, 3] = L[moving, None] * v[moving]
    out = [first]
    for s in steps:
        out.append(out[-1] @ s)
    return np.stack(out)
