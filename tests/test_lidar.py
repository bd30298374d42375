"""Projection (hand-computed pixel), deskew, and cheap-sensor simulation."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import KITTI_RAW, R_CAM_LIDAR, needs_shared, ring_scan

from leovr.geometry import interpolate_poses, invert_T, make_T, transform_points
from leovr.lidar import (
    azimuth_times,
    deskew,
    parse_input,
    project_points,
    simulate_cheap_sensor,
    sparse_depth,
)
from leovr.lidar.cheap_sensor import MID40_FOV_DEG, ring_ids

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
T_CL = make_T(R_CAM_LIDAR, [0.1, 0.0, 0.0])


def test_projection_hand_computed_pixel_and_nearest_wins():
    # lidar (10, 2, -1) -> camera (-2 + 0.1, 1, 10) -> u = 500 * -0.19 + 320 = 225, v = 500 * 0.1 + 240 = 290
    # lidar (20, 3.9, -2) -> camera (-3.8, 2, 20) -> the same pixel, farther: must lose
    pts = np.array([[20, 3.9, -2], [10, 2, -1], [-5, 0, 0], [10, 50, 0]], np.float32)
    proj = project_points(pts, K, T_CL, (480, 640))
    assert list(proj.u) == [225] and list(proj.v) == [290] and list(proj.index) == [1]
    d = proj.to_map()
    assert d[290, 225] == pytest.approx(10.0) and (d > 0).sum() == 1
    # order must not matter
    assert sparse_depth(pts[::-1], K, T_CL, (480, 640))[290, 225] == pytest.approx(10.0)


def test_azimuth_times_for_spinning_lidar():
    # starts behind the car, turns clockwise seen from above: left, forward at mid-sweep, right, behind again
    pts = np.array([[-1.0, 1e-6, 0], [0.0, 1.0, 0], [1.0, 0.0, 0], [0.0, -1.0, 0], [-1.0, -1e-6, 0]])
    np.testing.assert_allclose(azimuth_times(pts, 0.1), [0.0, 0.025, 0.05, 0.075, 0.1], atol=1e-6)


def test_interpolate_poses_extrapolates_rotation_and_translation():
    R = np.array([[np.cos(0.2), -np.sin(0.2), 0], [np.sin(0.2), np.cos(0.2), 0], [0, 0, 1]])
    T1 = make_T(R, [1.0, 0.0, 0.0])
    back, ahead = interpolate_poses(np.eye(4), T1, np.array([-0.5, 1.5]))
    np.testing.assert_allclose(back[:3, 3], [-0.5, 0, 0], atol=1e-12)
    np.testing.assert_allclose(np.arctan2(back[1, 0], back[0, 0]), -0.1, atol=1e-12)
    np.testing.assert_allclose(np.arctan2(ahead[1, 0], ahead[0, 0]), 0.3, atol=1e-12)


def test_deskew_frame_moves_points_to_the_image_time_from_either_side():
    """A sweep that starts before the image and ends after it (KITTI raw): every return lands where the
    LiDAR at the image's time would have seen it."""
    from leovr.data.records import Frame
    from leovr.lidar.deskew import deskew_frame

    rng = np.random.default_rng(1)
    world = rng.uniform(-20, 20, (400, 3))  # static points, LiDAR frame at the image's time
    yaw = np.array([[np.cos(0.02), 0, np.sin(0.02)], [0, 1, 0], [-np.sin(0.02), 0, np.cos(0.02)]])  # about camera y
    motion = make_T(yaw, [0.0, 0.0, 1.2])  # the camera's motion over one frame interval (0.1 s)
    T_cl = make_T(R_CAM_LIDAR)
    times = rng.uniform(-0.06, 0.04, len(world))
    lidar_motion = invert_T(T_cl) @ motion @ T_cl
    at = interpolate_poses(np.eye(4), lidar_motion, times / 0.1)  # the LiDAR at each return's time
    measured = np.einsum("nij,nj->ni", invert_T(at)[:, :3, :3], world) + invert_T(at)[:, :3, 3]
    f = Frame(0, 0.0, np.zeros((4, 4, 3), np.uint8), np.eye(3), T_cl, measured.astype(np.float64), times)
    np.testing.assert_allclose(deskew_frame(f, motion, 0.1).points, world, atol=1e-9)
    assert np.abs(measured - world).max() > 0.5


def test_ring_ids_unchanged_when_deskewing_moves_returns_across_the_seam():
    scan = ring_scan()  # 360 returns a ring, azimuth rising from -180 degrees
    moved = scan.copy()
    second = np.arange(64) * 360 + 1  # each ring's second return (-179 degrees), carried back over the seam
    r = np.hypot(scan[second, 0], scan[second, 1])
    moved[second, 0], moved[second, 1] = r * np.cos(np.radians(179.9)), r * np.sin(np.radians(179.9))
    assert (np.diff(np.arctan2(moved[:, 1], moved[:, 0])) > np.pi).sum() == 64  # the scan crosses back over the seam
    np.testing.assert_array_equal(ring_ids(moved), ring_ids(scan))


def test_deskew_recovers_static_world_under_motion():
    rng = np.random.default_rng(0)
    world = rng.uniform(-20, 20, (500, 3))
    T0 = np.eye(4)
    T1 = make_T(np.array([[np.cos(0.1), -np.sin(0.1), 0], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]]), [1.0, 0.2, 0.0])
    times = rng.uniform(0, 0.1, len(world))
    poses = interpolate_poses(T0, T1, times / 0.1)
    measured = np.einsum("nij,nj->ni", invert_T(poses)[:, :3, :3], world) + invert_T(poses)[:, :3, 3]
    fixed = deskew(np.hstack([measured, np.ones((500, 1))]), times, T0, T1, 0.1)
    np.testing.assert_allclose(fixed[:, :3], transform_points(invert_T(T1), world), atol=1e-9)
    assert np.allclose(fixed[:, 3], 1.0)
    # without compensation the error is large, so the test can fail
    assert np.abs(measured - transform_points(invert_T(T1), world)).max() > 0.5


def test_vlp16_keeps_16_of_64_rings_ordered_and_shuffled():
    scan = ring_scan()
    split = simulate_cheap_sensor(scan, parse_input("vlp16"))
    el = np.round(np.degrees(np.arctan2(split.kept[:, 2], np.hypot(split.kept[:, 0], split.kept[:, 1]))), 3)
    assert len(np.unique(el)) == 16 and len(split.kept) == 16 * 360 and len(split.heldout) == 48 * 360
    shuffled = scan[np.random.default_rng(0).permutation(len(scan))]
    kept = simulate_cheap_sensor(shuffled, parse_input("vlp16")).kept
    el2 = np.round(np.degrees(np.arctan2(kept[:, 2], np.hypot(kept[:, 0], kept[:, 1]))), 3)
    assert len(np.unique(el2)) == 16


@needs_shared
def test_vlp16_on_real_hdl64_scan():
    from leovr.data import open_sequence

    f = open_sequence(KITTI_RAW)[0]
    assert len(np.unique(ring_ids(f.points))) == 65  # 64 rings + the partial one KITTI scans start with
    split = simulate_cheap_sensor(f.points, parse_input("vlp16"))
    kept = split.kept
    assert len(np.unique(ring_ids(kept, n_rings=16))) == 16
    np.testing.assert_array_equal(f.points[split.heldout_index], split.heldout)
    assert len(kept) + len(split.heldout_index) == len(f.points)
    assert 0.22 < len(kept) / len(f.points) < 0.28


def _dense_forward_scan(step_deg: float = 0.12) -> np.ndarray:
    a = np.radians(np.arange(-25, 25, step_deg))
    A, E = np.meshgrid(a, a)
    r = 20.0
    return np.stack([r * np.cos(E) * np.cos(A), r * np.cos(E) * np.sin(A), r * np.sin(E)], -1).reshape(-1, 3)


def test_mid40_cone_rosette_and_coverage_growth():
    scan = _dense_forward_scan()
    kept = [simulate_cheap_sensor(scan, parse_input("mid40"), frame_index=i).kept for i in range(6)]
    for k in kept:
        off_axis = np.degrees(np.arccos(k[:, 0] / np.linalg.norm(k, axis=1)))
        assert off_axis.max() <= MID40_FOV_DEG / 2 + 0.3
        assert 2000 < len(k) <= 10_000
    # the rosette fills the whole cone, not a ring or a line
    off_axis = np.degrees(np.arccos(kept[0][:, 0] / np.linalg.norm(kept[0], axis=1)))
    assert off_axis.min() < 2 and off_axis.max() > 17
    # non-repeating: consecutive frames differ; integrated coverage keeps growing
    keys = [set(map(tuple, np.round(k, 4))) for k in kept]
    assert len(keys[0] & keys[1]) < 0.5 * len(keys[0])
    union = [len(set().union(*keys[: n + 1])) for n in range(6)]
    assert all(b > a for a, b in zip(union, union[1:])) and union[-1] > 3 * union[0]


def test_ratio_input_fraction_disjoint_and_seeded():
    scan = _dense_forward_scan(0.5)
    Kc = np.array([[300.0, 0, 200], [0, 300, 100], [0, 0, 1]])
    args = dict(K=Kc, T_cam_lidar=make_T(R_CAM_LIDAR), shape=(200, 400))
    s = simulate_cheap_sensor(scan, parse_input("ratio:0.1"), 3, 7, **args)
    n = len(project_points(scan, Kc, args["T_cam_lidar"], (200, 400)).u)
    assert len(s.kept) + len(s.heldout) == n
    assert abs(len(s.kept) / n - 0.1) < 0.02
    assert not set(map(tuple, s.kept)) & set(map(tuple, s.heldout))
    np.testing.assert_array_equal(scan[s.heldout_index], s.heldout)  # the same returns from another deskew
    again = simulate_cheap_sensor(scan, parse_input("ratio:0.1"), 3, 7, **args)
    np.testing.assert_array_equal(s.kept, again.kept)
    other = simulate_cheap_sensor(scan, parse_input("ratio:0.1"), 4, 7, **args)
    assert not np.array_equal(s.kept, other.kept)


@pytest.mark.parametrize("bad", ["ratio:0.5", "ratio:x", "vlp32", "ratio:0.001"])
def test_parse_input_rejects_bad_specs(bad):
    with pytest.raises(ValueError):
        parse_input(bad)


def test_scan_history_places_earlier_scans_in_the_current_camera():
    from leovr.lidar.accumulate import ScanHistory

    T_cam_lidar = np.eye(4)
    h = ScanHistory(frames=2, T_cam_lidar=T_cam_lidar, check=False)
    for i in range(3):  # only the last two are kept
        h.add(i, np.array([[0.0, 0.0, 10.0 + i]]))
    assert [s.index for s in h.scans] == [1, 2]
    step = np.eye(4)
    step[2, 3] = 1.0  # each frame 1 m further along the optical axis
    poses = {1: step, 2: step @ step}
    pts = h.gather(poses | {5: np.eye(4)}, T_world_cam=step @ step @ step)
    # frame 1's point (11 m ahead of a camera at z=1) seen from z=3: 9 m; frame 2's (12 m ahead of z=2): 11 m
    np.testing.assert_allclose(sorted(pts[:, 2]), [9.0, 11.0])
    assert len(h.gather({2: step}, step)) == 1  # a frame without a pose is left out
    h0 = ScanHistory(frames=0)
    h0.add(0, np.ones((3, 3)))
    assert not h0.scans


def test_scan_history_drops_returns_a_later_scan_contradicts():
    """A later scan that sees free space where an earlier return was (a mover that left) or a nearer
    surface in front of it (hidden now) drops it; a static wall seen by both, and a direction the later
    scan did not see, keep theirs."""
    from leovr.lidar.accumulate import ScanHistory

    # camera: z forward; LiDAR: x forward (KITTI-like axes)
    T_cam_lidar = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], float)
    h = ScanHistory(frames=4, T_cam_lidar=T_cam_lidar)
    wall = np.array([[20.0, y, 0.0] for y in (-1.0, 0.0, 1.0)])  # LiDAR frame, seen by both scans
    car = np.array([[10.0, 3.0, 0.0]])  # in front of the wall at 16.7 degrees: gone in the later scan
    behind = np.array([[30.0, -8.0, 0.0]])  # later hidden by a truck at 15 m in that direction
    aside = np.array([[10.0, 0.0, 5.0]])  # a direction the later scan has no return in
    h.add(0, np.concatenate([wall, car, behind, aside]))
    later = np.concatenate([wall, [[20.0, 6.0, 0.0]], behind * 0.5])  # the wall behind the car's place; the truck
    h.add(1, later)
    poses = {0: np.eye(4), 1: np.eye(4)}  # a parked ego
    pts = h.gather(poses, np.eye(4))
    first = h.scans[0]
    assert first.dropped.tolist() == [False, False, False, True, True, False]
    assert len(pts) == 4 + len(later)
    h_off = ScanHistory(frames=4, T_cam_lidar=T_cam_lidar, check=False)
    h_off.add(0, np.concatenate([wall, car, behind, aside]))
    h_off.add(1, later)
    assert len(h_off.gather(poses, np.eye(4))) == 6 + len(later)


def test_with_history_keeps_the_own_scan_and_thins_earlier_returns_per_cell():
    from leovr.lidar.accumulate import with_history

    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    sparse = np.zeros((100, 100), np.float32)
    sparse[50, 50] = 5.0
    # earlier returns: one on the own pixel (ignored), two in one empty 4 x 4 cell (nearest wins), one far off
    uvz = np.array([[50, 50, 3.0], [10, 10, 8.0], [11, 10, 6.0], [90, 20, 7.0]])
    pts = np.stack([(uvz[:, 0] - 50) / 100 * uvz[:, 2], (uvz[:, 1] - 50) / 100 * uvz[:, 2], uvz[:, 2]], 1)
    out = with_history(sparse, pts, K, cell=4)
    assert out[50, 50] == 5.0 and out[20, 90] == 7.0
    assert out[10, 11] == 6.0 and out[10, 10] == 0.0
    assert (out > 0).sum() == 3
    assert with_history(sparse, np.zeros((0, 3)), K) is sparse
