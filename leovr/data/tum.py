"""TUM RGB-D reader: rgb.txt, depth.txt and groundtruth.txt associated by timestamp.

The depth camera is treated as a dense range sensor: its valid pixels, back-projected into the
camera frame, become the frame's "LiDAR" points (extrinsic = identity), so the same completion
pipeline fills its holes (LeoVR Sec. V-G).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leovr.data.io import associate, check_timestamps, read_depth_png, read_image, require_file
from leovr.data.records import Frame
from leovr.data.sequence import FileSequence
from leovr.errors import DataError
from leovr.geometry import pose_from_tum

TUM_DEPTH_SCALE = 5000.0  # depth PNG units per metre
MAX_DT = 0.02  # association tolerance in seconds, as in TUM's associate.py
# calibrated intrinsics of the three Freiburg Kinects (TUM RGB-D benchmark); ROS default otherwise
INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}
DEFAULT_INTRINSICS = (525.0, 525.0, 319.5, 239.5)


def is_tum(path: Path) -> bool:
    return (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


def read_tum_list(path: Path, min_cols: int = 2) -> tuple[np.ndarray, list[list[str]]]:
    """Read a TUM list file ('# comment' lines skipped) as (timestamps, remaining columns)."""
    require_file(path, "TUM list")
    stamps, rows = [], []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < min_cols:
            raise DataError(path, f"line {n}: expected at least {min_cols} columns, got {len(parts)}")
        try:
            stamps.append(float(parts[0]))
        except ValueError:
            raise DataError(path, f"line {n}: '{parts[0]}' is not a timestamp") from None
        rows.append(parts[1:])
    return np.array(stamps), rows


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Valid depth pixels as N x 3 camera-frame points."""
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    x = (u - K[0, 2]) * z / K[0, 0]
    y = (v - K[1, 2]) * z / K[1, 1]
    return np.stack([x, y, z], 1).astype(np.float32)


class TumRgbdSequence(FileSequence):
    """A TUM RGB-D folder; frames are the RGB images that have a depth image within 20 ms."""

    name = "tum_rgbd"
    rate_hz = 30.0

    def __init__(self, path: str | Path) -> None:
        self.path = path = Path(path)
        if not is_tum(path):
            raise DataError(path, "not a TUM RGB-D folder (expected rgb.txt and depth.txt)")
        t_rgb, rgb = read_tum_list(path / "rgb.txt")
        t_depth, dep = read_tum_list(path / "depth.txt")
        check_timestamps(t_rgb, path / "rgb.txt")
        check_timestamps(t_depth, path / "depth.txt")
        j = associate(t_rgb, t_depth, MAX_DT)
        keep = j >= 0
        if not keep.any():
            raise DataError(path / "depth.txt", "no depth image within 20 ms of any RGB image")
        self._times = t_rgb[keep]
        self.image_files = [path / rgb[i][0] for i in np.nonzero(keep)[0]]
        self.scan_files = []  # the depth image is the scan (`_load`)
        self.T_cam_lidar = np.eye(4)
        self.depth_files = [path / dep[k][0] for k in j[keep]]
        fx, fy, cx, cy = next((v for k, v in INTRINSICS.items() if k in path.name), DEFAULT_INTRINSICS)
        self.K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        self._poses = None
        gt = path / "groundtruth.txt"
        if gt.is_file():
            t_gt, rows = read_tum_list(gt, min_cols=8)
            check_timestamps(t_gt, gt)
            k = associate(self._times, t_gt, MAX_DT)
            if (k < 0).any():
                raise DataError(gt, f"{int((k < 0).sum())} frames have no pose within 20 ms")
            vals = np.array([[float(v) for v in r[:7]] for r in rows])
            self._poses = np.stack([pose_from_tum(vals[i]) for i in k])
        self.has_poses = self._poses is not None
        self.has_lidar = True

    def _load(self, i: int) -> Frame:
        """The RGB image, and the depth image back-projected as the frame's points (camera frame)."""
        sensor_depth = read_depth_png(self.depth_files[i], TUM_DEPTH_SCALE)
        points = backproject(sensor_depth, self.K)
        if len(points) == 0:
            raise DataError(self.depth_files[i], "depth image has no valid pixel")
        return self._frame(i, read_image(self.image_files[i]), points)
