"""Sequence records, readers for each supported layout, and LiDAR utilities."""

from __future__ import annotations

from pathlib import Path

from leovr.data.kitti_odometry import KittiOdometrySequence, is_kitti_odometry
from leovr.data.kitti_raw import KittiRawSequence, find_drive
from leovr.data.native import NativeSequence, NativeWriter, is_native, write_native
from leovr.data.records import Frame, SequenceInfo
from leovr.data.sequence import Sequence
from leovr.data.tum import TumRgbdSequence, is_tum
from leovr.errors import DataError

READERS = ("native", "kitti_raw", "kitti_odometry", "tum_rgbd")


def open_sequence(path: str | Path, reader: str | None = None) -> Sequence:
    """Open a sequence, choosing the reader from the folder layout unless `reader` names one."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or folder")
    if not path.is_dir():
        raise DataError(path, "a sequence is a folder, not a file")
    if reader is None:
        if is_native(path):
            reader = "native"
        elif is_tum(path):
            reader = "tum_rgbd"
        elif is_kitti_odometry(path):
            reader = "kitti_odometry"
        elif find_drive(path) is not None:
            reader = "kitti_raw"
        else:
            raise DataError(
                path,
                "unrecognised layout: expected sequence.yaml (native), rgb.txt + depth.txt (TUM RGB-D), "
                "calib.txt + image_0|image_2 (KITTI odometry) or image_02/data (KITTI raw sync)",
            )
    classes = {
        "native": NativeSequence,
        "kitti_raw": KittiRawSequence,
        "kitti_odometry": KittiOdometrySequence,
        "tum_rgbd": TumRgbdSequence,
    }
    if reader not in classes:
        raise DataError(path, f"unknown reader '{reader}' (choose from {', '.join(READERS)})")
    return classes[reader](path)


__all__ = [
    "DataError",
    "Frame",
    "KittiOdometrySequence",
    "KittiRawSequence",
    "NativeSequence",
    "NativeWriter",
    "Sequence",
    "SequenceInfo",
    "TumRgbdSequence",
    "open_sequence",
    "write_native",
]
