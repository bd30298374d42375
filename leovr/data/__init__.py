"""Sequence records, readers for each supported layout, and LiDAR utilities."""

from __future__ import annotations

from pathlib import Path

from leovr.data.kitti_odometry import KittiOdometrySequence, is_kitti_odometry
from leovr.data.kitti_raw import KittiRawSequence, find_drive
from leovr.data.native import NativeSequence, NativeWriter, is_native, write_native
from leovr.data.records import Frame, SequenceInfo
from leovr.data.rosbag import RosbagSequence, is_rosbag
from leovr.data.sequence import Sequence
from leovr.data.tum import TumRgbdSequence, is_tum
from leovr.errors import DataError

READERS = ("native", "kitti_raw", "kitti_odometry", "tum_rgbd", "rosbag")


def detect_reader(path: Path, search: bool = True) -> str | None:
    """The reader a folder's layout calls for, or None. `search`: a KITTI raw drive may also be the only
    *_sync folder one or two levels down (`leovr batch` looks at each folder itself instead)."""
    if is_rosbag(path):
        return "rosbag"
    if is_native(path):
        return "native"
    if is_tum(path):
        return "tum_rgbd"
    if is_kitti_odometry(path):
        return "kitti_odometry"
    if (path / "image_02" / "data").is_dir() or (search and find_drive(path) is not None):
        return "kitti_raw"
    return None


def open_sequence(path: str | Path, reader: str | None = None) -> Sequence:
    """Open a sequence, choosing the reader from the folder layout unless `reader` names one."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or folder")
    if not path.is_dir() and not is_rosbag(path):
        raise DataError(path, "a sequence is a folder (or a ROS bag: a .bag file or a ROS 2 bag folder), not this file")
    if reader is None:
        reader = detect_reader(path)
        if reader is None:
            raise DataError(
                path,
                "unrecognised layout: expected sequence.yaml (native), rgb.txt + depth.txt (TUM RGB-D), "
                "calib.txt + image_0|image_2 (KITTI odometry), image_02/data (KITTI raw sync) "
                "or metadata.yaml (a ROS 2 bag)",
            )
    classes = {
        "native": NativeSequence,
        "kitti_raw": KittiRawSequence,
        "kitti_odometry": KittiOdometrySequence,
        "tum_rgbd": TumRgbdSequence,
        "rosbag": RosbagSequence,
    }
    if reader not in classes:
        raise DataError(path, f"unknown reader '{reader}' (choose from {', '.join(READERS)})")
    return classes[reader](path)


__all__ = [
    "DataError",
    "detect_reader",
    "Frame",
    "KittiOdometrySequence",
    "KittiRawSequence",
    "NativeSequence",
    "NativeWriter",
    "RosbagSequence",
    "Sequence",
    "SequenceInfo",
    "TumRgbdSequence",
    "open_sequence",
    "write_native",
]
