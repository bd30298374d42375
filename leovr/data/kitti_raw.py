"""KITTI raw "sync" reader: image_02 colour camera, Velodyne HDL-64 scans, calibration, optional OXTS."""

from __future__ import annotations

import warnings
from datetime import datetime
from pathlib import Path

import numpy as np

from leovr.data.io import check_timestamps, read_matrix_rows
from leovr.data.kitti_common import KITTI_CAMERA_HEIGHT_M, split_projection
from leovr.data.oxts import oxts_poses, read_packets
from leovr.data.sequence import FileSequence
from leovr.errors import DataError, brief
from leovr.geometry import invert_T, make_T, poses_at


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
    """KITTI raw timestamps ('2011-09-26 13:02:25.964389445') as seconds of the recording's clock."""
    try:
        lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
        secs = []
        for ln in lines:
            day, _, frac = ln.partition(".")
            base = datetime.strptime(day, "%Y-%m-%d %H:%M:%S").timestamp()
            secs.append(base + (float("0." + frac) if frac else 0.0))
    except (OSError, ValueError) as exc:
        raise DataError(path, f"unreadable timestamps: {exc}") from exc
    return np.array(secs)


def _stamps_for(path: Path, numbers: list[int], what: str) -> np.ndarray | None:
    """The lines of a KITTI timestamp file for the given frame numbers; None when the file is absent."""
    if not path.is_file():
        return None
    t = _read_kitti_time(path)
    if len(t) <= numbers[-1]:
        raise DataError(
            path, f"{len(t)} {what} timestamps, but frame number {numbers[-1]} needs line {numbers[-1] + 1}"
        )
    return t[numbers]


def _numbered(folder: Path, pattern: str) -> dict[int, Path]:
    """Files of `folder` by the frame number their name holds (0000000042.png -> 42)."""
    out: dict[int, Path] = {}
    for p in sorted(folder.glob(pattern)):
        if not p.stem.isdigit():
            raise DataError(p, "file name is not a frame number (KITTI names frames 0000000000, 0000000001, ...)")
        out[int(p.stem)] = p
    return out


def _frames(numbers: list[int]) -> str:
    return f"frame{'s' if len(numbers) > 1 else ''} {brief(numbers)}" if numbers else "no frame"


class KittiRawSequence(FileSequence):
    """One KITTI raw drive in "sync" layout; calibration is read from the date folder above it."""

    name = "kitti_raw"
    camera_height_m = KITTI_CAMERA_HEIGHT_M

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        drive = find_drive(path)
        if drive is None:
            raise DataError(path, "not a KITTI raw drive (expected image_02/data, or one *_sync folder holding it)")
        self.path = drive
        images = _numbered(drive / "image_02" / "data", "*.png")
        if not images:
            raise DataError(drive / "image_02" / "data", "no PNG images")
        velo_dir = drive / "velodyne_points" / "data"
        scans = _numbered(velo_dir, "*.bin") if velo_dir.is_dir() else {}
        self.has_lidar = bool(scans)
        numbers = sorted(images)
        if self.has_lidar:
            numbers = sorted(set(images) & set(scans))
            no_scan, no_image = sorted(set(images) - set(scans)), sorted(set(scans) - set(images))
            if not numbers:
                raise DataError(velo_dir, "no scan has the frame number of an image in image_02/data")
            if no_scan or no_image:
                warnings.warn(
                    f"{drive}: frames paired by number; skipped {_frames(no_scan)} without a scan"
                    f" and {_frames(no_image)} without an image",
                    stacklevel=2,
                )
        self._numbers = numbers
        self.image_files = [images[n] for n in numbers]
        self.scan_files = [scans[n] for n in numbers] if self.has_lidar else []
        self.K, self.T_cam_lidar, T_cam_imu = self._read_calibration(drive)
        ts_file = drive / "image_02" / "timestamps.txt"
        camera_t = _stamps_for(ts_file, numbers, "image")
        if camera_t is not None:
            self._times = check_timestamps(camera_t - camera_t[0], ts_file)
        else:  # frame numbers at the camera rate: a gap in the numbering stays a gap in time
            self._times = (np.array(numbers, float) - numbers[0]) / self.rate_hz
        self.sweeps = None
        velo = drive / "velodyne_points"
        starts = _stamps_for(velo / "timestamps_start.txt", numbers, "scan start") if self.has_lidar else None
        ends = _stamps_for(velo / "timestamps_end.txt", numbers, "scan end") if self.has_lidar else None
        if starts is not None and ends is not None and camera_t is not None:
            sweeps = np.stack([starts, ends], 1) - camera_t[:, None]
            if not (np.isfinite(sweeps).all() and (np.diff(sweeps, axis=1) > 0).all()):
                raise DataError(velo / "timestamps_end.txt", "a scan ends before it starts")
            self.sweeps = sweeps
        oxts = _numbered(drive / "oxts" / "data", "*.txt") if (drive / "oxts" / "data").is_dir() else {}
        self._poses = None
        self.gps_poses: np.ndarray | None = None  # the fixes alone, as KITTI's devkit reads them (for comparison)
        if oxts and T_cam_imu is not None:
            missing = [n for n in numbers if n not in oxts]
            if missing:
                raise DataError(drive / "oxts" / "data", f"no OXTS packet for {_frames(missing)}")
            packets = read_packets([oxts[n] for n in numbers])
            oxts_t = _stamps_for(drive / "oxts" / "timestamps.txt", numbers, "OXTS")
            if oxts_t is not None:
                oxts_t = check_timestamps(oxts_t, drive / "oxts" / "timestamps.txt")
            T_imu_cam = invert_T(T_cam_imu)

            def camera_poses(T_w_imu: np.ndarray) -> np.ndarray:
                if oxts_t is not None and camera_t is not None:
                    # each packet is stamped by the GPS/IMU's own clock tick, 2-14 ms off the camera's (11-12
                    # m/s: up to 0.15 m): the poses at the images' times, interpolated between the packets
                    T_w_imu = poses_at(oxts_t, T_w_imu, camera_t)
                return invert_T(T_w_imu[0] @ T_imu_cam) @ T_w_imu @ T_imu_cam  # world = first camera frame

            self._poses = camera_poses(oxts_poses(packets, oxts_t))
            self.gps_poses = camera_poses(oxts_poses(packets))
        self.has_poses = self._poses is not None

    def frame_numbers(self) -> list[int]:
        """The drive's frame numbers (file names), gaps included."""
        return list(self._numbers)

    def _read_calibration(self, drive: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        c2c_path = _calib_file(drive, "calib_cam_to_cam.txt")
        v2c_path = _calib_file(drive, "calib_velo_to_cam.txt")
        c2c = read_matrix_rows(c2c_path, "camera calibration")
        for key, size in (("P_rect_02", 12), ("R_rect_00", 9)):
            if key not in c2c or c2c[key].size != size:
                got = "missing" if key not in c2c else f"{c2c[key].size} numbers"
                raise DataError(c2c_path, f"missing or malformed '{key}': needs {size} numbers, {got}")
            if not np.isfinite(c2c[key]).all():
                raise DataError(c2c_path, f"'{key}' holds NaN or infinite values")
        P = c2c["P_rect_02"].reshape(3, 4)
        if abs(np.linalg.det(P[:, :3])) < 1e-9 or P[0, 0] <= 0 or P[1, 1] <= 0:
            raise DataError(c2c_path, "'P_rect_02' is singular or has non-positive focal lengths")
        K, T_rect2 = split_projection(P)
        R_rect = make_T(c2c["R_rect_00"].reshape(3, 3))
        v2c = read_matrix_rows(v2c_path, "LiDAR-to-camera calibration")
        if "R" not in v2c or "T" not in v2c or v2c["R"].size != 9 or v2c["T"].size != 3:
            raise DataError(v2c_path, "missing or malformed 'R' (9 values) / 'T' (3 values)")
        if not (np.isfinite(v2c["R"]).all() and np.isfinite(v2c["T"]).all()):
            raise DataError(v2c_path, "'R' or 'T' holds NaN or infinite values")
        T_cam0_velo = make_T(v2c["R"].reshape(3, 3), v2c["T"])
        T_cam_lidar = T_rect2 @ R_rect @ T_cam0_velo
        T_cam_imu = None
        i2v_path = _calib_file(drive, "calib_imu_to_velo.txt")
        if i2v_path.is_file():
            i2v = read_matrix_rows(i2v_path, "IMU-to-LiDAR calibration")
            if "R" in i2v and "T" in i2v:
                T_cam_imu = T_cam_lidar @ make_T(i2v["R"].reshape(3, 3), i2v["T"])
        return K, T_cam_lidar, T_cam_imu
