"""Decoding of the ROS messages a recorded drive holds, once deserialized by `rosbags`: images (raw or
compressed), camera intrinsics, point clouds with per-point times, static transforms and poses.

Field names follow ROS 2; ROS 1 spellings (`K`, `D`, a header `seq`) are read as well. Errors name the
topic and the problem; the reader adds the bag's path.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
TF_TYPE = "tf2_msgs/msg/TFMessage"

# PointField datatypes (sensor_msgs/PointField) as numpy types
FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
# per-point time fields, as drivers name them: Ouster `t` (ns from the scan's stamp), Velodyne `time` (s),
# Hesai `timestamp` (absolute s), Livox `offset_time` (ns)
TIME_FIELDS = ("t", "time", "timestamp", "offset_time", "time_offset")
INTENSITY_FIELDS = ("intensity", "reflectivity", "i")


class MessageError(ValueError):
    """A message leovr cannot use; the text says why."""


def stamp_ns(msg: Any) -> int:
    """A message's header stamp in integer nanoseconds (ROS 2 `sec`/`nanosec`, ROS 1 `secs`/`nsecs`)."""
    t = msg.header.stamp
    sec = getattr(t, "sec", None)
    if sec is None:
        return int(t.secs) * 1_000_000_000 + int(t.nsecs)
    return int(sec) * 1_000_000_000 + int(t.nanosec)


def decode_image(msg: Any, msgtype: str) -> np.ndarray:
    """An Image (rgb8, bgr8, rgba8, bgra8, mono8, mono16) or CompressedImage (jpeg, png) as RGB or gray
    uint8 (mono16: the top byte, shifted down to the bits the camera fills: see `Mono16Scale`)."""
    if msgtype.endswith("CompressedImage"):
        data = np.frombuffer(bytes(msg.data), np.uint8) if not isinstance(msg.data, np.ndarray) else msg.data
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise MessageError(f"compressed image ({msg.format!r}) cannot be decoded")
        if img.ndim == 3:
            return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
        return img
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, np.uint8)
    if len(data) < h * step:
        raise MessageError(f"image data holds {len(data)} bytes, {h} rows of {step} need {h * step}")
    rows = data[: h * step].reshape(h, step)
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3}
    if enc in channels:
        c = channels[enc]
        img = rows[:, : w * c].reshape(h, w, c) if c > 1 else rows[:, :w]
        conv = {
            "bgr8": cv2.COLOR_BGR2RGB,
            "8uc3": cv2.COLOR_BGR2RGB,
            "rgba8": cv2.COLOR_RGBA2RGB,
            "bgra8": cv2.COLOR_BGRA2RGB,
        }.get(enc)
        return cv2.cvtColor(img, conv) if conv is not None else img.copy()  # a copy: the message's buffer is read-only
    if enc in ("mono16", "16uc1"):
        dtype = ">u2" if msg.is_bigendian else "<u2"
        return rows[:, : 2 * w].copy().view(dtype).reshape(h, w).astype(np.uint16)
    raise MessageError(f"image encoding {msg.encoding!r} is not read (rgb8, bgr8, rgba8, bgra8, mono8, mono16)")


def to_uint8(img: np.ndarray, shift: int) -> np.ndarray:
    """A 16-bit image as uint8: its values shifted down by `shift` bits (fixed per sequence), clipped."""
    if img.dtype == np.uint8:
        return img
    return np.clip(img.astype(np.uint32) >> shift, 0, 255).astype(np.uint8)


def mono16_shift(img: np.ndarray) -> int:
    """Bits to drop so that the brightest pixel of a 16-bit image fits 8 bits (a 12-bit camera: 4)."""
    top = int(img.max()) if img.size else 0
    return max(top.bit_length() - 8, 0)


def camera_intrinsics(msg: Any) -> tuple[np.ndarray, np.ndarray, str, tuple[int, int]]:
    """K (3 x 3), distortion coefficients, distortion model and (height, width) of a CameraInfo."""
    k = getattr(msg, "k", None)
    k = msg.K if k is None else k
    d = getattr(msg, "d", None)
    d = msg.D if d is None else d
    K = np.asarray(k, np.float64).reshape(3, 3)
    if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MessageError("camera_info has no usable camera matrix (k)")
    return K, np.asarray(d, np.float64), str(msg.distortion_model or "plumb_bob"), (int(msg.height), int(msg.width))


def cloud_fields(msg: Any) -> dict[str, tuple[int, str]]:
    """The cloud's fields by name: (byte offset, numpy type), one element each."""
    order = ">" if msg.is_bigendian else "<"
    out = {}
    for f in msg.fields:
        if int(f.datatype) not in FIELD_TYPES:
            raise MessageError(f"point field {f.name!r} has unknown datatype {f.datatype}")
        out[str(f.name)] = (int(f.offset), order + FIELD_TYPES[int(f.datatype)])
    return out


def time_field(fields: dict[str, tuple[int, str]]) -> str | None:
    return next((n for n in TIME_FIELDS if n in fields), None)


def _records(msg: Any, fields: dict[str, tuple[int, str]]) -> np.ndarray:
    """The cloud's points as an N x point_step byte array (padded rows cut)."""
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    data = np.asarray(msg.data, np.uint8)
    row = int(msg.row_step) or int(msg.width) * step
    if int(msg.height) > 1 and row != int(msg.width) * step:  # padded rows: the points of each row only
        data = data[: int(msg.height) * row].reshape(int(msg.height), row)[:, : int(msg.width) * step].ravel()
    if len(data) < n * step:
        raise MessageError(f"point cloud data holds {len(data)} bytes, {n} points of {step} need {n * step}")
    return data[: n * step].reshape(n, step)


def _column(recs: np.ndarray, fields: dict[str, tuple[int, str]], name: str) -> np.ndarray:
    off, typ = fields[name]
    size = np.dtype(typ).itemsize
    return recs[:, off : off + size].copy().view(typ).ravel()


def _point_times(msg: Any, fields: dict[str, tuple[int, str]], recs: np.ndarray) -> tuple[np.ndarray, bool] | None:
    """Each point's time in seconds and whether it is absolute (from the epoch) or an offset from the
    cloud's stamp; None without a time field or without a finite time. Integer fields are nanoseconds,
    float fields seconds; values of more than a day are absolute. A point without a finite time takes the
    sweep's median time."""
    tname = time_field(fields)
    if tname is None or not len(recs):
        return None
    t = _column(recs, fields, tname).astype(np.float64) * (1e-9 if np.dtype(fields[tname][1]).kind in "iu" else 1.0)
    finite = np.isfinite(t)
    if not finite.any():
        return None
    if not finite.all():
        t = np.where(finite, t, np.median(t[finite]))
    return t, bool(np.median(t) > 86400.0)


def decode_cloud(msg: Any, ref_ns: int, time_scale: float | None = 1.0) -> tuple[np.ndarray, np.ndarray | None]:
    """A PointCloud2 as N x 4 float32 (x, y, z, intensity; 0 without one) and each point's time in seconds
    from `ref_ns` (the image's stamp, ns; None without a time field). Points with a non-finite coordinate
    are dropped. Times as `_point_times` reads them, offsets from the stamp x `time_scale` (a driver writing
    another unit; None: the times are not used)."""
    fields = cloud_fields(msg)
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        raise MessageError(f"point cloud has no {', '.join(missing)} field (fields: {', '.join(fields)})")
    recs = _records(msg, fields)
    if len(recs) == 0:
        return np.zeros((0, 4), np.float32), None
    pts = np.zeros((len(recs), 4), np.float32)
    for c, name in enumerate("xyz"):
        pts[:, c] = _column(recs, fields, name)
    inten = next((f for f in INTENSITY_FIELDS if f in fields), None)
    if inten is not None:
        pts[:, 3] = _column(recs, fields, inten)
    times = None
    if time_scale is not None and (timed := _point_times(msg, fields, recs)) is not None:
        t, absolute = timed
        # from the cloud's stamp: the stamps' difference in integer ns keeps full precision
        times = t - 1e-9 * ref_ns if absolute else t * time_scale + 1e-9 * (stamp_ns(msg) - ref_ns)
    keep = np.isfinite(pts[:, :3]).all(1)
    if not keep.all():
        pts = pts[keep]
        times = None if times is None else times[keep]
    return pts, times


def cloud_time_range(msg: Any) -> tuple[float, float, bool] | None:
    """The smallest and largest per-point time of a cloud as `_point_times` reads them (seconds) and whether
    they are absolute; None without per-point times or points."""
    try:
        fields = cloud_fields(msg)
        timed = _point_times(msg, fields, _records(msg, fields))
    except MessageError:
        return None
    if timed is None:
        return None
    t, absolute = timed
    return float(t.min()), float(t.max()), absolute


def transform_matrix(tf: Any) -> np.ndarray:
    """A geometry_msgs Transform as a 4 x 4 matrix (child to parent)."""
    q, t = tf.rotation, tf.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [t.x, t.y, t.z]
    return T


def pose_matrix(msg: Any, msgtype: str) -> tuple[np.ndarray, str]:
    """The pose of an Odometry or PoseStamped (4 x 4, the body in the world) and the body's frame name
    (Odometry's child frame; empty for PoseStamped)."""
    pose = msg.pose.pose if msgtype.endswith("Odometry") else msg.pose
    q, p = pose.orientation, pose.position
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [p.x, p.y, p.z]
    return T, str(getattr(msg, "child_frame_id", "") or "")


class FrameTree:
    """The static transforms of a recording (`/tf_static`), to chain from one sensor's frame to another's."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, np.ndarray]] = {}  # child -> (parent, T_parent_child)

    def add(self, msg: Any) -> None:
        for tf in msg.transforms:
            self.parent[str(tf.child_frame_id).lstrip("/")] = (
                str(tf.header.frame_id).lstrip("/"),
                transform_matrix(tf.transform),
            )

    def _to_root(self, frame: str) -> tuple[str, np.ndarray]:
        T, seen = np.eye(4), set()
        while frame in self.parent and frame not in seen:
            seen.add(frame)
            parent, T_pc = self.parent[frame]
            T = T_pc @ T
            frame = parent
        return frame, T

    def between(self, target: str, source: str) -> np.ndarray | None:
        """T_target_source (source coordinates into target's), None when the two are not connected."""
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return np.eye(4)
        rt, T_rt = self._to_root(target)
        rs, T_rs = self._to_root(source)
        if rt != rs:
            return None
        return np.linalg.inv(T_rt) @ T_rs

    @property
    def frames(self) -> list[str]:
        return sorted(set(self.parent) | {p for p, _ in self.parent.values()})
