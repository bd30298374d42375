"""Write any readable sequence as a ROS bag (`leovr convert SEQ --out drive.mcap | drive.db3 | drive.bag`), so
that a recording can round-trip and tests can make bags: a ROS 2 bag folder (MCAP or SQLite 3 storage) or a
ROS 1 `.bag` file, through `rosbags`.

Topics: `/camera/image_raw` (Image, rgb8 or mono8), `/camera/camera_info` (the pinhole K, no distortion),
`/lidar/points` (PointCloud2: x, y, z float32, intensity float32 when present, `time` float64 seconds from
the stamp when the scan has point times), `/tf_static` (the LiDAR in the camera's frame) and
`/ground_truth/pose` (PoseStamped: the camera in the world) when the sequence has poses. Every message of a
frame is stamped with the frame's time (from a fixed epoch when the sequence counts from zero), a scan with
point times at its sweep's first or last point when asked (`cloud_stamp`), as many LiDAR drivers stamp.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from leovr.data.sequence import Sequence
from leovr.errors import DataError

CAMERA_FRAME, LIDAR_FRAME, WORLD_FRAME = "camera", "lidar", "world"
TOPICS = {
    "image": "/camera/image_raw",
    "info": "/camera/camera_info",
    "cloud": "/lidar/points",
    "tf": "/tf_static",
    "pose": "/ground_truth/pose",
}
EPOCH_NS = 1_600_000_000 * 1_000_000_000  # stamps of a sequence that counts from zero start here
FORMATS = {".mcap": "mcap", ".db3": "sqlite3", ".bag": "ros1"}


def bag_format(out: Path) -> str | None:
    """`mcap`, `sqlite3` or `ros1` for an output path named like a bag, else None."""
    return FORMATS.get(Path(out).suffix.lower())


class RosMessages:
    """Typed messages of one ROS version."""

    def __init__(self, ros1: bool) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = ros1
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.store.types:  # the ROS 1 store lacks it
            from rosbags.typesys import get_types_from_msg

            self.store.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        self.T = self.store.types

    def header(self, ns: int, frame: str, seq: int = 0) -> Any:
        stamp = self.T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if self.ros1:
            return self.T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(self, ns: int, img: np.ndarray, seq: int) -> Any:
        enc, c = ("rgb8", 3) if img.ndim == 3 else ("mono8", 1)
        h, w = img.shape[:2]
        return self.T["sensor_msgs/msg/Image"](
            header=self.header(ns, CAMERA_FRAME, seq),
            height=h,
            width=w,
            encoding=enc,
            is_bigendian=0,
            step=w * c,
            data=np.ascontiguousarray(img, np.uint8).reshape(-1),
        )

    def camera_info(self, ns: int, K: np.ndarray, h: int, w: int, seq: int) -> Any:
        roi = self.T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        P = np.c_[K, np.zeros(3)].ravel()
        arrays = {"D": np.zeros(5), "K": np.asarray(K, np.float64).ravel(), "R": np.eye(3).ravel(), "P": P}
        if not self.ros1:
            arrays = {k.lower(): v for k, v in arrays.items()}
        return self.T["sensor_msgs/msg/CameraInfo"](
            header=self.header(ns, CAMERA_FRAME, seq),
            height=h,
            width=w,
            distortion_model="plumb_bob",
            binning_x=0,
            binning_y=0,
            roi=roi,
            **arrays,
        )

    def cloud(self, ns: int, points: np.ndarray, times: np.ndarray | None, seq: int) -> Any:
        PF = self.T["sensor_msgs/msg/PointField"]
        names = ["x", "y", "z"] + (["intensity"] if points.shape[1] > 3 else [])
        dtype = [(n, "<f4") for n in names] + ([("time", "<f8")] if times is not None else [])
        rec = np.zeros(len(points), np.dtype(dtype))
        for c, n in enumerate(names):
            rec[n] = points[:, c]
        if times is not None:
            rec["time"] = times
        fields = [
            PF(name=n, offset=rec.dtype.fields[n][1], datatype=8 if n == "time" else 7, count=1)
            for n in rec.dtype.names
        ]
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(ns, LIDAR_FRAME, seq),
            height=1,
            width=len(rec),
            fields=fields,
            is_bigendian=False,
            point_step=rec.dtype.itemsize,
            row_step=rec.dtype.itemsize * len(rec),
            data=rec.view(np.uint8).reshape(-1),
            is_dense=True,
        )

    def _quat(self, R: np.ndarray) -> Any:
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        return self.T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def tf_static(self, ns: int, T_cam_lidar: np.ndarray) -> Any:
        tr = self.T["geometry_msgs/msg/Transform"](
            translation=self.T["geometry_msgs/msg/Vector3"](
                x=T_cam_lidar[0, 3], y=T_cam_lidar[1, 3], z=T_cam_lidar[2, 3]
            ),
            rotation=self._quat(T_cam_lidar[:3, :3]),
        )
        ts = self.T["geometry_msgs/msg/TransformStamped"](
            header=self.header(ns, CAMERA_FRAME), child_frame_id=LIDAR_FRAME, transform=tr
        )
        return self.T["tf2_msgs/msg/TFMessage"](transforms=[ts])

    def pose(self, ns: int, T: np.ndarray, seq: int) -> Any:
        p = self.T["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3])
        pose = self.T["geometry_msgs/msg/Pose"](position=p, orientation=self._quat(T[:3, :3]))
        return self.T["geometry_msgs/msg/PoseStamped"](header=self.header(ns, WORLD_FRAME, seq), pose=pose)

    def serialize(self, msg: Any, msgtype: str) -> bytes:
        return self.store.serialize_ros1(msg, msgtype) if self.ros1 else self.store.serialize_cdr(msg, msgtype)


def open_bag_writer(out: Path, fmt: str) -> Any:
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        return Writer(out)
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
    return Writer(out, version=9, storage_plugin=plugin)


CLOUD_STAMPS = ("image", "sweep_start", "sweep_end")


def write_bag(
    seq: Sequence, out: str | Path, fmt: str | None = None, progress: bool = True, cloud_stamp: str = "image"
) -> Path:
    """Write `seq` as a bag at `out` (format from its suffix unless `fmt`: mcap, sqlite3, ros1) and return its
    path: `NAME.bag` a ROS 1 file, `NAME.mcap` or `NAME.db3` a ROS 2 bag folder `NAME/` holding that storage
    file and its metadata.yaml. A bag is written whole or not at all: an interrupted write removes what it began.
    `cloud_stamp`: a scan with point times is
    stamped with its image's time (`image`), or at its first (`sweep_start`) or last point (`sweep_end`)."""
    import shutil

    out = Path(out)
    fmt = fmt or bag_format(out)
    if fmt not in ("mcap", "sqlite3", "ros1"):
        raise DataError(out, "a bag's name ends in .mcap or .db3 (ROS 2) or .bag (ROS 1)")
    if fmt != "ros1" and out.suffix.lower() in (".mcap", ".db3"):
        out = out.with_suffix("")  # a ROS 2 bag is a folder: NAME/NAME.mcap beside NAME/metadata.yaml
    if out.exists():
        raise DataError(out, "already exists; a bag is written to a new path")
    if cloud_stamp not in CLOUD_STAMPS:
        raise ValueError(f"cloud_stamp is one of {CLOUD_STAMPS}, not {cloud_stamp!r}")
    m = RosMessages(fmt == "ros1")
    stamps = np.asarray(seq.timestamps(), np.float64)
    base = EPOCH_NS if len(stamps) and stamps[0] < 86400.0 else 0
    ns = [base + int(round(t * 1e9)) for t in stamps]
    writer = open_bag_writer(out, fmt)
    try:
        with writer:
            _write_frames(writer, m, seq, ns, progress, cloud_stamp)
    except BaseException:
        if out.is_dir():
            shutil.rmtree(out, ignore_errors=True)
        else:
            out.unlink(missing_ok=True)
        raise
    return out


def _write_frames(writer: Any, m: RosMessages, seq: Sequence, ns: list[int], progress: bool, cloud_stamp: str) -> None:
    conns: dict[str, Any] = {}

    def put(key: str, msgtype: str, t: int, msg: Any) -> None:
        if key not in conns:
            conns[key] = writer.add_connection(TOPICS[key], msgtype, typestore=m.store)
        writer.write(conns[key], t, m.serialize(msg, msgtype))

    for i, frame in enumerate(tqdm(seq, total=len(seq), desc="bag", unit="frame", disable=not progress)):
        t = ns[i]
        if i == 0 and frame.points is not None:
            put("tf", "tf2_msgs/msg/TFMessage", t, m.tf_static(t, frame.T_cam_lidar))
        put("image", "sensor_msgs/msg/Image", t, m.image(t, frame.image, i))
        put("info", "sensor_msgs/msg/CameraInfo", t, m.camera_info(t, frame.K, frame.height, frame.width, i))
        if frame.points is not None:
            times, tc = frame.point_times, t
            if times is not None and len(times) and cloud_stamp != "image":
                shift = int(round(float(times.min() if cloud_stamp == "sweep_start" else times.max()) * 1e9))
                times, tc = times - shift * 1e-9, t + shift
            put("cloud", "sensor_msgs/msg/PointCloud2", t, m.cloud(tc, frame.points, times, i))
        if frame.T_world_cam is not None:
            put("pose", "geometry_msgs/msg/PoseStamped", t, m.pose(t, frame.T_world_cam, i))
