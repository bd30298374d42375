"""Session 56 (issue 16): how much rotation error the vehicle model of `odometry/vehicle_motion.py` stands. The
synthetic car of tests/test_vehicle_motion.py (camera 1.5 m ahead of the rear axle, turns up to 6 degrees a
frame, 120 frames): each step's direction turned sideways by 1 degree (as the development clips measure) and its
rotation by `sigma` degrees about a random axis; SE(3) ATE (m) of the measured track and of the model's, mean of
10 seeds.

    .venv/bin/python docs/dev/session56/rotation_noise.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tests"))
from test_vehicle_motion import _drive, _error, _steps  # noqa: E402

from odometry.vehicle_motion import fit_vehicle, redirect_steps  # noqa: E402


def noisy(truth: np.ndarray, dir_deg: float, rot_deg: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = [truth[0]]
    for s in _steps(truth):
        s = s.copy()
        s[:3, 3] = Rotation.from_rotvec(np.radians([0.0, dir_deg, 0.0]) * rng.standard_normal(3)).as_matrix() @ s[:3, 3]
        s[:3, :3] = Rotation.from_rotvec(np.radians(rot_deg) * rng.standard_normal(3)).as_matrix() @ s[:3, :3]
        out.append(out[-1] @ s)
    return np.stack(out)


def main() -> None:
    truth = _drive()
    print("rotation sigma (deg) | measured ATE | model ATE | model / measured")
    for sig in (0.0, 0.02, 0.05, 0.1, 0.2, 0.4):
        m, v = [], []
        for seed in range(10):
            n = noisy(truth, 1.0, sig, seed)
            model = fit_vehicle(_steps(n))
            m.append(_error(n, truth))
            v.append(_error(redirect_steps(n, model), truth))
        print(f"{sig} | {np.mean(m):.3f} | {np.mean(v):.3f} | {np.mean(v) / np.mean(m):.2f}")


if __name__ == "__main__":
    main()
