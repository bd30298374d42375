"""A ROS bag's calibration: the camera's intrinsics from its CameraInfo (with the maps that undistort
its images into a pinhole camera of the same size), and the camera-LiDAR extrinsic chained through
`/tf_static` or read from a file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from leovr.data import ros_messages as rm
from leovr.errors import DataError, brief


def camera_model(path: Path, camera: str, info_topic: str | None, info: Any) -> tuple[np.ndarray, Any]:
    """(K, undistortion maps or None): intrinsics from the CameraInfo, with the maps when the lens distorts."""
    if info is None:
        raise DataError(path, f"no camera info for {camera} (sensor_msgs/CameraInfo): the camera matrix is needed")
    try:
        K, D, model, (h, w) = rm.camera_intrinsics(info)
    except rm.MessageError as exc:
        raise DataError(path, f"{info_topic}: {exc}") from exc
    maps = None
    if len(D) and np.any(D != 0):
        if model in ("plumb_bob", "rational_polynomial"):
            Knew = cv2.getOptimalNewCameraMatrix(K, D, (w, h), 0.0)[0]
            maps = cv2.initUndistortRectifyMap(K, D, None, Knew, (w, h), cv2.CV_32FC1)
        elif model in ("equidistant", "fisheye"):
            Knew = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D[:4], (w, h), np.eye(3))
            maps = cv2.fisheye.initUndistortRectifyMap(K, D[:4], np.eye(3), Knew, (w, h), cv2.CV_32FC1)
        else:
            raise DataError(
                path,
                f"{info_topic}: distortion model {model!r} is not read (plumb_bob, rational_polynomial, equidistant)",
            )
        K = Knew
    return np.asarray(K, np.float64), maps


def lidar_extrinsic(
    path: Path, tree: rm.FrameTree, camera_frame: str, lidar_frame: str, extrinsic: Path | None
) -> np.ndarray:
    """T_cam_lidar: from the extrinsic file when given, else chained through /tf_static."""
    if extrinsic is not None:
        return read_extrinsic(Path(extrinsic))
    T = tree.between(camera_frame, lidar_frame)
    if T is None:
        frames = brief(tree.frames, 8) or "no /tf_static"
        raise DataError(
            path,
            f"no transform from the LiDAR's frame {lidar_frame!r} to the camera's "
            f"{camera_frame!r} ({frames}); give one with --extrinsic FILE "
            "(T_cam_lidar, 12 or 16 numbers)",
        )
    return T


def read_extrinsic(path: Path) -> np.ndarray:
    """T_cam_lidar from a text file of 12 (3 x 4) or 16 (4 x 4) numbers."""
    try:
        vals = np.array(path.read_text().replace(",", " ").split(), np.float64)
    except OSError as exc:
        raise DataError(path, f"cannot read the extrinsic: {exc.strerror or exc}") from exc
    except ValueError:
        raise DataError(path, "an extrinsic file holds 12 or 16 numbers (T_cam_lidar)") from None
    if len(vals) not in (12, 16) or not np.isfinite(vals).all():
        raise DataError(path, f"an extrinsic file holds 12 or 16 finite numbers (T_cam_lidar), not {len(vals)}")
    T = np.eye(4)
    T[:3] = vals[:12].reshape(3, 4)
    if len(vals) == 16 and not np.allclose(vals[12:], [0, 0, 0, 1]):
        raise DataError(path, "the last row of a 4 x 4 extrinsic must be 0 0 0 1")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise DataError(path, "the extrinsic's rotation block is not a rotation")
    return T
