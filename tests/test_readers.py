"""Readers: shared KITTI clips, generated TUM and native folders, layout detection, slicing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import KITTI_ODOM, KITTI_RAW, KITTI_RAW_POSES, needs_posed_drive, needs_shared, write_kitti_raw

from leovr.data import open_sequence, write_native
from leovr.data.io import read_matrix_rows
from leovr.data.kitti_odometry import read_odometry_calib
from leovr.errors import DataError


@needs_shared
def test_kitti_raw_clip_loads_with_calibration_matching_official_projection():
    seq = open_sequence(KITTI_RAW)
    assert seq.name == "kitti_raw" and len(seq) == 24 and seq.has_lidar and not seq.has_poses
    f = seq[5]
    assert f.image.shape == (375, 1242, 3) and f.image.dtype == np.uint8
    assert f.points.shape[1] == 4 and 70_000 < len(f.points) < 115_000
    assert f.timestamp == pytest.approx(0.5)
    # our K @ T_cam_lidar must equal KITTI's P_rect_02 @ R_rect_00 @ Tr_velo_to_cam
    date = KITTI_RAW / "2011_09_26"
    c2c = read_matrix_rows(date / "calib_cam_to_cam.txt", "c")
    v2c = read_matrix_rows(date / "calib_velo_to_cam.txt", "v")
    Rr = np.eye(4)
    Rr[:3, :3] = c2c["R_rect_00"].reshape(3, 3)
    Tr = np.eye(4)
    Tr[:3, :3], Tr[:3, 3] = v2c["R"].reshape(3, 3), v2c["T"]
    official = c2c["P_rect_02"].reshape(3, 4) @ Rr @ Tr
    ours = f.K @ f.T_cam_lidar[:3]
    np.testing.assert_allclose(ours, official, rtol=1e-9, atol=1e-6)
    # the README says 15k to 17k points fall inside the image
    from leovr.lidar import project_points

    n_in = len(project_points(f.points, f.K, f.T_cam_lidar, f.shape).u)
    assert 14_000 < n_in < 17_500


@needs_shared
def test_kitti_odometry_clip_has_poses_and_no_lidar():
    seq = open_sequence(KITTI_ODOM)
    assert seq.name == "kitti_odometry" and len(seq) == 51 and seq.has_poses and not seq.has_lidar
    calib = read_odometry_calib(KITTI_ODOM / "calib.txt")
    assert set(calib) == {"P0", "P1"}
    f = seq[10]
    assert f.image.ndim == 2 and f.image.shape == (370, 1226) and f.points is None
    assert f.K[0, 0] == pytest.approx(707.0912)
    # the car drives forward (camera z) about 1.2 m per frame in this clip
    assert f.T_world_cam[2, 3] == pytest.approx(seq[0].T_world_cam[2, 3] + 12.0, abs=1.5)
    np.testing.assert_allclose(seq.timestamps()[:2], [0.0, 0.1044989])


def test_slicing_keeps_original_indices(kitti_raw_tiny):
    seq = open_sequence(kitti_raw_tiny)
    view = seq[1:]
    assert len(view) == 2 and view[0].index == 1 and view[-1].index == 2
    with pytest.raises(IndexError):
        seq[3]
    assert [f.index for f in view] == [1, 2]


def test_layout_detection_finds_drive_two_levels_down(kitti_raw_tiny):
    assert open_sequence(kitti_raw_tiny.parent.parent).path == kitti_raw_tiny
    with pytest.raises(DataError, match="unrecognised layout"):
        open_sequence(kitti_raw_tiny / "image_02")


def _write_tum(root: Path, n: int = 4) -> Path:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, dep, gt = ["# rgb"], ["# depth"], ["# ground truth"]
    depth = np.zeros((48, 64), np.uint16)
    depth[10:40, 5:60] = 5000 * 2  # 2 m
    for i in range(n):
        t = 100.0 + i / 30
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), np.full((48, 64, 3), 50 * i, np.uint8))
        cv2.imwrite(str(root / "depth" / f"{t + 0.005:.6f}.png"), depth)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        dep.append(f"{t + 0.005:.6f} depth/{t + 0.005:.6f}.png")
        gt.append(f"{t + 0.001:.4f} {0.1 * i} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(dep) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


def test_tum_rgbd_associates_and_backprojects(tmp_path):
    seq = open_sequence(_write_tum(tmp_path / "rgbd_dataset_freiburg1_xyz"))
    assert seq.name == "tum_rgbd" and len(seq) == 4 and seq.has_poses
    f = seq[2]
    assert f.K[0, 0] == pytest.approx(517.3)
    assert len(f.points) == 30 * 55 and np.allclose(f.points[:, 2], 2.0)
    assert f.T_world_cam[0, 3] == pytest.approx(0.2)
    # the depth camera's points project back onto the pixels they came from
    from leovr.lidar import sparse_depth

    d = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    assert (d > 0).sum() == 30 * 55 and np.allclose(d[10:40, 5:60], 2.0)


def test_native_round_trip(kitti_raw_tiny, tmp_path):
    src = open_sequence(kitti_raw_tiny)
    out = write_native(src, tmp_path / "native")
    seq = open_sequence(out)
    assert seq.name == "native" and len(seq) == len(src)
    a, b = src[1], seq[1]
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_allclose(a.K, b.K)
    np.testing.assert_allclose(a.T_cam_lidar, b.T_cam_lidar)
    assert b.timestamp == pytest.approx(a.timestamp)
    # the camera's height above the road (camera-only scale) travels with the copy: KITTI's platform
    assert src.camera_height_m == seq.camera_height_m == pytest.approx(1.65)


def test_native_copy_keeps_the_drives_frame_numbers_and_warns_of_unread_scans(tmp_path):
    """A KITTI drive missing its frame 1: the copy names its files by the drive's numbers (0, 2, 3), so outputs
    of runs on it carry the drive's numbers; scans left in lidar/ without a `lidar:` entry are named unread."""
    import yaml

    drive = write_kitti_raw(tmp_path / "raw", frames=4)
    for folder, ext in (("image_02", "png"), ("velodyne_points", "bin")):
        (drive / folder / "data" / f"0000000001.{ext}").unlink()
    src = open_sequence(drive)
    assert src.frame_numbers() == [0, 2, 3]
    out = write_native(src, tmp_path / "native")
    assert sorted(p.name for p in (out / "images").iterdir()) == ["000000.png", "000002.png", "000003.png"]
    seq = open_sequence(out)
    assert seq.frame_numbers() == [0, 2, 3]
    np.testing.assert_array_equal(seq[1].points, src[1].points)
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    del meta["lidar"]
    (out / "sequence.yaml").write_text(yaml.safe_dump(meta))
    with pytest.warns(UserWarning, match="no 'lidar:' entry, so the scans in .*lidar are not read"):
        assert not open_sequence(out).has_lidar


def test_native_camera_height_must_be_a_positive_number(kitti_raw_tiny, tmp_path):
    import yaml

    out = write_native(open_sequence(kitti_raw_tiny), tmp_path / "native")
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    del meta["camera"]["height_above_road_m"]
    (out / "sequence.yaml").write_text(yaml.safe_dump(meta))
    assert open_sequence(out).camera_height_m is None  # unknown: the generator's depth sets the scale
    meta["camera"]["height_above_road_m"] = -1.0
    (out / "sequence.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match="height_above_road_m.*positive"):
        open_sequence(out)


def test_native_writer_keeps_poses_depth_times_and_masks(tmp_path):
    from leovr.data import Frame, NativeWriter

    w = NativeWriter(tmp_path / "seq", name="t")
    rng = np.random.default_rng(0)
    poses = []
    for i in range(3):
        T = np.eye(4)
        T[:3, 3] = [i, 0.5 * i, 0]
        poses.append(T)
        depth = np.full((20, 30), 3.2567, np.float32)
        mask = np.zeros((20, 30), bool)
        mask[:, i] = True
        w.write(
            Frame(
                i,
                0.1 * i,
                rng.integers(0, 255, (20, 30, 3), dtype=np.uint8),
                np.eye(3),
                points=rng.normal(size=(50, 4)).astype(np.float32),
                point_times=np.linspace(0, 0.1, 50),
                T_world_cam=T,
                depth=depth,
                moving_mask=mask,
            )
        )
    seq = open_sequence(w.close())
    assert seq.has_poses and seq.has_depth and seq.has_lidar
    f = seq[2]
    np.testing.assert_allclose(f.T_world_cam, poses[2], atol=1e-9)
    np.testing.assert_allclose(f.depth, round(3.2567 * 256) / 256)  # metres x 256 PNG (KITTI convention)
    np.testing.assert_allclose(f.point_times, np.linspace(0, 0.1, 50), atol=1e-7)
    assert f.points.shape == (50, 4) and f.moving_mask[:, 2].all() and f.moving_mask.sum() == 20


def test_kitti_raw_reads_oxts_poses(kitti_raw_tiny):
    (kitti_raw_tiny / "oxts" / "data").mkdir(parents=True)
    for i in range(3):
        # 49 deg N, moving east: longitude grows; heading east (yaw 0), level
        pkt = [49.0, 8.0 + i * 1e-5, 100.0, 0, 0, 0] + [0] * 24
        (kitti_raw_tiny / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(map(str, pkt)))
    (kitti_raw_tiny.parent / "calib_imu_to_velo.txt").write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    seq = open_sequence(kitti_raw_tiny)
    assert seq.has_poses
    np.testing.assert_allclose(seq[0].T_world_cam, np.eye(4), atol=1e-9)
    step = np.cos(np.radians(49.0)) * 6378137.0 * np.radians(1e-5)
    # the IMU (= LiDAR here) moves along its own x, which is the camera's z (forward)
    np.testing.assert_allclose(seq[2].T_world_cam[:3, 3], [0, 0, 2 * step], atol=1e-6)


@needs_posed_drive
def test_kitti_raw_drive_poses_at_image_times_and_scan_times_from_azimuth():
    """OXTS packets are stamped 2-14 ms off the images; poses interpolated to the image times drive at a
    steady 11-12 m/s (at the packets' own times the steps swing by about 10 %). Each return's time follows
    from the scan's start and end stamps and its azimuth: the forward returns near the image's time."""
    seq = open_sequence(KITTI_RAW_POSES)
    assert seq.has_poses and seq.sweeps is not None
    steps = np.linalg.norm(np.diff(np.stack([seq[i].T_world_cam[:3, 3] for i in range(12)]), axis=0), axis=1)
    speed = steps / np.diff(seq.timestamps()[:12])
    assert 11.0 < speed.min() and speed.max() < 12.5
    assert np.abs(np.diff(steps)).max() < 0.02 * steps.mean()
    f = seq[3]
    assert f.point_times is not None and len(f.point_times) == len(f.points)
    start, end = seq.sweeps[3]
    assert -0.07 < start < 0 < end < 0.05 and f.point_times.min() >= start - 1e-9 and f.point_times.max() <= end + 1e-9
    ahead = (f.points[:, 0] > 5) & (np.abs(f.points[:, 1]) < 0.2 * f.points[:, 0])
    assert np.abs(np.median(f.point_times[ahead]) - (start + end) / 2) < 0.005
