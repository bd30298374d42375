"""KITTI raw "sync" reader: image_02 colour camera, Velodyne HDL-64 scans, calibration, optional OXTS."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np

from leovr.data.io import check_timestamps, read_matrix_rows
from leovr.data.kitti_common import split_projection
from leovr.data.sequence import FileSequence
from leovr.errors import DataError
from leovr.geometry import invert_T, make_T

EARTH_RADIUS_M = 6378137.0


def find_drive(path: Path) -> Path | None:
    """The drive folder (holding image_02/data) at `path`, or the only *_sync folder one or two levels down."""
    if (path / "image_02" / "data").is_dir():
        return path
    if not path.is_dir():
        return None
    drives = sorted(p for pat in ("*_sync", "*/*_sync") for p in path.glob(pat) if (p / "image_02" / "data").is_dir())
    return drives[0] if len(drives) == 1 else None


def _calib_file(drive: Path, name: str) -> Path:
    for folder in (drive.parent, drive):
        if (folder / name).is_file():
            return folder / name
    return drive.parent / name


def _read_kitti_time(path: Path) -> np.ndarray:
    """KITTI raw timestamps ('2011-09-26 13:02:25.964389445') as seconds from the first."""
    try:
        lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
        secs = []
        for ln in lines:
            day, _, frac = ln.partition(".")
            base = datetime.strptime(day, "%Y-%m-%d %H:%M:%S").timestamp()
            secs.append(base + (float("0." + frac) if frac else 0.0))
    except (OSError, ValueError) as exc:
        raise DataError(path, f"unreadable timestamps: {exc}") from exc
    t = np.array(secs)
    return t - t[0] if len(t) else t


def oxts_poses(files: list[Path]) -> np.ndarray:
    """IMU poses (F x 4 x 4, relative to the first) from OXTS packets, Mercator as in KITTI's devkit."""
    packets = []
    for f in files:
        try:
            packets.append(np.array(f.read_text().split()[:6], float))
        except (OSError, ValueError) as exc:
            raise DataError(f, f"unreadable OXTS packet: {exc}") from exc
        if len(packets[-1]) < 6:
            raise DataError(f, "OXTS packet has fewer than 6 values (lat lon alt roll pitch yaw)")
    o = np.array(packets)
    lat, lon, alt, roll, pitch, yaw = o.T
    scale = np.cos(np.radians(lat[0]))
    tx = scale * EARTH_RADIUS_M * np.radians(lon)
    ty = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0))
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], 1)).as_matrix()
    T = np.tile(np.eye(4), (len(o), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = np.stack([tx, ty, alt], 1)
    return invert_T(T[0]) @ T


class KittiRawSequence(FileSequence):
    """One KITTI raw drive in "sync" layout; calibration is read from the date folder above it."""

    name = "kitti_raw"

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        drive = find_drive(path)
        if drive is None:
            raise DataError(path, "not a KITTI raw drive (expected image_02/data, or one *_sync folder holding it)")
        self.path = drive
        self.image_files = sorted((drive / "image_02" / "data").glob("*.png"))
        if not self.image_files:
            raise DataError(drive / "image_02" / "data", "no PNG images")
        velo_dir = drive / "velodyne_points" / "data"
        self.scan_files = sorted(velo_dir.glob("*.bin")) if velo_dir.is_dir() else []
        self.has_lidar = bool(self.scan_files)
        if self.has_lidar and len(self.scan_files) != len(self.image_files):
            raise DataError(
                velo_dir,
                f"{len(self.scan_files)} scans but {len(self.image_files)} images in {drive / 'image_02' / 'data'}",
            )
        self.K, self.T_cam_lidar, T_cam_imu = self._read_calibration(drive)
        ts_file = drive / "image_02" / "timestamps.txt"
        if ts_file.is_file():
            self._times = check_timestamps(_read_kitti_time(ts_file), ts_file)
            if len(self._times) != len(self.image_files):
                raise DataError(ts_file, f"{len(self._times)} timestamps for {len(self.image_files)} images")
        else:
            self._times = np.arange(len(self.image_files)) / self.rate_hz
        oxts = sorted((drive / "oxts" / "data").glob("*.txt"))
        self._poses = None
        if oxts and T_cam_imu is not None:
            if len(oxts) != len(self.image_files):
                raise DataError(drive / "oxts" / "data", f"{len(oxts)} OXTS packets for {len(self.image_files)} images")
            T_w_imu = oxts_poses(oxts)
            T_imu_cam = invert_T(T_cam_imu)
            # world = first camera frame
            self._poses = invert_T(T_w_imu[0] @ T_imu_cam) @ T_w_imu @ T_imu_cam
        self.has_poses = self._poses is not None

    def _read_calibration(self, drive: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        c2c_path = _calib_file(drive, "calib_cam_to_cam.txt")
        v2c_path = _calib_file(drive, "calib_velo_to_cam.txt")
        c2c = read_matrix_rows(c2c_path, "camera calibration")
        for key in ("P_rect_02", "R_rect_00"):
            if key not in c2c or c2c[key].size not in (9, 12):
                raise DataError(c2c_path, f"missing or malformed '{key}'")
        P = c2c["P_rect_02"].reshape(3, 4)
        K, T_rect2 = split_projection(P)
        R_rect = make_T(c2c["R_rect_00"].reshape(3, 3))
        v2c = read_matrix_rows(v2c_path, "LiDAR-to-camera calibration")
        if "R" not in v2c or "T" not in v2c or v2c["R"].size != 9 or v2c["T"].size != 3:
            raise DataError(v2c_path, "missing or malformed 'R' (9 values) / 'T' (3 values)")
        T_cam0_velo = make_T(v2c["R"].reshape(3, 3), v2c["T"])
        T_cam_lidar = T_rect2 @ R_rect @ T_cam0_velo
        T_cam_imu = None
        i2v_path = _calib_file(drive, "calib_imu_to_velo.txt")
        if i2v_path.is_file():
            i2v = read_matrix_rows(i2v_path, "IMU-to-LiDAR calibration")
            if "R" in i2v and "T" in i2v:
                T_cam_imu = T_cam_lidar @ make_T(i2v["R"].reshape(3, 3), i2v["T"])
        return K, T_cam_lidar, T_cam_imu
