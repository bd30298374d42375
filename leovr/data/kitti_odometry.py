"""KITTI odometry reader: sequences/XX with image_0 or image_2, calib.txt, times.txt, optional
velodyne/ and ground-truth poses in poses/XX.txt beside sequences/."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.data.io import read_timestamp_file, require_file, require_intrinsics
from leovr.data.kitti_common import KITTI_CAMERA_HEIGHT_M, read_kitti_poses, split_projection
from leovr.data.sequence import FileSequence
from leovr.errors import DataError
from leovr.geometry import invert_T

CALIB_KEYS = ("P0", "P1", "P2", "P3", "Tr")


def is_kitti_odometry(path: Path) -> bool:
    return (path / "calib.txt").is_file() and ((path / "image_0").is_dir() or (path / "image_2").is_dir())


def read_odometry_calib(path: Path) -> dict[str, np.ndarray]:
    """calib.txt rows as 3x4 matrices; rows may be keyed ('P0: ...') or bare in the order P0..P3, Tr."""
    require_file(path, "calibration")
    out: dict[str, np.ndarray] = {}
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(path, f"unreadable calibration: {exc}") from exc
    for n, line in enumerate(lines):
        key, sep, rest = line.partition(":")
        if not sep:
            if n >= len(CALIB_KEYS):
                continue
            key, rest = CALIB_KEYS[n], line
        try:
            vals = np.array([float(v) for v in rest.split()])
        except ValueError:
            raise DataError(path, f"line {n + 1} is not a list of numbers") from None
        if vals.size != 12:
            raise DataError(path, f"line {n + 1} ('{key.strip()}') has {vals.size} numbers, expected 12")
        out[key.strip().replace("Tr_velo_to_cam", "Tr")] = vals.reshape(3, 4)
    if "P0" not in out:
        raise DataError(path, "no P0 row")
    return out


class KittiOdometrySequence(FileSequence):
    """A KITTI odometry sequence; prefers the colour camera (image_2) when present."""

    name = "kitti_odometry"
    camera_height_m = KITTI_CAMERA_HEIGHT_M

    def __init__(self, path: str | Path) -> None:
        self.path = path = Path(path)
        if not is_kitti_odometry(path):
            raise DataError(path, "not a KITTI odometry sequence (expected calib.txt and image_0/ or image_2/)")
        cam = 2 if (path / "image_2").is_dir() else 0
        self.image_files = sorted((path / f"image_{cam}").glob("*.png"))
        if not self.image_files:
            raise DataError(path / f"image_{cam}", "no PNG images")
        calib = read_odometry_calib(path / "calib.txt")
        if f"P{cam}" not in calib:
            raise DataError(path / "calib.txt", f"no P{cam} row for image_{cam}")
        if not np.isfinite(calib[f"P{cam}"]).all():
            raise DataError(path / "calib.txt", f"'P{cam}' holds NaN or infinite values")
        self.K, T_cam_cam0 = split_projection(calib[f"P{cam}"])
        require_intrinsics(self.K, path / "calib.txt")
        self.T_cam_lidar = np.eye(4)
        velo = path / "velodyne"
        self.scan_files = sorted(velo.glob("*.bin")) if velo.is_dir() else []
        self.has_lidar = bool(self.scan_files)
        if self.has_lidar:
            if "Tr" not in calib:
                raise DataError(path / "calib.txt", "velodyne/ present but no Tr row (LiDAR-to-camera transform)")
            if len(self.scan_files) != len(self.image_files):
                raise DataError(velo, f"{len(self.scan_files)} scans but {len(self.image_files)} images")
            T_cam0_velo = np.eye(4)
            T_cam0_velo[:3] = calib["Tr"]
            self.T_cam_lidar = T_cam_cam0 @ T_cam0_velo
        times = path / "times.txt"
        if times.is_file():
            self._times = read_timestamp_file(times, len(self.image_files))
        else:
            self._times = np.arange(len(self.image_files)) / self.rate_hz
        pose_file = path.parent.parent / "poses" / f"{path.name}.txt"
        self._poses = None
        if pose_file.is_file():
            T0 = read_kitti_poses(pose_file)  # camera 0 poses
            if len(T0) != len(self.image_files):
                raise DataError(pose_file, f"{len(T0)} poses for {len(self.image_files)} images")
            self._poses = T0 @ invert_T(T_cam_cam0)
        self.has_poses = self._poses is not None
