"""The road plane as the camera-only scale source (`odometry.ground_plane`) and its use in the
epipolar motion (`odometry.mono_motion`)."""

from __future__ import annotations

import numpy as np
import pytest

from odometry.ground_plane import fit_ground, height_mode, road_corners

K = np.array([[260.0, 0, 224], [0, 260.0, 128], [0, 0, 1]])


def _road(rng, n: int, height: float, noise: float = 0.01, far: float = 25.0) -> np.ndarray:
    """Points on a road `height` below a level camera (y down), 3 to `far` units ahead, +-4 sideways."""
    z = rng.uniform(3, far, n)
    return np.c_[rng.uniform(-4, 4, n), height * (1 + noise * rng.standard_normal(n)), z]


def test_road_height_among_clutter():
    rng = np.random.default_rng(0)
    road = _road(rng, 120, 1.3)
    car = np.c_[rng.uniform(-1, 1, 60), rng.uniform(0.5, 0.9, 60), rng.uniform(5, 8, 60)]  # a car's back
    sky = np.c_[rng.uniform(-10, 10, 40), rng.uniform(-6, -1, 40), rng.uniform(5, 40, 40)]  # above the camera
    fit = fit_ground(np.r_[road, car, sky, [[np.nan, 1, 5]]])
    assert fit is not None and fit.height == pytest.approx(1.3, rel=0.02)
    assert fit.normal @ [0, 1, 0] > np.cos(np.radians(2)) and fit.inliers >= 50


def test_the_lowest_surface_is_the_road():
    """A car body with more corners than the road in view: the road is still the plane further down
    (the nearer 60 % of the points are read, so the road is kept as near as the car)."""
    rng = np.random.default_rng(1)
    road = _road(rng, 40, 1.6, far=9.0)
    body = np.c_[rng.uniform(-1, 1, 70), 1.0 + 0.01 * rng.standard_normal(70), rng.uniform(4, 9, 70)]
    assert height_mode(np.r_[road, body][:, 1], 0.05) == pytest.approx(1.6, rel=0.05)
    assert fit_ground(np.r_[road, body]).height == pytest.approx(1.6, rel=0.03)
    # a clutter cluster of less than half the road's support below the road does not win
    assert height_mode(np.r_[body[:, 1], 1.6 + 0.01 * rng.standard_normal(20)], 0.05) == pytest.approx(1.0, rel=0.05)


def test_a_pitched_camera_still_finds_the_plane():
    rng = np.random.default_rng(2)
    road = _road(rng, 150, 1.65, noise=0.003)
    a = np.radians(3)  # the camera looks 3 degrees down: the road normal tilts in the camera frame
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    fit = fit_ground(road @ R.T)
    assert fit is not None and fit.height == pytest.approx(1.65, rel=0.02)
    assert np.degrees(np.arccos(fit.normal @ R @ [0, 1, 0])) < 0.5


def test_no_plane_from_too_few_or_no_road_points():
    rng = np.random.default_rng(3)
    assert fit_ground(_road(rng, 5, 1.5)) is None
    # all above
    assert fit_ground(np.c_[rng.uniform(-5, 5, 50), rng.uniform(-3, -1, 50), rng.uniform(3, 20, 50)]) is None
    assert fit_ground(np.zeros((0, 3))) is None


def test_road_corners_lie_in_the_corridor_below_the_horizon():
    img = (np.random.default_rng(4).random((256, 448)) * 255).astype(np.uint8)
    uv = road_corners(img, K, camera_height=1.65, corridor_m=2.5)
    assert len(uv) > 100
    below = uv[:, 1] - K[1, 2]
    assert (below > 0.08 * 256 - 1).all()
    # sideways: at most 2.5 m from the camera's track on a road 1.65 m down
    assert (np.abs(uv[:, 0] - K[0, 2]) * 1.65 <= below * 2.5 + 1.0).all()
