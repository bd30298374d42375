"""ROS bags as sequences: ROS 2 bags (MCAP or SQLite 3 storage) and ROS 1 `.bag` files, read with the
pure-Python `rosbags` library (no ROS installation).

Opening a bag reads its messages' stamps once (not their data: memory stays flat in the bag's length);
a frame's image and scan are read from the bag when the pipeline asks for the frame. The topics:

- one camera (`sensor_msgs/Image`: rgb8, bgr8, rgba8, bgra8, mono8, mono16; or `CompressedImage`: jpeg,
  png) with its `CameraInfo` (plumb_bob / rational_polynomial distortion undistorted once, into a
  pinhole camera of the same size);
- one point cloud (`sensor_msgs/PointCloud2`: x, y, z; intensity and a per-point time optional);
- the camera-LiDAR extrinsic, chained through `/tf_static` (or given as a file);
- optional ground-truth poses (`nav_msgs/Odometry` or `geometry_msgs/PoseStamped`), interpolated at the
  images' stamps and moved to the camera through `/tf_static` when their body frame is another.

Each is picked automatically when the bag holds one candidate; `TopicChoice` (the CLI's `--camera-topic`,
`--lidar-topic`, ...) names it otherwise.

Stamps: messages are taken in recording order; of each topic, the largest set of messages whose header
stamps increase in that order is kept (a stamp that repeats, goes back or jumps ahead loses its own message
only), and of those the largest stretch without an hour's gap (a clock not set stamps 0). Each message left
out is named in a warning; a topic that would lose more than half its messages is refused.

Pairing: each image takes the sweep whose points' times span the image's stamp (clouds with per-point
times: the stamp plus the offsets, whichever end of the sweep the driver stamps), else the sweep nearest in
time within half the time between sweeps; clouds without per-point times pair by nearest header stamp
within half a scan period. An image without a scan becomes a frame without returns, or is left out
(`drop_unpaired`).
"""

from __future__ import annotations

import os
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from leovr.data import ros_messages as rm
from leovr.data.bag_calibration import camera_model, lidar_extrinsic
from leovr.data.bag_index import BagIndex, index_bag
from leovr.data.bag_salvage import SalvagedBag, storage_files
from leovr.data.bag_time import increasing, pair_by_span, point_time_scale
from leovr.data.bag_topics import BagTopic, bag_topics, pick_info_topic, pick_topic
from leovr.data.io import associate
from leovr.data.records import Frame
from leovr.data.sequence import RecordedSequence
from leovr.errors import DataError
from leovr.geometry import poses_at

ROS2_SUFFIXES = (".mcap", ".db3")
MAX_POSE_GAP_S = 0.5  # images farther than this outside the poses' time span: the poses are not used


@dataclass
class TopicChoice:
    """Which topics of a bag to read (None: the only candidate), an extrinsic file for bags without
    `/tf_static`, and whether images without a scan are left out."""

    camera: str | None = None
    camera_info: str | None = None
    lidar: str | None = None
    poses: str | None = None
    extrinsic: Path | None = None
    drop_unpaired: bool = False


CHOICE = TopicChoice()  # what the command line chose (`leovr --camera-topic ...`); readers take it by default


def is_rosbag(path: Path) -> bool:
    """A ROS 1 bag file, a ROS 2 bag folder (metadata.yaml, or storage files without it: a recorder that
    did not close), or a storage file (`.mcap`, `.db3`) inside one or alone."""
    path = Path(path)
    if path.is_file():
        return bool(storage_files(path))
    return path.is_dir() and ((path / "metadata.yaml").is_file() or bool(storage_files(path)))


def _bag_root(path: Path) -> Path:
    """The ROS 2 bag folder of a storage file inside one; else the path itself."""
    if path.is_file() and path.suffix in ROS2_SUFFIXES and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return path


class RosbagSequence(RecordedSequence):
    """A ROS 1 or ROS 2 bag read as a sequence of camera + LiDAR frames (module docstring)."""

    name = "rosbag"

    def __init__(self, path: str | Path, choice: TopicChoice | None = None) -> None:
        self.path = Path(path)
        self.choice = choice or CHOICE
        self._lock = threading.Lock()
        self._reader: Any = None
        self._pid = -1
        self.salvaged = ""  # where a damaged bag stops, when it does
        reader = self._open()
        self.topics = bag_topics(reader)
        self.camera = pick_topic(
            self.path,
            self.topics,
            rm.IMAGE_TYPES,
            self.choice.camera,
            "camera",
            "--camera-topic",
            salvaged=self.salvaged,
        )
        self.lidar = pick_topic(
            self.path, self.topics, (rm.CLOUD_TYPE,), self.choice.lidar, "point cloud", "--lidar-topic", required=False
        )
        self.info_topic = pick_info_topic(self.path, self.topics, self.camera, self.choice.camera_info)
        self.pose_topic = pick_topic(
            self.path,
            self.topics,
            (*rm.POSE_TYPES,),
            self.choice.poses,
            "pose",
            "--pose-topic",
            required=False,
            ambiguous_ok=True,
        )
        idx = index_bag(reader, self.path, self.topics, self.camera, self.lidar, self.info_topic, self.pose_topic)
        self._log_span = idx.log_span
        self.K, self._maps = camera_model(self.path, self.camera, self.info_topic, idx.info)
        self._mono_shift: int | None = None
        self._pair(idx)
        self.T_cam_lidar = (
            lidar_extrinsic(self.path, idx.tree, idx.camera_frame, idx.lidar_frame, self.choice.extrinsic)
            if self.lidar is not None
            else np.eye(4)
        )
        self._poses = self._camera_poses(idx)
        self.has_lidar = self.lidar is not None
        self.has_poses = self._poses is not None
        diffs = np.diff(self._times)
        self.rate_hz = float(1.0 / np.median(diffs)) if len(diffs) and np.median(diffs) > 0 else 10.0
        self.damaged = self.salvaged or idx.damaged
        if self.damaged:
            warnings.warn(f"{self.path}: {self.damaged}; the {len(self)} frames before it are read", stacklevel=2)

    # -- opening --------------------------------------------------------------------------------------------

    def _open(self) -> Any:
        """The bag's reader, opened once per process (a forked worker opens its own)."""
        if self._reader is not None and self._pid == os.getpid():
            return self._reader
        from rosbags.highlevel import AnyReader

        try:
            reader = AnyReader([_bag_root(self.path)])
            reader.open()
        except Exception as exc:  # rosbags raises its own errors, and others on damaged files
            reader = self._salvage(exc)
        self._reader, self._pid = reader, os.getpid()
        return reader

    def _salvage(self, error: Exception) -> SalvagedBag:
        """A bag rosbags cannot open (cut off, no index or summary, no metadata.yaml): its storage files
        scanned up to the damage (`bag_salvage`)."""
        try:
            bag = SalvagedBag(_bag_root(self.path))
        except Exception as exc:  # nothing readable at all
            raise DataError(self.path, f"cannot open this bag: {error}{_repair_hint(self.path)}") from exc
        if not bag.end_time:
            why = f": {bag.damaged}" if bag.damaged else ""
            raise DataError(
                self.path,
                f"cannot open this bag ({error}) and no message can be read from it{why}{_repair_hint(self.path)}",
            )
        if bag.damaged and self._reader is None:  # said once, not again in each worker that reopens it
            self.salvaged = f"damaged, {bag.damaged}{_repair_hint(self.path)}"
        return bag

    # -- pairing and poses ----------------------------------------------------------------------------------

    def _pair(self, idx: BagIndex) -> None:
        """Each image with the sweep whose point times span its stamp, else the nearest (module docstring)."""
        keep_img = increasing(self.path, self.camera, [s for _, s in idx.images])
        images = [idx.images[k] for k in keep_img]
        img_ns = np.array([s for _, s in images], np.int64)
        scan = np.full(len(images), -1, np.int64)
        self._clouds, spans = [], []
        self.pairing_rule = ""
        self.time_scale: float | None = 1.0  # per-point times' unit, as found against the scan period
        self._sweep_offsets = np.zeros((0, 2))
        if self.lidar is not None:
            keep_cl = increasing(self.path, self.lidar, [s for _, s in idx.clouds]) if idx.clouds else []
            self._clouds = [idx.clouds[k] for k in keep_cl]
            spans = [idx.spans[k] for k in keep_cl]
        if self._clouds:
            cl_ns = np.array([s for _, s in self._clouds], np.int64)
            period = float(np.median(np.diff(cl_ns))) if len(cl_ns) > 1 else 1e8
            self.time_scale = point_time_scale(self.path, self.lidar, spans, period * 1e-9)
            if self.time_scale is None:
                spans = [None] * len(spans)
            lo, hi = cl_ns.copy(), cl_ns.copy()
            for k, sp in enumerate(spans):
                if sp is not None:
                    a, b, absolute = sp
                    lo[k], hi[k] = (
                        (round(a * 1e9), round(b * 1e9))
                        if absolute
                        else (cl_ns[k] + round(a * self.time_scale * 1e9), cl_ns[k] + round(b * self.time_scale * 1e9))
                    )
            timed = sum(sp is not None for sp in spans)
            self.pairing_rule = (
                "sweep time span (per-point times)"
                if timed == len(spans)
                else "nearest header stamp (no per-point times)"
                if not timed
                else f"sweep time span where clouds carry per-point times ({timed} of {len(spans)}), "
                "else nearest header stamp"
            )
            # outside every sweep: the nearest within half the time between sweeps (a lost sweep's images stay
            # unpaired); a cloud without point times within half a scan period of its stamp
            scan = pair_by_span(img_ns, lo, hi, cl_ns, np.maximum(period - (hi - lo), 0.0) / 2)
            paired = scan >= 0
            self._sweep_offsets = np.c_[img_ns[paired] - lo[scan[paired]], cl_ns[scan[paired]] - img_ns[paired]] * 1e-9
            if (~paired).sum() * 2 > len(paired):
                near = cl_ns[associate(img_ns, cl_ns, np.inf)]  # each image's nearest scan stamp
                warnings.warn(
                    f"{self.path}: {(~paired).sum()} of {len(paired)} images of {self.camera} have no sweep of "
                    f"{self.lidar} at their time; the scans' stamps lie a median "
                    f"{np.median(near - img_ns) * 1e-9:+.3f} s from the images' (another clock, or an offset "
                    "the recorder did not correct?)",
                    stacklevel=3,
                )
        keep = scan >= 0 if (self.choice.drop_unpaired and self.lidar is not None) else np.ones(len(images), bool)
        if not keep.any():
            raise DataError(
                self.path, f"no image of {self.camera} has a scan of {self.lidar} within half a scan period"
            )
        self._images = [images[k] for k in np.nonzero(keep)[0]]
        self._scan = scan[keep]
        self._stamps_ns = img_ns[keep]
        self._times = (self._stamps_ns - self._stamps_ns[0]) * 1e-9
        self.unpaired = int((self._scan < 0).sum()) if self.lidar is not None else 0

    def _camera_poses(self, idx: BagIndex) -> np.ndarray | None:
        """The camera's pose at each image's stamp (F x 4 x 4), None without usable poses."""
        if not idx.poses:
            return None
        idx.poses.sort(key=lambda p: p[0])
        t = np.array([p[0] for p in idx.poses], np.int64)
        T_world_body = np.stack([p[1] for p in idx.poses])
        body = idx.poses[0][2]
        T_body_cam = idx.tree.between(body, idx.camera_frame) if body else None
        if T_body_cam is None:
            if body and body.lstrip("/") != idx.camera_frame.lstrip("/"):
                warnings.warn(
                    f"{self.path}: no transform from the poses' frame {body!r} to the camera's "
                    f"{idx.camera_frame!r}; the poses are taken as the camera's",
                    stacklevel=3,
                )
            T_body_cam = np.eye(4)
        gap = max(float(t[0] - self._stamps_ns[0]), float(self._stamps_ns[-1] - t[-1])) * 1e-9
        if gap > MAX_POSE_GAP_S:
            warnings.warn(
                f"{self.path}: the poses of {self.pose_topic} end {gap:.2f} s before the images do; not used",
                stacklevel=3,
            )
            return None
        at = (self._stamps_ns - t[0]) * 1e-9
        return poses_at((t - t[0]) * 1e-9, T_world_body, at) @ T_body_cam

    # -- frames ---------------------------------------------------------------------------------------------

    def _num_frames(self) -> int:
        return len(self._images)

    def _message(self, topic: str, log_ns: int, stamp_ns: int) -> tuple[Any, str]:
        """The message of `topic` logged at `log_ns` with header stamp `stamp_ns`."""
        with self._lock:
            reader = self._open()
            conns = self.topics[topic].connections
            for conn, _, raw in reader.messages(connections=conns, start=log_ns, stop=log_ns + 1):
                msg = reader.deserialize(raw, conn.msgtype)
                if rm.stamp_ns(msg) == stamp_ns:
                    return msg, conn.msgtype
        raise DataError(self.path, f"{topic}: the message stamped {stamp_ns * 1e-9:.6f} s cannot be read again")

    def _load(self, i: int) -> Frame:
        msg, msgtype = self._message(self.camera, *self._images[i])
        try:
            image = rm.decode_image(msg, msgtype)
        except rm.MessageError as exc:
            raise DataError(self.path, f"{self.camera} image {i}: {exc}") from exc
        if image.dtype == np.uint16:
            if self._mono_shift is None:  # fixed by the first frame read, for the whole sequence
                self._mono_shift = rm.mono16_shift(image)
            image = rm.to_uint8(image, self._mono_shift)
        if self._maps is not None:
            image = cv2.remap(image, *self._maps, cv2.INTER_LINEAR)
        points = times = None
        if self.lidar is not None:
            k = int(self._scan[i])
            if k < 0:
                points = np.zeros((0, 4), np.float32)
            else:
                cloud, _ = self._message(self.lidar, *self._clouds[k])
                try:
                    points, times = rm.decode_cloud(cloud, int(self._stamps_ns[i]), self.time_scale)
                except rm.MessageError as exc:
                    raise DataError(self.path, f"{self.lidar} scan of frame {i}: {exc}") from exc
        return self._frame(i, image, points, times)

    # -- what `leovr info` prints ---------------------------------------------------------------------------

    def topic_table(self) -> list[dict]:
        """Every topic: type, messages, rate (Hz, from its log times where read, else over the bag's span) and
        what leovr uses it for."""
        use = {self.camera: "camera", self.info_topic: "camera info", self.lidar: "LiDAR", self.pose_topic: "poses"}
        if self.lidar is not None and self.choice.extrinsic is None:
            use |= {t: "extrinsic" for t in ("/tf_static", "tf_static")}
        bag_span = max((self._reader.end_time - self._reader.start_time) * 1e-9, 1e-9)

        def rate(t: BagTopic) -> float:
            a, b = self._log_span.get(t.name, (0, 0))
            span = (b - a) * 1e-9 if b > a else bag_span
            return round((t.count - 1) / span, 2) if t.count > 1 else 0.0

        return [
            {
                "topic": t.name,
                "type": t.msgtype,
                "messages": t.count,
                "rate_hz": rate(t),
                "used_as": use.get(t.name, ""),
            }
            for t in sorted(self.topics.values(), key=lambda t: t.name)
        ]

    def pairing(self) -> dict:
        """Images paired and not, the rule that paired them, and where the images fell: seconds from the
        start of their sweep's points (`image_after_sweep_start_s`) and from the image to its scan's header
        stamp (`scan_stamp_after_image_s`), each as min / median / max."""
        out: dict = {"images": len(self), "paired_with_a_scan": len(self) - self.unpaired, "unpaired": self.unpaired}
        if self.pairing_rule:
            out["pairing"] = self.pairing_rule
        if len(self._sweep_offsets):
            for k, name in enumerate(("image_after_sweep_start_s", "scan_stamp_after_image_s")):
                col = self._sweep_offsets[:, k]
                out[name] = [round(float(v), 4) for v in (col.min(), np.median(col), col.max())]
        return out | ({"damaged": self.damaged} if self.damaged else {})


def _repair_hint(path: Path) -> str:
    """The tool that repairs a bag of this format (a recorder killed mid-write leaves no index)."""
    storage = {p.suffix for p in storage_files(_bag_root(Path(path)))}
    if ".bag" in storage:
        return " (`rosbag reindex` repairs a ROS 1 bag)"
    if ".mcap" in storage:
        return " (`mcap recover` repairs an MCAP file)"
    if ".db3" in storage:
        return " (`sqlite3 FILE .recover` salvages a SQLite file's rows)"
    return ""
